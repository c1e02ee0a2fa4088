"""Figures of a stream's results: the success matrix, anchor weights per task, the simplex,
the forgetting curves, the pruning rule and the anchor counts; a benchmark's performance
against memory is :mod:`hispo_pl.perf_memory_figures`'s.

Shared by TensorBoard (:mod:`hispo_pl.stream_report`) and the anchor-weights notebook. Only
``matplotlib.figure.Figure`` is used (no pyplot), so nothing depends on a display backend.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

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
