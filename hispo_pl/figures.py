"""Figures of a stream's results: the success matrix, anchor weights per task, the simplex,
and a benchmark's performance against memory.

Shared by TensorBoard (:mod:`hispo_pl.stream_report`) and the anchor-weights notebook. Only
``matplotlib.figure.Figure`` is used (no pyplot), so nothing depends on a display backend.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import ScalarFormatter

from .metrics import METRICS
from .rundir import task_label

# One style per method, the same in every figure: the shipped methods have their own (HiSPO a
# red star), any other name (a user's method, a study's variant) one chosen from its name.
METHOD_STYLES: dict[str, tuple[str, str]] = {
    "hispo": ("*", "tab:red"),
    "hispo-pac": ("p", "darkred"),
    "hilow": ("h", "tab:pink"),
    "csp": ("D", "tab:purple"),
    "cspo": ("d", "navy"),
    "scn": ("s", "tab:blue"),
    "sc1": ("H", "tab:cyan"),
    "ftn": ("^", "tab:orange"),
    "ft1": ("v", "tab:olive"),
    "frz": ("X", "tab:gray"),
    "l2": ("<", "tab:brown"),
    "ewc": (">", "tab:green"),
    "pnn": ("o", "black"),
    "rpl": ("8", "teal"),
}
OTHER_MARKERS = "osD^vP*Xh<>pd8H"
OTHER_COLORS = (
    "goldenrod", "slateblue", "darkcyan", "sienna", "orchid", "yellowgreen", "steelblue",
    "coral", "darkmagenta", "olivedrab", "rosybrown", "dodgerblue", "chocolate", "seagreen",
)  # fmt: skip


def method_style(method: str) -> dict[str, str]:
    """The marker (``fmt``) and colour of ``method`` in every figure: the shipped methods'
    own, else one picked by a hash of the name (stable across figures, runs and machines;
    ``hash()`` of a str changes with each interpreter)."""
    if method in METHOD_STYLES:
        marker, color = METHOD_STYLES[method]
    else:
        h = zlib.crc32(method.encode())
        color = OTHER_COLORS[h % len(OTHER_COLORS)]
        marker = OTHER_MARKERS[(h // len(OTHER_COLORS)) % len(OTHER_MARKERS)]
    return {"fmt": marker, "color": color}


def marker_size(marker: str) -> float:
    """Points of a method's marker: stars and thin shapes a little larger, to weigh alike."""
    return 11.0 if marker == "*" else 7.0


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


# Where a label may go around its point, nearest first: rings of growing radius (points on the
# page), eight directions on each. (dx, dy) is a unit direction; the label's box touches the
# point's side of the ring, so a label "east" starts right of the point, "north" sits above it.
LABEL_RADII = (4.0, 12.0, 22.0, 34.0, 48.0, 64.0)
LABEL_DIRECTIONS = ((1, 0), (1, 1), (1, -1), (0, 1), (0, -1), (-1, 0), (-1, 1), (-1, -1))


def label_offsets(
    points: Sequence[tuple[float, float]],
    sizes: Sequence[tuple[float, float]],
    bounds: tuple[float, float, float, float] | None = None,
    marker: float = 7.0,
) -> list[tuple[float, float, bool]]:
    """Where each point's label goes, as the offset in points from the point to the label's
    lower-left corner and whether it needs a leader line: the nearest free place on rings
    around its own point (:data:`LABEL_RADII` × :data:`LABEL_DIRECTIONS`) whose box of
    ``sizes`` (width, height, in points) meets no label already placed and no point's marker
    (``marker`` points wide), inside ``bounds`` (the axes: x0, y0, x1, y1) when given.
    ``points`` are in points on the page. Labels of a crowded spot fan out around it, each
    joined to its point by a leader line, rather than stacking in a column away from it;
    with no free place at all, the label goes right of its point."""
    placed: list[tuple[float, float, float, float]] = []
    offsets = []
    half = marker / 2
    marks = [(px - half, py - half, px + half, py + half) for px, py in points]
    for (x, y), (w, h) in zip(points, sizes, strict=True):
        choice = None
        # first a place nearer its own point than any other; in a tight crowd, any free one
        for attached in (True, False):
            for ring, radius in enumerate(LABEL_RADII):
                for ux, uy in LABEL_DIRECTIONS:
                    dx = radius + half if ux > 0 else -radius - half - w if ux < 0 else -w / 2
                    dy = radius + half if uy > 0 else -radius - half - h if uy < 0 else -h / 2
                    if ux and uy:  # a diagonal: the corner of the box on the ring
                        dx, dy = dx - ux * 0.3 * radius, dy - uy * 0.3 * radius
                    box = (x + dx, y + dy, x + dx + w, y + dy + h)
                    free = not any(_overlap(box, o) for o in placed + marks)
                    if free and ring:  # a leader line must not cross a label already placed
                        free = not any(_crosses((x, y), box, o) for o in placed)
                    near = not attached or _nearest((x, y), box, points, marker)
                    if free and near and _within(box, bounds):
                        choice = (dx, dy, ring > 0 or not attached)
                        break
                if choice is not None:
                    break
            if choice is not None:
                break
        if choice is None:
            choice = (LABEL_RADII[0] + half, -h / 2, False)
        dx, dy, _ = choice
        placed.append((x + dx, y + dy, x + dx + w, y + dy + h))
        offsets.append(choice)
    return offsets


def _distance(point: tuple[float, float], box: tuple[float, ...]) -> float:
    """From ``point`` to the nearest point of ``box`` (0 inside it)."""
    dx = max(box[0] - point[0], 0.0, point[0] - box[2])
    dy = max(box[1] - point[1], 0.0, point[1] - box[3])
    return float(np.hypot(dx, dy))


def _nearest(own: tuple[float, float], box: tuple[float, ...], points, spot: float) -> bool:
    """Whether no other point (apart from those within ``spot`` of ``own``, whose markers
    touch its own) is nearer to the label's box than its own point: a label read as its
    neighbour's is worse than one a little away."""
    mine = _distance(own, box)
    far = [p for p in points if np.hypot(p[0] - own[0], p[1] - own[1]) > spot]
    return all(_distance(p, box) >= mine for p in far)


def _crosses(own: tuple[float, float], box: tuple[float, ...], other: tuple[float, ...]) -> bool:
    """Whether the leader line from ``own`` to the centre of the label's box passes through
    the box ``other``."""
    cx, cy = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    for t in np.linspace(0.0, 1.0, 24):
        px, py = own[0] + t * (cx - own[0]), own[1] + t * (cy - own[1])
        if other[0] < px < other[2] and other[1] < py < other[3]:
            return True
    return False


def _overlap(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _within(box: tuple[float, ...], bounds: tuple[float, ...] | None) -> bool:
    if bounds is None:
        return True
    return (
        bounds[0] <= box[0] and bounds[1] <= box[1] and box[2] <= bounds[2] and box[3] <= bounds[3]
    )


def _draw_method(ax, method: str, x: float, y: float, **errors) -> None:
    """One method's point in its own style (:func:`method_style`), with its error bars."""
    style = method_style(method)
    ax.errorbar(x, y, **style, ms=marker_size(style["fmt"]), mec="white", mew=0.6, capsize=3,
                zorder=3, **errors)  # fmt: skip


def _count_note(counts: Mapping[str, int], unit: str, single: str = "") -> str:
    """``3 seeds each`` or ``3 seeds each; 1 seed (no interval): hispo-6k``: what the error
    bars are over, said once instead of in a legend (``single``: said of a count of one)."""
    if not counts:
        return ""

    def many(n: int) -> str:
        return f"{n} {unit}{'s' if n != 1 else ''}{single if n == 1 else ''}"

    usual = max(sorted(set(counts.values())), key=list(counts.values()).count)
    note = f"{many(usual)} each"
    for n in sorted(set(counts.values()) - {usual}):
        note += f"; {many(n)}: {', '.join(m for m, c in counts.items() if c == n)}"
    return note


def perf_vs_memory_figure(rows: Sequence, stream: str = "") -> Figure:
    """The paper's Figure 2: MEM on x, PER (%) on y over the whole 0..100 range, one point per
    method in its own style (rows with ``method``, ``seeds`` and ``metrics``: ``MEM`` and
    ``PER`` as (mean, std)), error bars of the std over seeds where there are several, each
    method named beside its point (no legend); the x label says how many seeds each has."""
    rows = [r for r in rows if "MEM" in r.metrics]
    fig = Figure(figsize=(6.8, 4.5), layout="constrained")
    ax = fig.add_subplot()
    for row in rows:
        (x, xs), (y, ys) = row.metrics["MEM"], row.metrics["PER"]
        several = len(row.seeds) > 1
        _draw_method(ax, row.method, x, 100 * y, xerr=xs if several else None,
                     yerr=100 * ys if several else None)  # fmt: skip
    xs_all = [r.metrics["MEM"][0] for r in rows] or [1.0]
    ax.set_xlim(*span_limits(min(xs_all), max(xs_all), min_span=1.0))
    top = max([100 * sum(r.metrics["PER"]) for r in rows] + [100.0])
    ax.set_ylim(0, top + 4)
    ax.set_yticks(range(0, 101, 20))
    plain_ticks(ax)
    ax.xaxis.set_major_formatter("{x:.2f}")
    note = _count_note({r.method: len(r.seeds) for r in rows}, "seed", " (no interval)")
    ax.set_xlabel("MEM (stored size / one single-task model)" + (f"\n{note}" if note else ""))
    ax.set_ylabel("PER (success %, mean ± std over seeds)")
    ax.set_title(f"Performance vs memory{': ' + stream if stream else ''}")
    ax.grid(alpha=0.3)
    centres = [(r.metrics["MEM"][0], 100 * r.metrics["PER"][0]) for r in rows]
    label_markers(fig, ax, [r.method for r in rows], centres)
    return fig


def label_markers(
    fig: Figure,
    ax,
    names: Sequence[str],
    centres: Sequence[tuple[float, float]],
    fontsize: float = 8,
) -> None:
    """Write each method's name beside its point (data coordinates ``centres``) in its
    colour, where :func:`label_offsets` finds room; a label that had to move past its
    neighbours keeps a thin leader line to its own point."""
    fig.draw_without_rendering()  # the layout's final axes, so labels are placed as drawn
    points = ax.transData.transform(centres) * 72 / fig.dpi if centres else []
    sizes = [(0.62 * fontsize * len(name), 1.2 * fontsize) for name in names]
    frame = ax.get_window_extent().extents * 72 / fig.dpi
    offsets = label_offsets([tuple(p) for p in points], sizes, bounds=tuple(frame))
    for name, centre, (dx, dy, leader) in zip(names, centres, offsets, strict=True):
        color = method_style(name)["color"]
        ax.annotate(
            name,
            centre,
            xytext=(dx, dy),
            textcoords="offset points",
            ha="left",
            va="bottom",
            color=color,
            fontsize=fontsize,
            zorder=4,
            arrowprops=dict(arrowstyle="-", color=color, lw=0.6, shrinkA=1, shrinkB=3)
            if leader
            else None,
        )


def iqm_vs_memory_figure(rows: Sequence, title: str) -> Figure:
    """PER's IQM with its interval against mean MEM, one point per method in its own style
    (rows with ``method``, ``streams``, ``means`` and ``iqm``: point, low, high), each named
    beside its point (no legend); the x label says over how many streams."""
    fig = Figure(figsize=(6.4, 4.6), layout="constrained")
    ax = fig.add_subplot()
    drawn = [r for r in rows if "MEM" in r.means]
    for row in drawn:
        point, low, high = row.iqm
        _draw_method(ax, row.method, row.means["MEM"], point,
                     yerr=[[point - low], [high - point]])  # fmt: skip
    xs = [r.means["MEM"] for r in drawn] or [1.0]
    ax.set_xlim(*span_limits(min(xs), max(xs), min_span=1.0))
    ax.set_ylim(0, max([r.iqm[2] for r in drawn] + [100.0]) + 5)  # a bar and a label at 100 %
    ax.set_yticks(range(0, 101, 20))
    plain_ticks(ax)
    ax.xaxis.set_major_formatter("{x:.2f}")
    note = _count_note({r.method: len(r.streams) for r in drawn}, "stream")
    ax.set_xlabel("MEM (mean stored size / one single-task model)" + (f"\n{note}" if note else ""))
    ax.set_ylabel("PER IQM (success %), 95 % CI")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    centres = [(r.means["MEM"], r.iqm[0]) for r in drawn]
    label_markers(fig, ax, [r.method for r in drawn], centres, fontsize=7)
    return fig


def forgetting_figure(rows: Sequence[Sequence[float]]) -> Figure:
    """The forgetting curves as they are (TensorBoard's charts smooth them): after each task
    trained (x), the success on every task of the stream (%), one colour and marker per task,
    dashed before the task is trained (zero-shot) and solid from then on."""
    R = 100 * np.asarray(rows, dtype=float)
    trained, n = R.shape
    fig = Figure(figsize=(2.8 + 0.55 * max(trained, 3), 3.4), layout="constrained")
    ax = fig.add_subplot()
    after = np.arange(1, trained + 1)
    for k, tag in enumerate(task_labels(n)):
        color, marker = f"C{k % 10}", OTHER_MARKERS[k % len(OTHER_MARKERS)]
        seen = after >= k + 1
        ax.plot(after[~seen | (after == k + 1)], R[~seen | (after == k + 1), k], ls="--",
                color=color, lw=1)  # fmt: skip
        ax.plot(after[seen], R[seen, k], color=color, lw=1.8, marker=marker, ms=5, label=tag)
        ax.plot(after[~seen], R[~seen, k], ls="none", color=color, marker=marker, ms=5,
                mfc="none")  # fmt: skip
    ax.set_xticks(after, task_labels(trained))
    ax.set_xlim(0.7, trained + 0.3)
    ax.set_ylim(-3, 105)
    ax.set_xlabel("after training task\n(dashed, hollow: the task not trained yet)")
    ax.set_ylabel("success (%)")
    ax.set_title("success on each task", fontsize=10)
    ax.grid(alpha=0.3)
    fig.legend(loc="outside right upper", fontsize="small", title="success on")
    return fig


def rule_figure(decisions: Sequence) -> Figure | None:
    """HiSPO's pruning rule of each task after the first, one panel per subspace: the ratio
    ``L_prev / L_curr`` (▼ pruned, ▲ kept) against its line ``1 + eps``, each value written
    beside it, on an axis from 0 that holds every point (None: no decision compared two
    losses)."""
    compared = [d for d in decisions if getattr(d, "l_prev", None) is not None and d.l_curr]
    compared = [d for d in compared if getattr(d, "eps", None) is not None]
    if not compared:
        return None
    last = {(d.task, d.subspace): d for d in compared}  # a resumed run may repeat a task
    subspaces = list(dict.fromkeys(d.subspace for d in last.values()))
    tasks = sorted({t for t, _ in last})
    fig = Figure(
        figsize=(0.6 + (1.6 + 0.6 * len(tasks)) * len(subspaces), 3.4), layout="constrained"
    )
    axes = fig.subplots(1, len(subspaces), squeeze=False)[0]
    top = max(max(d.l_prev / d.l_curr, 1 + d.eps) for d in last.values())
    for ax, name in zip(axes, subspaces, strict=True):
        drawn = [(x, last[task, name]) for x, task in enumerate(tasks) if (task, name) in last]
        for i, (x, d) in enumerate(drawn):
            ratio, line = d.l_prev / d.l_curr, 1 + d.eps
            pruned = d.decision == "prune"
            ax.hlines(line, x - 0.35, x + 0.35, color="0.25", ls="--", lw=1.4)
            if i == len(drawn) - 1 or drawn[i + 1][1].eps != d.eps:  # once per value of eps
                ax.annotate(f"1 + ε = {line:.2f}", (x + 0.37, line), va="center", fontsize=7,
                            color="0.25")  # fmt: skip
            ax.plot([x, x], [0, ratio], color="0.75", lw=3, zorder=1)
            ax.plot(x, ratio, marker="v" if pruned else "^", ms=10, ls="none", zorder=3,
                    color="tab:red" if pruned else "tab:green")  # fmt: skip
            ax.annotate(f"{ratio:.2f} {d.decision}", (x, ratio), xytext=(0, 7),
                        textcoords="offset points", ha="center", fontsize=8)  # fmt: skip
        ax.set_xticks(range(len(tasks)), [task_tag(t) for t in tasks])
        ax.set_xlim(-0.6, len(tasks) + 0.3)
        ax.set_ylim(0, 1.2 * top)
        ax.set_xlabel("task")
        ax.set_title(f"{name}: L_prev / L_curr vs 1 + ε", fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel("L_prev / L_curr")
    fig.suptitle("pruned (▼) where L_prev / L_curr ≤ 1 + ε, else kept (▲)", fontsize=9)
    return fig


DECISION_MARKERS = {"first": ("o", "0.4"), "keep": ("^", "tab:green"), "prune": ("v", "tab:red")}
"""How each decision on a new anchor is drawn: its marker and fill."""


def anchor_counts_figure(decisions: Sequence) -> Figure | None:
    """The anchor count of each subspace after each task (``decisions`` as
    :meth:`~hispo_pl.rundir.RunDir.decisions` reads them; a repeated task's last wins), marked
    by the decision that set it (▲ kept, ▼ pruned), against the count without pruning
    (dotted); every count on an integer axis from 0 (None: no decision with a count)."""
    last = {(d.task, d.subspace): d for d in decisions if getattr(d, "anchors", None)}
    if not last:
        return None
    tasks = sorted({t for t, _ in last})
    fig = Figure(figsize=(3.2 + 0.6 * len(tasks), 3.4), layout="constrained")
    ax = fig.add_subplot()
    x_all = np.array([task_label(t) for t in tasks])
    ax.plot(x_all, x_all, ":", color="0.6", label="no pruning")
    names = list(dict.fromkeys(s for _, s in last))
    for i, name in enumerate(names):
        rows = sorted((d for (_, s), d in last.items() if s == name), key=lambda d: d.task)
        x = np.array([task_label(d.task) for d in rows])
        y = np.array([d.anchors for d in rows]) + 0.05 * (i - (len(names) - 1) / 2)
        (line,) = ax.step(x, y, where="post", lw=2, color=f"C{i}", label=name)
        for xi, yi, d in zip(x, y, rows, strict=True):
            marker, color = DECISION_MARKERS.get(d.kind, ("s", "k"))
            ax.scatter(xi, yi, marker=marker, s=70, color=color, edgecolor=line.get_color(),
                       linewidth=1.5, zorder=3)  # fmt: skip
    for decision, (marker, color) in DECISION_MARKERS.items():
        ax.scatter([], [], marker=marker, color=color, label=decision)
    ax.set_xticks(x_all, [task_tag(t) for t in tasks])
    ax.set_xlabel("after task")
    ax.set_ylabel("anchors")
    ax.set_ylim(0, max(max(x_all), max(d.anchors for d in last.values())) + 0.6)
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_title("anchors per subspace", fontsize=10)
    fig.legend(loc="outside right upper", fontsize="small")
    return fig
