"""Every figure kind rendered and read back as a reader of a paper would: labels present, no
offset on an axis, success over the whole 0..100, titles and legends inside the picture,
labels that do not overlap."""

from __future__ import annotations

import numpy as np
import pytest

from hispo_pl.benchmark.finished_runs import MethodRow
from hispo_pl.figures import (
    METHOD_STYLES,
    anchor_counts_figure,
    anchor_weights_figure,
    forgetting_figure,
    method_style,
    rule_figure,
    simplex_figure,
    stream_summary,
    success_matrix_figure,
)
from hispo_pl.perf_memory_figures import label_offsets, perf_vs_memory_figure
from hispo_pl.results import LossDecision

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


def _attached(fig, ax) -> None:
    """Every method label is nearer its own point than any other point (apart from points whose
    markers touch its own), or joined to it by a leader line; no two labels overlap."""
    renderer = _drawn(fig)
    boxes = [t.get_window_extent(renderer) for t in ax.texts]
    assert not any(a.overlaps(b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])
    points = [ax.transData.transform(t.xy) for t in ax.texts]
    for text, box, own in zip(ax.texts, boxes, points, strict=True):

        def gap(p, box=box):
            return np.hypot(
                max(box.x0 - p[0], 0, p[0] - box.x1), max(box.y0 - p[1], 0, p[1] - box.y1)
            )

        others = [p for p in points if np.hypot(*(p - own)) > 7 * fig.dpi / 72]  # markers apart
        assert text.arrow_patch is not None or all(gap(own) <= gap(p) for p in others), text


def _styles(ax) -> dict[str, tuple]:
    """Each labelled method's drawn (colour, marker), read from the figure."""
    from matplotlib.colors import to_rgba

    drawn = [(to_rgba(c.lines[0].get_color()), c.lines[0].get_marker()) for c in ax.containers]
    return dict(zip([t.get_text() for t in ax.texts], drawn, strict=True))


def _no_offset(fig, ax) -> bool:
    _drawn(fig)
    return ax.xaxis.get_offset_text().get_text() == ax.yaxis.get_offset_text().get_text() == ""


def test_the_grid_s_iqm_figure_has_plain_axes_intervals_and_a_title_inside():
    from types import SimpleNamespace

    from hispo_pl.perf_memory_figures import iqm_vs_memory_figure

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
    assert ax.get_xlabel().endswith("2 streams each; 1 stream: hispo")  # once, not per method
    assert ax.get_legend() is None  # the names are beside their points, not repeated
    assert _inside(fig, ax.title)
    caps = [line for container in ax.containers for line in container.lines[1]]
    assert caps  # each point has its interval drawn
    # scn and ftn share a spot: each is named next to it, the names apart, and no two methods
    # drawn alike
    assert sorted(t.get_text() for t in ax.texts) == ["ftn", "hispo", "scn"]
    _attached(fig, ax)
    assert len(set(_styles(ax).values())) == 3


def test_a_method_has_one_style_in_every_figure_whatever_its_place():
    from types import SimpleNamespace

    from hispo_pl.perf_memory_figures import iqm_vs_memory_figure

    names = [*METHOD_STYLES, "my-method"]
    grid = [
        SimpleNamespace(method=m, streams=["a"], means={"MEM": 1.0 + i}, iqm=(50, 40, 60))
        for i, m in enumerate(names)
    ]
    (ax,) = iqm_vs_memory_figure(grid, "all").axes
    in_grid = _styles(ax)
    assert len(set(in_grid.values())) == len(names)  # every method drawn its own way
    two = [_row("my-method", (2.0, 0.0), (0.5, 0.1)), _row("hispo", (1.5, 0.0), (0.9, 0.0))]
    (ax,) = perf_vs_memory_figure(two).axes
    assert _styles(ax) == {m: in_grid[m] for m in ("my-method", "hispo")}  # not by position
    # a user's method: from its name, stable, and never a shipped method's look
    assert method_style("my-method") == method_style("my-method")  # the same in each call
    shipped = {(c, m) for m, c in METHOD_STYLES.values()}
    for name in ("my-method", "bc-scn", "hispo-6k", "score-2", "eps-0.05-0.1"):
        style = method_style(name)
        assert (style["color"], style["fmt"]) not in shipped
    assert method_style("hispo") == {"fmt": "*", "color": "tab:red"}


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
    assert sorted(t.get_text() for t in ax.texts) == ["frz", "ftn", "hispo", "hispo-6k", "scn"]
    _attached(fig, ax)
    renderer = _drawn(fig)
    frame = ax.get_window_extent(renderer)
    boxes = [t.get_window_extent(renderer) for t in ax.texts]
    assert all(frame.x0 <= b.x0 and b.x1 <= frame.x1 and b.y1 <= frame.y1 for b in boxes)
    assert ax.get_legend() is None  # no second list of the same names
    assert ax.get_xlabel().endswith("3 seeds each; 1 seed (no interval): hispo-6k")
    one_seed = ax.containers[3]  # no zero-length "± 0" bar drawn for a single seed
    assert not one_seed.has_yerr and not one_seed.has_xerr
    assert ax.containers[0].has_yerr


def test_a_reference_is_drawn_hollow_beside_each_method_and_no_label_covers_it():
    """Another protocol's figure on the same streams (the paper's) beside ours: a hollow
    marker per method that has one, in its colour, joined to our point, and said under the
    axis; names stay clear of the hollow markers."""
    from types import SimpleNamespace

    from hispo_pl.perf_memory_figures import iqm_vs_memory_figure

    rows = [
        SimpleNamespace(method="hispo", streams=["a", "b"], means={"MEM": 3.5}, iqm=(92, 91, 93)),
        SimpleNamespace(method="scn", streams=["a", "b"], means={"MEM": 4.0}, iqm=(93, 92, 94)),
        SimpleNamespace(method="ftn", streams=["a"], means={"MEM": 4.0}, iqm=(96, 96, 96)),
    ]
    reference = {"hispo": (2.1, 98.9), "scn": (4.0, 99.0), "pnn": (9.9, 99.5)}  # pnn: no row
    fig = iqm_vs_memory_figure(rows, "beside", reference, "the paper's")
    (ax,) = fig.axes
    hollow = [line for line in ax.lines if line.get_markerfacecolor() == "none"]
    drawn = sorted((float(h.get_xdata()[0]), float(h.get_ydata()[0])) for h in hollow)
    assert drawn == [(2.1, 98.9), (4.0, 99.0)]  # one per method with a row and a figure
    from matplotlib.colors import to_rgba

    colours = {to_rgba(h.get_markeredgecolor()) for h in hollow}
    assert colours == {_styles(ax)[m][0] for m in ("hispo", "scn")}
    assert ax.get_xlim()[0] < 2.1 and ax.get_xlabel().endswith("hollow: the paper's")
    fig.draw_without_rendering()
    marks = ax.transData.transform(drawn) * 72 / fig.dpi
    own = dict(zip([r.method for r in rows], ax.transData.transform(
        [(r.means["MEM"], r.iqm[0]) for r in rows]) * 72 / fig.dpi, strict=True))  # fmt: skip
    for text in ax.texts:
        box = text.get_window_extent().extents * 72 / fig.dpi
        for mx, my in marks:
            assert not (box[0] < mx + 3.5 and mx - 3.5 < box[2] and box[1] < my + 3.5
                        and my - 3.5 < box[3]), text.get_text()  # fmt: skip
            # and no name sits nearer a hollow marker than its own point
            assert _box_distance((mx, my), box) >= _box_distance(own[text.get_text()], box)
    plain = iqm_vs_memory_figure(rows, "ours alone")
    assert not [line for line in plain.axes[0].lines if line.get_markerfacecolor() == "none"]


def _box_distance(point, box) -> float:
    dx = max(box[0] - point[0], 0.0, point[0] - box[2])
    dy = max(box[1] - point[1], 0.0, point[1] - box[3])
    return float(np.hypot(dx, dy))


def test_labels_of_coincident_points_fan_out_around_them():
    offsets = label_offsets([(100, 100)] * 5, [(20, 10)] * 5)
    boxes = [(100 + dx, 100 + dy, 120 + dx, 110 + dy) for dx, dy, _ in offsets]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not (a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])
    near = [np.hypot(max(b[0] - 100, 0, 100 - b[2]), max(b[1] - 100, 0, 100 - b[3])) for b in boxes]
    assert max(near) < 20  # around the spot, not a column running away from it
    assert {dx > 0 for dx, _, _ in offsets} == {True, False}  # on both sides
    assert [leader for *_, leader in offsets][:1] == [False]  # the first sits beside it


def test_the_rule_figure_holds_every_deciding_value():
    decisions = [
        LossDecision(
            task=1, subspace="high", decision="prune", eps=0.1, l_curr=0.0314, l_prev=0.0323
        ),
        LossDecision(task=1, subspace="low", decision="keep", eps=0.6, l_curr=0.2046, l_prev=1.909),
        LossDecision(task=0, subspace="low", decision="first", eps=0.6, l_curr=0.21),
    ]
    fig = rule_figure(decisions)
    high, low = fig.axes
    for ax, ratio, line in ((high, 0.0323 / 0.0314, 1.1), (low, 1.909 / 0.2046, 1.6)):
        bottom, top = ax.get_ylim()
        assert bottom == 0 and top > max(ratio, line)  # the far ratio (9.3) is on the axis
        texts = " ".join(t.get_text() for t in ax.texts)
        assert f"{ratio:.2f}" in texts and f"1 + ε = {line:.2f}" in texts
    assert "prune" in " ".join(t.get_text() for t in high.texts)
    assert rule_figure(decisions[2:]) is None  # nothing compared yet


def test_forgetting_and_anchor_figures_draw_each_task_apart():
    fig = forgetting_figure([[1.0, 0.05, 0.2], [1.0, 1.0, 0.26]])
    (ax,) = fig.axes
    solid = [
        line for line in ax.lines if line.get_linestyle() == "-" and line.get_label()[0] == "T"
    ]
    assert [line.get_label() for line in solid] == ["T01", "T02", "T03"]
    assert len({line.get_color() for line in solid}) == 3
    assert ax.get_ylim()[1] >= 100
    decisions = [
        LossDecision(task=0, subspace="high", decision="first", anchors=1),
        LossDecision(task=1, subspace="high", decision="prune", anchors=1),
        LossDecision(task=0, subspace="low", decision="first", anchors=1),
        LossDecision(task=1, subspace="low", decision="keep", anchors=2),
    ]
    (ax,) = anchor_counts_figure(decisions).axes
    assert ax.get_ylim()[0] == 0 and ax.get_ylim()[1] > 2  # every count on the axis
    steps = {line.get_label(): list(line.get_ydata()) for line in ax.lines}
    assert max(steps["low"]) > 1.9 and max(steps["high"]) < 1.1


def test_stream_summary_prints_mem_as_a_ratio():
    results = {"PER": 0.994, "BWT": 0.0, "FWT": None, "MEM": 1.934}
    assert stream_summary(results) == "PER 99.4  BWT 0.0 (success %)  MEM 1.93"
    assert stream_summary({"MEM": 4.0}) == "MEM 4.00"
