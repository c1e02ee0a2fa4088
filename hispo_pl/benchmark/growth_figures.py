"""The growth report's two figures (the paper's Figure 2d): MEM against tasks
(``memory_growth.png``) and PER after each task (``per_after_task.png``), one panel per stream
family, drawn from :class:`~.growth_curves.GrowthData`.

    write_growth_figures(grid, growth_data(grid, Committed(root)), out)
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .growth_curves import STRUCTURAL, GrowthData, _family_title, mean_curve

FIGURES = ("memory_growth.png", "per_after_task.png")


def _styles(grid) -> dict[str, dict[str, str]]:
    """Each method's marker and colour, the one it has in every figure."""
    from ..figures import method_style

    return {m: method_style(m) for m in dict.fromkeys([*grid.methods, *STRUCTURAL])}


def _panels(data: GrowthData):
    """A figure with one panel per family (those with runs; all of them before any)."""
    from matplotlib.figure import Figure

    families = [f for f, s in data.families.items() if any(r.stream in s for r in data.runs)]
    families = families or list(data.families)
    fig = Figure(figsize=(4.6 * len(families), 3.6), layout="constrained")
    return fig, families, fig.subplots(1, len(families), squeeze=False)[0]


def _draw(
    ax, x_runs: Sequence[Sequence[float]], style: dict, label: str, scale: float = 1.0, z: int = 2
):
    """Each run thin, their mean thick with the method's marker (``z``: its drawing order)."""
    for curve in x_runs:
        ax.plot(
            range(1, len(curve) + 1),
            np.multiply(curve, scale),
            color=style["color"],
            lw=0.8,
            alpha=0.35,
        )
    mean = np.multiply(mean_curve(x_runs), scale)
    ax.plot(
        range(1, len(mean) + 1),
        mean,
        color=style["color"],
        marker=style["fmt"],
        lw=1.8,
        ms=5 if style["fmt"] == "*" else 4,
        zorder=z,
        label=f"{label} ({len(x_runs)} run{'s' * (len(x_runs) > 1)})",
    )


def _task_axis(ax) -> None:
    from matplotlib.ticker import MaxNLocator

    ax.set_xlabel("tasks trained")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(alpha=0.3)


def _structural_lines(data: GrowthData, family: str) -> list[tuple[list[str], list[float]]]:
    """The family's structural curves, methods with the same curve on one line (SCN and FTN
    both hold one network per task: drawn apart, one would hide the other)."""
    lines: dict[tuple[float, ...], list[str]] = {}
    for method in STRUCTURAL:
        grown = data.structure.get((family, method))
        if grown is not None:
            lines.setdefault(tuple(grown), []).append(method)
    return [(methods, list(grown)) for grown, methods in lines.items()]


def memory_growth_figure(grid, data: GrowthData):
    """MEM against tasks, one panel per family: the measured methods' runs and their mean,
    the structural methods dashed; PNN's line leaves the top once it exceeds one network per
    task, its last value written where it leaves."""
    fig, families, axes = _panels(data)
    styles = _styles(grid)
    for ax, family in zip(axes, families, strict=True):
        top = 1.0
        for i, method in enumerate(grid.methods):  # the grid's first method drawn on top
            curves = [r.memory for r in data.of(family, method) if r.memory is not None]
            if curves and method not in STRUCTURAL:
                _draw(ax, curves, styles[method], method, z=3 + len(grid.methods) - i)
                top = max(top, *(max(c) for c in curves))
        for methods, grown in _structural_lines(data, family):
            ax.plot(
                range(1, len(grown) + 1),
                grown,
                ls="--",
                lw=1.2,
                color=styles[methods[0]]["color"],
                label=f"{' = '.join(methods)} (structure)",
            )
            if "pnn" not in methods:
                top = max(top, max(grown))
        scn = [r.memory for r in data.of(family, "scn") if r.memory is not None]
        for curve in scn:
            ax.plot(
                range(1, len(curve) + 1),
                curve,
                ls="none",
                marker="x",
                ms=5,
                color=styles["scn"]["color"],
            )
        if scn:
            ax.plot(
                [],
                [],
                ls="none",
                marker="x",
                color=styles["scn"]["color"],
                label=f"scn measured ({len(scn)} run{'s' * (len(scn) > 1)})",
            )
        pnn = data.structure.get((family, "pnn"))
        ax.set_ylim(0, top * 1.08)
        if pnn is not None and max(pnn) > top * 1.08:
            k = next(i for i, v in enumerate(pnn) if v > top * 1.08)
            ax.annotate(
                f" pnn: {pnn[-1]:.1f} at {len(pnn)} tasks",
                (k + 1, top * 1.04),
                fontsize=8,
                ha="left",
                va="top",
                color=styles["pnn"]["color"],
            )
        ax.set_title(_family_title(family, data.families[family]), fontsize=9)
        _task_axis(ax)
        ax.legend(fontsize=7, loc="upper left")
    axes[0].set_ylabel("MEM (× one single-task model)")
    return fig


def per_after_task_figure(grid, data: GrowthData):
    """PER after each task (×100), one panel per family: each run thin, the method's mean
    thick."""
    fig, families, axes = _panels(data)
    styles = _styles(grid)
    for ax, family in zip(axes, families, strict=True):
        for i, method in enumerate(grid.methods):
            curves = [r.per for r in data.of(family, method)]
            if curves:
                _draw(ax, curves, styles[method], method, 100, 3 + len(grid.methods) - i)
        ax.set_title(_family_title(family, data.families[family]), fontsize=9)
        _task_axis(ax)
        ax.set_ylim(-2, 102)
        ax.legend(fontsize=7, loc="lower left")
    axes[0].set_ylabel("PER after the task (success ×100)")
    return fig


def write_growth_figures(grid, data: GrowthData, out: Path) -> list[Path]:
    """Both figures into ``out`` (none before any run, or without matplotlib)."""
    if not data.runs:
        return []
    try:
        import matplotlib.figure  # noqa: F401
    except ImportError:
        return []
    from ..io import write_figure

    written = []
    for name, draw in zip(FIGURES, (memory_growth_figure, per_after_task_figure), strict=True):
        write_figure(draw(grid, data), Path(out) / name, dpi=130, bbox_inches="tight")
        written.append(Path(out) / name)
    return written
