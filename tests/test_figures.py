"""Every figure kind rendered and read back as a reader of a paper would: labels present, no
offset on an axis, success over the whole 0..100, titles and legends inside the picture,
labels that do not overlap."""

from __future__ import annotations

import numpy as np
import pytest

from hispo_pl.benchmark.records import MethodRow
from hispo_pl.figures import (
    anchor_weights_figure,
    label_offsets,
    perf_vs_memory_figure,
    simplex_figure,
    stream_summary,
    success_matrix_figure,
)

STREAM = ["pointmaze-umaze-N[500]", "pointmaze-large-N[500]", "pointmaze-umaze-PO[500]"]


def _drawn(fig):
    """The figure drawn as it is saved (Agg), and its renderer to measure boxes with."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _inside(fig, artist) -> bool:
    """The artist's drawn box lies within the figure (nothing cut at an edge)."""
    box, page = artist.get_window_extent(_drawn(fig)), fig.bbox
    return (
        box.x0 >= page.x0 - 1
        and box.y0 >= page.y0 - 1
        and box.x1 <= page.x1 + 1
        and box.y1 <= page.y1 + 1
    )


def _no_offset(fig, ax) -> bool:
    _drawn(fig)
    return ax.xaxis.get_offset_text().get_text() == ax.yaxis.get_offset_text().get_text() == ""


def test_the_grid_s_iqm_figure_has_plain_axes_intervals_and_a_title_inside():
    from types import SimpleNamespace

    from hispo_pl.figures import iqm_vs_memory_figure

    rows = [  # MEM equal to the fifth decimal: one spot, no offset axis
        SimpleNamespace(method="scn", streams=["a", "b"], means={"MEM": 4.00004}, iqm=(97, 95, 99)),
        SimpleNamespace(
            method="ftn", streams=["a", "b"], means={"MEM": 4.00021}, iqm=(96, 90, 100)
        ),
        SimpleNamespace(method="hispo", streams=["a"], means={"MEM": 3.1}, iqm=(98, 97, 99)),
        SimpleNamespace(method="x", streams=["a"], means={}, iqm=(50, 40, 60)),  # no MEM: left out
    ]
    fig = iqm_vs_memory_figure(rows, "PER's IQM against MEM over the grid's streams and seeds")
    (ax,) = fig.axes
    assert _no_offset(fig, ax)
    assert all("e" not in t.get_text() for t in ax.get_xticklabels())
    low, high = ax.get_xlim()
    assert high - low >= 1.0 and low < 3.1 and high > 4.0002
    bottom, top = ax.get_ylim()
    assert bottom <= 0 and top >= 100
    assert ax.get_xlabel().startswith("MEM") and ax.get_ylabel().startswith("PER IQM")
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [
        "scn (2 streams)",
        "ftn (2 streams)",
        "hispo (1 stream)",
    ]
    assert _inside(fig, ax.title) and _inside(fig, ax.get_legend())
    caps = [line for container in ax.containers for line in container.lines[1]]
    assert caps  # each point has its interval drawn
    # scn and ftn share a spot: each is named next to it, the names apart, each with a line
    # to its own marker, and no two methods drawn alike
    renderer = _drawn(fig)
    assert sorted(t.get_text() for t in ax.texts) == ["ftn", "hispo", "scn"]
    boxes = [t.get_window_extent(renderer) for t in ax.texts]
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])
    assert all(t.arrow_patch is not None for t in ax.texts)
    styles = {(c.lines[0].get_color(), c.lines[0].get_marker()) for c in ax.containers}
    assert len(styles) == len(ax.containers) == 3


def test_twelve_methods_are_drawn_twelve_ways():
    from types import SimpleNamespace

    from hispo_pl.figures import iqm_vs_memory_figure

    rows = [
        SimpleNamespace(method=f"m{i}", streams=["a"], means={"MEM": 1.0 + i}, iqm=(50, 40, 60))
        for i in range(12)
    ]
    (ax,) = iqm_vs_memory_figure(rows, "twelve").axes
    styles = {(c.lines[0].get_color(), c.lines[0].get_marker()) for c in ax.containers}
    colors = {c.lines[0].get_color() for c in ax.containers}
    assert len(styles) == len(colors) == 12


def test_success_matrix_names_its_tasks_in_percent():
    fig = success_matrix_figure([[1.0, None, None], [0.9, 0.8, None], [0.9, 0.7, 0.5]], STREAM)
    ax, bar = fig.axes
    rows = [t.get_text() for t in ax.get_yticklabels()]
    assert rows == [f"T0{k + 1} {task}" for k, task in enumerate(STREAM)]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["T01", "T02", "T03"]
    assert ax.get_xlabel() == "success on task" and ax.get_ylabel() == "after training task"
    assert bar.get_ylabel() == "success (%)" and ax.images[0].get_clim() == (0, 100)
    assert all(_inside(fig, label) for label in ax.get_yticklabels())  # long names not cut
    with pytest.raises(ValueError, match="2 task names for a 3-task matrix"):
        success_matrix_figure(np.eye(3).tolist(), STREAM[:2])


def test_anchor_weights_title_and_legend_fit_the_picture():
    fig = anchor_weights_figure([[1.0, 0.0], [0.4, 0.6]], "high")  # two tasks: a narrow figure
    (ax,) = fig.axes
    assert ax.get_ylim() == (0, 1.02) and ax.get_ylabel() == "weight" and ax.get_xlabel() == "task"
    assert fig.get_suptitle() == "high: anchor weights per task (2 anchors)"
    assert _inside(fig, fig._suptitle) and _inside(fig, fig.legends[0])
    renderer = _drawn(fig)
    title, legend = fig._suptitle.get_window_extent(renderer), fig.legends[0]
    assert not title.overlaps(legend.get_window_extent(renderer))  # the title reads whole
    assert not title.overlaps(ax.get_window_extent(renderer))
    assert _no_offset(fig, ax)
    one = anchor_weights_figure([[1.0], [1.0]], "low")
    assert one.get_suptitle() == "low: anchor weights per task (1 anchor)"


def test_simplex_title_and_legend_fit_the_picture():
    fig = simplex_figure([[1.0, 0.0, 0.0], [0.2, 0.5, 0.3]], "low")
    (ax,) = fig.axes
    assert ax.get_title() == "low: anchor weights per task on the simplex"
    assert _inside(fig, ax.title) and _inside(fig, ax.get_legend())


def _row(method, mem, per, seeds=(0, 1, 2)):
    return MethodRow(method, list(seeds), {"PER": per, "BWT": (0.0, 0.0), "MEM": mem})


def test_perf_vs_memory_has_plain_axes_the_whole_success_range_and_separate_labels():
    # MEM equal to the fifth decimal (4.00004 and 4.00021): one spot, no "+4" offset axis
    rows = [
        _row("ftn", (4.00004, 0.0), (0.949, 0.011)),
        _row("hispo", (4.00021, 0.0), (0.970, 0.018)),
        _row("scn", (4.00004, 0.0), (0.990, 0.004)),
        _row("hispo-6k", (3.07, 0.0), (0.872, 0.0), seeds=(0,)),
        _row("frz", (3.5, 0.0), (0.995, 0.0)),  # at the top: its label stays inside the axes
    ]
    fig = perf_vs_memory_figure(rows, "videogame-2")
    (ax,) = fig.axes
    assert _no_offset(fig, ax)
    assert all("e" not in t.get_text() for t in ax.get_xticklabels())  # no scientific notation
    low, high = ax.get_xlim()
    assert high - low >= 1.0  # values a hair apart are not spread over the axis
    bottom, top = ax.get_ylim()
    assert bottom <= 0 and top >= 100  # success on its whole range, not a truncated axis
    assert ax.get_xlabel().startswith("MEM") and ax.get_ylabel().startswith("PER (success %")
    assert ax.get_title() == "Performance vs memory: videogame-2"
    renderer = _drawn(fig)
    boxes = [t.get_window_extent(renderer) for t in ax.texts]
    assert sorted(t.get_text() for t in ax.texts) == ["frz", "ftn", "hispo", "hispo-6k", "scn"]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not a.overlaps(b), "method labels overlap"
    frame = ax.get_window_extent(renderer)
    assert all(frame.x0 <= b.x0 and b.x1 <= frame.x1 and b.y1 <= frame.y1 for b in boxes)
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "hispo-6k (1 seed, no interval)" in legend and "ftn (3 seeds)" in legend
    one_seed = ax.containers[3]  # no zero-length "± 0" bar drawn for a single seed
    assert not one_seed.has_yerr and not one_seed.has_xerr
    assert ax.containers[0].has_yerr
    assert _inside(fig, ax.get_legend())


def test_label_offsets_stack_labels_of_coincident_points():
    offsets = label_offsets([(100, 100), (100, 100), (100, 100)], [(20, 10)] * 3)
    boxes = [(100 + dx, 100 + dy, 120 + dx, 110 + dy) for dx, dy in offsets]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not (a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])


def test_stream_summary_prints_mem_as_a_ratio():
    results = {"PER": 0.994, "BWT": 0.0, "FWT": None, "MEM": 1.934}
    assert stream_summary(results) == "PER 99.4  BWT 0.0 (success %)  MEM 1.93"
    assert stream_summary({"MEM": 4.0}) == "MEM 4.00"
