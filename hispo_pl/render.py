"""Mazes from above, with trajectories: the pictures of ``hispo-pl render`` (paper Figs 7–8).

Everything is drawn in world (maze) coordinates, the frame the env reports positions in, so a
dataset's or a rollout's ``achieved_goal`` lands on the map without any conversion. Only
``matplotlib.figure.Figure`` is used (no pyplot): no global backend state, no display, PNGs
through Agg. Every maze artist carries a ``gid`` naming what it is (``wall``, ``door-closed``,
``door-open``, ``block-high``, ``block-low``, ``starts`` / ``goals`` for points,
``start-segment`` / ``goal-segment``, ``path``), so tests and legends find them by meaning
rather than by colour.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from .envs.drawing import FAILURE, FLOOR, GOAL, LABELS, START, STYLES, WALL
from .envs.family import family_behaviour
from .io import make_folder, write_figure
from .tasks import Task, parse_task

if TYPE_CHECKING:
    from .evaluation import PolicyFn


@dataclass(frozen=True)
class Overlay:
    """Trajectories to draw on one maze: per-episode position arrays [T, >= 2] and, for
    rollouts, whether each episode reached its goal (``None`` for a dataset)."""

    paths: list[np.ndarray]
    successes: np.ndarray | None = None


def draw_maze(ax: Axes, task: str | Task) -> None:
    """Draw ``task``'s maze from above on ``ax`` in world coordinates: floor, walls, doors
    (closed hatched, open dashed), blocks (dark hatched = 3 m, light = 1 m), start and goal
    points (triangles / stars) or segments (lines). The variant changes nothing visible."""
    task = parse_task(task)
    ax.set_facecolor(FLOOR)
    family_behaviour(task).draw_maze(ax, task)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_linewidth(2.0)
        spine.set_color(WALL)


def draw_paths(
    ax: Axes, paths: Sequence[np.ndarray], successes: Sequence[bool] | None = None
) -> list[Line2D]:
    """Draw trajectories (x, y of each [T, >= 2] array) over a maze: one colour per path so
    crossing paths stay apart, a dot at the start, a marker at the end. With ``successes``,
    failed episodes are red and dashed and end in a cross, so they catch the eye. Returns the
    path lines."""
    colours = _path_colours(len(paths))
    lines = []
    for k, path in enumerate(paths):
        xy = np.asarray(path)[:, :2]
        failed = successes is not None and not bool(successes[k])
        colour = FAILURE if failed else colours[k]
        (line,) = ax.plot(
            xy[:, 0],
            xy[:, 1],
            color=colour,
            lw=1.2,
            alpha=0.85,
            ls="--" if failed else "-",
            zorder=5,
        )
        line.set_gid("path")
        lines.append(line)
        ax.plot(*xy[0], "o", color=colour, ms=4, mec="black", mew=0.4, zorder=6)
        end = "X" if failed else ("o" if successes is None else "P")
        ax.plot(*xy[-1], end, color=colour, ms=6, mec="black", mew=0.5, zorder=6)
    return lines


def _path_colours(n: int) -> list:
    from matplotlib import colormaps

    cmap = colormaps["viridis" if n > 10 else "tab10"]
    if n > 10:
        return [cmap(x) for x in np.linspace(0.0, 0.9, n)]
    return [cmap(k) for k in range(n)]


def task_title(task: Task) -> str:
    """``amazeville-HXOO``: family and maze, and the variant only when it is not N."""
    suffix = f"-{task.variant}" if task.variant != "N" else ""
    return f"{task.family}-{task.maze}{suffix}"


# --- trajectories ------------------------------------------------------------------------


def dataset_paths(task: str | Task, episodes: int) -> list[np.ndarray]:
    """Positions of the first ``episodes`` episodes of a task's stored dataset (at most the
    task's own episode count); raises ``DatasetNotFoundError`` naming the command that makes
    it rather than generating data behind a picture's back."""
    from .data.datasets import load_episodes

    task = parse_task(task)
    arrays = load_episodes(replace(task, episodes=min(episodes, task.episodes)))
    ends = np.unique(arrays.episode_end)
    starts = np.concatenate([[0], ends[:-1] + 1])
    return [arrays.positions[s : e + 1] for s, e in zip(starts, ends, strict=True)]


def rollout_paths(task: str | Task, policy: PolicyFn, episodes: int, seed: int = 0) -> Overlay:
    """``episodes`` seeded rollouts of ``policy`` on ``task``, with the evaluator that
    ``hispo-pl evaluate`` uses, so a picture shows the episodes that are scored."""
    from .evaluation import RolloutEvaluator

    evaluator = RolloutEvaluator(task, episodes, seed)
    try:
        result = evaluator.run(policy, record=True)
    finally:
        evaluator.close()
    return Overlay(list(result.trajectories), result.successes)


# --- figures -----------------------------------------------------------------------------


def maze_figure(
    tasks: Sequence[str | Task],
    overlays: Sequence[Overlay | None] | None = None,
    ncols: int | None = None,
    panel: float = 3.4,
) -> Figure:
    """A grid of mazes, one panel per task titled by its maze, with optional trajectories and
    one legend for the whole figure (only for what is drawn)."""
    tasks = [parse_task(t) for t in tasks]
    overlays = list(overlays) if overlays is not None else [None] * len(tasks)
    if len(overlays) != len(tasks):
        raise ValueError(f"{len(overlays)} overlays for {len(tasks)} tasks")
    ncols = ncols or min(4, len(tasks))
    nrows = -(-len(tasks) // ncols)
    fig = Figure(figsize=(panel * ncols, panel * nrows + 0.6), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax, task, overlay in zip(axes, tasks, overlays, strict=False):
        draw_maze(ax, task)
        if overlay is not None:
            draw_paths(ax, overlay.paths, overlay.successes)
        ax.set_title(task_title(task), fontsize=11)
    for ax in axes[len(tasks) :]:
        fig.delaxes(ax)
    handles = legend_handles(fig, any(o is not None and o.successes is not None for o in overlays))
    if handles:  # as many legend columns as fit under the panels (about 2 in each)
        columns = max(2, min(len(handles), round(panel * ncols / 2.0)))
        fig.legend(
            handles=handles, loc="outside lower center", ncol=columns, fontsize=9, frameon=False
        )
    return fig


def legend_handles(fig: Figure, rollouts: bool = False) -> list:
    """Proxy artists for the kinds of cells and marks that appear in ``fig``."""
    drawn = {a.get_gid() for ax in fig.axes for a in [*ax.patches, *ax.lines]}
    handles: list = [Patch(label=LABELS[kind], **STYLES[kind]) for kind in LABELS if kind in drawn]
    marks = (("starts", START, "^", "start"), ("goals", GOAL, "*", "goal"))
    for gid, colour, marker, label in marks:
        if gid in drawn:
            handles.append(
                Line2D([], [], ls="none", marker=marker, mfc=colour, mec="white", ms=9, label=label)
            )
    for gid, colour, label in (("start-segment", START, "starts"), ("goal-segment", GOAL, "goals")):
        if gid in drawn:
            handles.append(Line2D([], [], color=colour, lw=3, alpha=0.8, label=label))
    if rollouts:
        handles.append(Line2D([], [], color="C0", marker="P", mec="black", label="success"))
        handles.append(
            Line2D([], [], color=FAILURE, ls="--", marker="X", mec="black", label="failure")
        )
    return handles


def save_figure(fig: Figure, out: str | Path, dpi: int = 150) -> Path:
    """Write ``fig`` (PNG, or any format its suffix names), creating the folder."""
    out = Path(out)
    make_folder(out.parent)
    write_figure(fig, out, dpi=dpi, bbox_inches="tight")
    return out


def render_mazes(
    tasks: Sequence[str | Task],
    out: str | Path,
    overlays: Sequence[Overlay | None] | None = None,
    ncols: int | None = None,
) -> Path:
    """Draw ``tasks`` as one grid figure (with ``overlays``) and save it to ``out``."""
    return save_figure(maze_figure(tasks, overlays, ncols), out)
