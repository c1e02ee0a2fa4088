"""Figures of a stream's results: the success matrix, anchor weights per task, the simplex.

Shared by TensorBoard (:mod:`hispo_pl.stream_report`) and the anchor-weights notebook. Only
``matplotlib.figure.Figure`` is used (no pyplot), so nothing depends on a display backend.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure

from .rundir import task_label

TRIANGLE = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, np.sqrt(3) / 2]])


def task_tag(k: int) -> str:
    """``T01`` for the 0-based task 0: tasks as every table and tag of hispo-pl names them."""
    return f"T{task_label(k):02d}"


def task_labels(n: int) -> list[str]:
    """The tags of the first ``n`` tasks."""
    return [task_tag(k) for k in range(n)]


def success_matrix_figure(R: Sequence[Sequence[float | None]]) -> Figure:
    """R[i][k] (success on task k after training task i) as an annotated heatmap; tasks not
    trained yet are blank."""
    matrix = np.array([[np.nan if v is None else v for v in row] for row in R], dtype=float)
    n = len(matrix)
    fig = Figure(figsize=(1.6 + 0.7 * n, 1.2 + 0.6 * n))
    ax = fig.add_subplot()
    image = ax.imshow(100 * matrix, vmin=0, vmax=100, cmap="viridis")
    for i in range(n):
        for k in range(n):
            if not np.isnan(matrix[i, k]):
                value = 100 * matrix[i, k]
                color = "black" if value > 60 else "white"
                ax.text(k, i, f"{value:.0f}", ha="center", va="center", color=color, fontsize=9)
    labels = task_labels(n)
    ax.set_xticks(range(n), labels)
    ax.set_yticks(range(n), labels)
    ax.set_xlabel("success on task")
    ax.set_ylabel("after training task")
    fig.colorbar(image, ax=ax, label="success (%)")
    fig.tight_layout()
    return fig


def anchor_weights_figure(alphas: Sequence[Sequence[float]], subspace: str) -> Figure:
    """Each task's anchor weights in one subspace as a stacked bar (rows: tasks)."""
    weights = np.asarray(alphas, dtype=float)
    n_tasks, n_anchors = weights.shape
    fig = Figure(figsize=(2.4 + 0.6 * n_tasks, 3.2))
    ax = fig.add_subplot()
    x = np.arange(n_tasks)
    bottom = np.zeros(n_tasks)
    colors = [f"C{j % 10}" for j in range(n_anchors)]
    for j in range(n_anchors):
        ax.bar(x, weights[:, j], bottom=bottom, color=colors[j], label=f"anchor {j + 1}", width=0.7)
        bottom += weights[:, j]
    ax.set_xticks(x, task_labels(n_tasks))
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("weight")
    ax.set_title(f"{subspace}: anchor weights per task ({n_anchors} anchors)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    fig.tight_layout()
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
    fig = Figure(figsize=(5.5, 4.8))
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
