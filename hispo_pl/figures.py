"""Figures of a stream's results: the success matrix, anchor weights per task, the simplex,
and a benchmark's performance against memory.

Shared by TensorBoard (:mod:`hispo_pl.stream_report`) and the anchor-weights notebook. Only
``matplotlib.figure.Figure`` is used (no pyplot), so nothing depends on a display backend.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import ScalarFormatter

from .metrics import METRICS
from .rundir import task_label

# Twelve markers and twelve distinct colours (matplotlib's ten, then black and navy): no two
# of the paper's twelve methods are drawn alike in a figure.
METHOD_MARKERS = "osD^vP*Xh<>p"
METHOD_COLORS = tuple(f"C{i}" for i in range(10)) + ("black", "navy")


def method_style(i: int) -> dict[str, str]:
    """The marker (``fmt``) and colour of the ``i``-th method of a figure."""
    return {
        "fmt": METHOD_MARKERS[i % len(METHOD_MARKERS)],
        "color": METHOD_COLORS[i % len(METHOD_COLORS)],
    }


TRIANGLE = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, np.sqrt(3) / 2]])


def task_tag(k: int) -> str:
    """``T01`` for the 0-based task 0: tasks as every table and tag of hispo-pl names them."""
    return f"T{task_label(k):02d}"


def task_labels(n: int) -> list[str]:
    """The tags of the first ``n`` tasks."""
    return [task_tag(k) for k in range(n)]


def matrix_tick_labels(n: int, tasks: Sequence[str] | None = None) -> list[str]:
    """``T01`` per task, or ``T01 pointmaze-umaze-N[500]`` when the task specs are known: a
    matrix read on its own (a paper's figure) names its tasks."""
    labels = task_labels(n)
    if tasks is None:
        return labels
    if len(tasks) != n:
        raise ValueError(f"{len(tasks)} task names for a {n}-task matrix")
    return [f"{label} {task}" for label, task in zip(labels, tasks, strict=True)]


def success_matrix_figure(
    R: Sequence[Sequence[float | None]], tasks: Sequence[str] | None = None
) -> Figure:
    """R[i][k] (success on task k after training task i) as an annotated heatmap in %; tasks
    not trained yet are blank. With ``tasks`` (the stream's specs) the rows name them."""
    matrix = np.array([[np.nan if v is None else v for v in row] for row in R], dtype=float)
    n = len(matrix)
    rows = matrix_tick_labels(n, tasks)
    longest = max((len(label) for label in rows), default=0)
    fig = Figure(figsize=(2.2 + 0.7 * n + 0.075 * longest, 1.4 + 0.6 * n), layout="constrained")
    ax = fig.add_subplot()
    image = ax.imshow(100 * matrix, vmin=0, vmax=100, cmap="viridis")
    for i in range(n):
        for k in range(n):
            if not np.isnan(matrix[i, k]):
                value = 100 * matrix[i, k]
                color = "black" if value > 60 else "white"
                ax.text(k, i, f"{value:.0f}", ha="center", va="center", color=color, fontsize=9)
    ax.set_xticks(range(n), task_labels(n))
    ax.set_yticks(range(n), rows)
    ax.set_xlabel("success on task")
    ax.set_ylabel("after training task")
    fig.colorbar(image, ax=ax, label="success (%)")
    return fig


def stream_summary(metrics: Mapping[str, float | None]) -> str:
    """``PER 99.4  BWT 0.0  FWT 0.6 (success %)  MEM 1.93``: a run's metrics (by name, as
    :attr:`~hispo_pl.results.StreamResults.metrics`) as the tables print them (success ×100,
    MEM a ratio of model sizes, never a percentage)."""
    known = [m for m in METRICS if metrics.get(m.name) is not None]
    percent = [f"{m.name} {m.format(metrics[m.name])}" for m in known if m.percent]
    text = "  ".join(percent) + (" (success %)" if percent else "")
    for m in known:
        if not m.percent:
            text += f"  {m.name} {m.format(metrics[m.name])}"
    return text.strip()


def anchor_weights_figure(alphas: Sequence[Sequence[float]], subspace: str) -> Figure:
    """Each task's anchor weights in one subspace as a stacked bar (rows: tasks); the layout
    makes room for the title and the legend (TensorBoard shows the canvas as drawn)."""
    weights = np.asarray(alphas, dtype=float)
    n_tasks, n_anchors = weights.shape
    fig = Figure(figsize=(max(4.8, 2.6 + 0.6 * n_tasks), 3.8), layout="constrained")
    ax = fig.add_subplot()
    x = np.arange(n_tasks)
    bottom = np.zeros(n_tasks)
    colors = [f"C{j % 10}" for j in range(n_anchors)]
    for j in range(n_anchors):
        ax.bar(x, weights[:, j], bottom=bottom, color=colors[j], label=f"anchor {j + 1}", width=0.7)
        bottom += weights[:, j]
    ax.set_xticks(x, task_labels(n_tasks))
    ax.set_xlabel("task")
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("weight")
    plural = "s" if n_anchors > 1 else ""
    fig.suptitle(f"{subspace}: anchor weights per task ({n_anchors} anchor{plural})", fontsize=11)
    fig.legend(loc="outside lower center", ncols=min(n_anchors, 5), fontsize="small")
    return fig


def to_triangle(weights: np.ndarray) -> np.ndarray:
    """Barycentric weights [n, 3] -> 2-D points in the equilateral triangle :data:`TRIANGLE`."""
    w = np.asarray(weights, dtype=float)
    return (w / w.sum(axis=1, keepdims=True)) @ TRIANGLE


def simplex_figure(
    alphas: Sequence[Sequence[float]],
    subspace: str,
    candidates: dict[int, tuple[np.ndarray, np.ndarray]] | None = None,
) -> Figure:
    """Each task's weights over exactly three anchors as a star in the triangle; with
    ``candidates`` (task -> (candidate weights [m, 3], their losses [m])), the Dirichlet
    search's candidates coloured by loss and each search's best marked."""
    weights = np.asarray(alphas, dtype=float)
    if weights.shape[1] != 3:
        raise ValueError(f"the simplex needs 3 anchors, got {weights.shape[1]}")
    labels = task_labels(len(weights))
    fig = Figure(figsize=(5.5, 4.8), layout="constrained")
    ax = fig.add_subplot()
    ax.fill(*TRIANGLE.T, fill=False, edgecolor="0.3", lw=1)
    for j, (vx, vy) in enumerate(TRIANGLE):
        offset = 8 if vy > 0 else -14
        ax.annotate(
            f"anchor {j + 1}", (vx, vy), ha="center", xytext=(0, offset), textcoords="offset points"
        )
    if candidates:
        losses = np.concatenate([loss for _, loss in candidates.values()])
        vmin, vmax = float(losses.min()), float(losses.max())
        for k, (points, loss) in sorted(candidates.items()):
            xy = to_triangle(points)
            scatter = ax.scatter(*xy.T, c=loss, cmap="viridis", vmin=vmin, vmax=vmax, s=14)
            best = xy[int(np.argmin(loss))]
            ax.scatter(*best, marker="X", s=90, color="red", edgecolor="k", zorder=4,
                       label=f"{labels[k]} best candidate (L_prev)")  # fmt: skip
        fig.colorbar(scatter, ax=ax, shrink=0.8, label="candidate loss")
    points = to_triangle(weights)
    ax.scatter(*points.T, marker="*", s=180, color="orange", edgecolor="k", zorder=5,
               label="task weights")  # fmt: skip
    for label, (px, py) in zip(labels, points, strict=True):
        ax.annotate(label, (px, py), xytext=(6, 4), textcoords="offset points")
    ax.set_xlim(-0.1, 1.1)
    ax.set_ylim(-0.08, 0.95)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0.0), ncols=2, fontsize="small")
    ax.set_title(f"{subspace}: anchor weights per task on the simplex")
    return fig


def plain_ticks(ax) -> None:
    """Tick labels as the values themselves: no offset ("+4") and no scientific notation, so
    equal values never look spread over an axis of 0.00005 steps."""
    for axis in (ax.xaxis, ax.yaxis):
        formatter = ScalarFormatter(useOffset=False)
        formatter.set_scientific(False)
        axis.set_major_formatter(formatter)


def span_limits(lo: float, hi: float, min_span: float) -> tuple[float, float]:
    """Limits around ``[lo, hi]`` at least ``min_span`` wide (centred), with a 10 % margin:
    values that differ in the fifth decimal stay on one spot."""
    centre, half = (lo + hi) / 2, max(hi - lo, min_span) / 2
    return centre - 1.1 * half, centre + 1.1 * half


def label_offsets(
    points: Sequence[tuple[float, float]],
    sizes: Sequence[tuple[float, float]],
    gap: float = 4.0,
    bounds: tuple[float, float, float, float] | None = None,
) -> list[tuple[float, float]]:
    """Where each point's label goes, as offsets in points from the point to the label's
    lower-left corner: the first of a few places around it (then further up or down) whose box
    of ``sizes`` (width, height, in points) meets no label already placed and no other point,
    and stays inside ``bounds`` (the axes: x0, y0, x1, y1) when given. ``points`` are in
    points on the page, so labels of coincident points stack, not overlap."""
    placed: list[tuple[float, float, float, float]] = []
    offsets = []
    for i, ((x, y), (w, h)) in enumerate(zip(points, sizes, strict=True)):
        candidates = [(gap, gap), (gap, -gap - h), (-gap - w, gap), (-gap - w, -gap - h)]
        candidates += [(gap, gap + k * (h + 1)) for k in range(1, 8)]
        candidates += [(gap, -gap - h - k * (h + 1)) for k in range(1, 8)]
        marks = [(px - 3, py - 3, px + 3, py + 3) for j, (px, py) in enumerate(points) if j != i]
        boxes = [(x + dx, y + dy, x + dx + w, y + dy + h) for dx, dy in candidates]
        free = [
            n
            for n, box in enumerate(boxes)
            if not any(_overlap(box, o) for o in placed + marks) and _within(box, bounds)
        ]
        n = free[0] if free else 0
        placed.append(boxes[n])
        offsets.append(candidates[n])
    return offsets


def _overlap(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _within(box: tuple[float, ...], bounds: tuple[float, ...] | None) -> bool:
    if bounds is None:
        return True
    return (
        bounds[0] <= box[0] and bounds[1] <= box[1] and box[2] <= bounds[2] and box[3] <= bounds[3]
    )


def perf_vs_memory_figure(rows: Sequence, stream: str = "") -> Figure:
    """The paper's Figure 2: MEM on x, PER (%) on y over the whole 0..100 range, one marker
    per method (rows with ``method``, ``seeds`` and ``metrics``: ``MEM`` and ``PER`` as (mean,
    std)), error
    bars of the std over seeds where there are several (one seed has no interval: the legend
    says so), each method labelled next to its marker without overlaps."""
    rows = [r for r in rows if "MEM" in r.metrics]
    fig = Figure(figsize=(6.8, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for i, row in enumerate(rows):
        (x, xs), (y, ys) = row.metrics["MEM"], row.metrics["PER"]
        several = len(row.seeds) > 1
        ax.errorbar(
            x,
            100 * y,
            xerr=xs if several else None,
            yerr=100 * ys if several else None,
            **method_style(i),
            capsize=3,
            label=f"{row.method} ({len(row.seeds)} seed{'s' if several else ''}"
            f"{'' if several else ', no interval'})",
        )
    xs_all = [r.metrics["MEM"][0] for r in rows] or [1.0]
    ax.set_xlim(*span_limits(min(xs_all), max(xs_all), min_span=1.0))
    top = max([100 * sum(r.metrics["PER"]) for r in rows] + [100.0])
    ax.set_ylim(0, top + 4)
    ax.set_yticks(range(0, 101, 20))
    plain_ticks(ax)
    ax.xaxis.set_major_formatter("{x:.2f}")
    ax.set_xlabel("MEM (stored size / one single-task model)")
    ax.set_ylabel("PER (success %, mean ± std over seeds)")
    ax.set_title(f"Performance vs memory{': ' + stream if stream else ''}")
    ax.grid(alpha=0.3)
    if rows:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    centres = [(r.metrics["MEM"][0], 100 * r.metrics["PER"][0]) for r in rows]
    colors = [method_style(i)["color"] for i in range(len(rows))]
    label_markers(fig, ax, [r.method for r in rows], centres, colors)
    return fig


def label_markers(
    fig: Figure,
    ax,
    names: Sequence[str],
    centres: Sequence[tuple[float, float]],
    colors: Sequence,
    fontsize: float = 8,
    leaders: bool = False,
) -> None:
    """Write each name next to its marker (data coordinates ``centres``) in its colour, where
    :func:`label_offsets` finds room: a crowded corner is read without the legend.
    ``leaders``: a thin line from each label to its marker, so a label pushed past a
    neighbour's marker still points at its own."""
    fig.draw_without_rendering()  # the layout's final axes, so labels are placed as drawn
    points = ax.transData.transform(centres) * 72 / fig.dpi if centres else []
    sizes = [(0.62 * fontsize * len(name), 1.2 * fontsize) for name in names]
    frame = ax.get_window_extent().extents * 72 / fig.dpi
    offsets = label_offsets([tuple(p) for p in points], sizes, bounds=tuple(frame))
    for name, centre, color, (dx, dy) in zip(names, centres, colors, offsets, strict=True):
        ax.annotate(
            name,
            centre,
            xytext=(dx, dy),
            textcoords="offset points",
            ha="left",
            va="bottom",
            color=color,
            fontsize=fontsize,
            arrowprops=dict(arrowstyle="-", color=color, lw=0.6, shrinkA=0, shrinkB=4)
            if leaders
            else None,
        )


def iqm_vs_memory_figure(rows: Sequence, title: str) -> Figure:
    """PER's IQM with its interval against mean MEM, one marker per method (rows with
    ``method``, ``streams``, ``means`` and ``iqm``: point, low, high)."""
    fig = Figure(figsize=(6.4, 4.6), layout="constrained")
    ax = fig.add_subplot()
    drawn = [r for r in rows if "MEM" in r.means]
    for i, row in enumerate(drawn):
        point, low, high = row.iqm
        ax.errorbar(
            row.means["MEM"],
            point,
            yerr=[[point - low], [high - point]],
            **method_style(i),
            capsize=3,
            label=f"{row.method} ({len(row.streams)} stream{'' if len(row.streams) == 1 else 's'})",
        )
    xs = [r.means["MEM"] for r in drawn] or [1.0]
    ax.set_xlim(*span_limits(min(xs), max(xs), min_span=1.0))
    ax.set_ylim(0, max([r.iqm[2] for r in drawn] + [100.0]) + 5)  # a bar and a label at 100 %
    ax.set_yticks(range(0, 101, 20))
    plain_ticks(ax)
    ax.xaxis.set_major_formatter("{x:.2f}")
    ax.set_xlabel("MEM (mean stored size / one single-task model)")
    ax.set_ylabel("PER IQM (success %), 95 % CI")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="lower right")
    centres = [(r.means["MEM"], r.iqm[0]) for r in drawn]
    colors = [method_style(i)["color"] for i in range(len(drawn))]
    label_markers(fig, ax, [r.method for r in drawn], centres, colors, fontsize=7, leaders=True)
    return fig
