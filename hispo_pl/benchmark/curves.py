"""Learning curves of single-task runs and the budget they license.

A single-task ``fit`` with ``--eval_every N`` writes every evaluation of its task into
``result.json`` (``curve``: step, success). A folder of such runs
(``runs/<setting>-<family>-<maze>/seed<S>/result.json``, as ``benchmarks/single_task_table.py``
lays them out) holding a ``curves.json`` (which settings and tasks, the tolerance) is a learning
curve study: its report is the mean curve of each (setting, task) over seeds, the figure, and
the budget :func:`choose_budget` picks from them, rebuilt from the runs' files alone.

    write_curves_report(Path("results/curves"))  # curves.md, curves.csv, curves.png
"""

from __future__ import annotations

import csv
import io
import json
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..io import atomic_write_text, write_figure
from ..rundir import RunDir

CURVES_FILE = (
    "curves.json"  # what makes a folder a learning-curve study: settings, tasks, tolerance
)


@dataclass(frozen=True)
class CurveStudy:
    """A learning-curve study's definition (its ``curves.json``)."""

    settings: tuple[str, ...]  # run-name prefixes: hbc, bc
    tasks: tuple[str, ...]  # run-name suffixes: pointmaze-umaze, ...
    # the setting whose curves choose the budget; None for a study of what a setting changes
    # at budgets already chosen (``"budget_setting": null``), which chooses none
    budget_setting: str | None
    tolerance: float = 2.0  # success points

    @classmethod
    def read(cls, folder: Path) -> CurveStudy:
        raw = json.loads((Path(folder) / CURVES_FILE).read_text())
        return cls(
            tuple(raw["settings"]),
            tuple(raw["tasks"]),
            raw.get("budget_setting", raw["settings"][0]),
            float(raw.get("tolerance", 2.0)),
        )


@dataclass(frozen=True)
class MeanCurve:
    """One (setting, task)'s success in % at each evaluated step, over its seeds."""

    steps: tuple[int, ...]
    mean: tuple[float, ...]
    std: tuple[float, ...]  # population std over seeds (0 with one seed)
    seeds: int

    @property
    def final(self) -> float:
        return self.mean[-1]


def mean_curve(curves: Sequence[Sequence[Mapping[str, float]]]) -> MeanCurve:
    """The mean and spread over seeds of curves evaluated at the same steps.

    Raises:
        ValueError: curves evaluated at different steps (runs of other budgets or intervals).
    """
    steps = [tuple(int(p["step"]) for p in curve) for curve in curves]
    if not curves or any(s != steps[0] for s in steps):
        raise ValueError(f"curves evaluated at different steps: {sorted(set(steps))}")
    by_step = list(zip(*([100 * p["success"] for p in curve] for curve in curves), strict=True))
    return MeanCurve(
        steps[0],
        tuple(statistics.fmean(v) for v in by_step),
        tuple(statistics.pstdev(v) for v in by_step),
        len(curves),
    )


def choose_budget(curves: Mapping[str, MeanCurve], tolerance: float) -> int:
    """The smallest evaluated step from which every curve stays within ``tolerance`` points of
    its own last value (at that step and every later evaluation): the budget at which each task
    has converged as far as its longest run shows. The last step when none is earlier.

    Example:
        >>> c = lambda *m: MeanCurve((1, 2, 3), m, (0, 0, 0), 1)
        >>> choose_budget({"u": c(50, 99, 100), "l": c(20, 90, 99.5)}, 2.0)
        3
        >>> choose_budget({"u": c(50, 99, 100), "l": c(20, 98, 99.5)}, 2.0)
        2
    """
    steps = next(iter(curves.values())).steps
    if any(c.steps != steps for c in curves.values()):
        raise ValueError("the curves were evaluated at different steps")
    for i, step in enumerate(steps):
        if all(abs(m - c.final) <= tolerance for c in curves.values() for m in c.mean[i:]):
            return step
    return steps[-1]


def load_curves(folder: Path, study: CurveStudy) -> dict[tuple[str, str], MeanCurve]:
    """(setting, task) -> its mean curve, from the finished runs under ``folder/runs``; a pair
    without a finished run is left out."""
    out = {}
    for setting in study.settings:
        for task in study.tasks:
            curves = [curve for _, curve in _run_curves(folder, setting, task)]
            if curves:
                out[(setting, task)] = mean_curve(curves)
    return out


def _run_curves(folder: Path, setting: str, task: str) -> list[tuple[int, list[dict]]]:
    """(seed, curve) of every finished run of ``setting`` on ``task`` that recorded one."""
    found = []
    for path in sorted((Path(folder) / "runs" / f"{setting}-{task}").glob("seed*/result.json")):
        curve = RunDir(path.parent).read_result().curve
        if curve:
            found.append((int(path.parent.name.removeprefix("seed")), curve))
    return found


def _cell(curve: MeanCurve, i: int) -> str:
    spread = f" ± {curve.std[i]:.1f}" if curve.seeds > 1 else ""
    return f"{curve.mean[i]:.1f}{spread}"


def _budget_line(study: CurveStudy, curves: Mapping[tuple[str, str], MeanCurve], last: int) -> str:
    chosen = {t: c for (s, t), c in curves.items() if s == study.budget_setting}
    missing = [t for t in study.tasks if t not in chosen]
    if missing:
        return f"Budget: not chosen yet ({study.budget_setting} lacks {', '.join(missing)})."
    return (
        f"Budget B = {choose_budget(chosen, study.tolerance):,} steps: the smallest evaluated "
        f"step from which every {study.budget_setting} curve stays within "
        f"{study.tolerance:g} points of its {last:,}-step value."
    )


def curves_markdown(study: CurveStudy, curves: Mapping[tuple[str, str], MeanCurve]) -> str:
    """The study's report: success per evaluated step (mean ± std over seeds), each pair's
    seeds, and the budget its ``budget_setting`` licenses (none for a study without one)."""
    lines = ["# Learning curves", ""]
    if not curves:
        return "\n".join([*lines, "No finished run yet.", ""])
    steps = next(iter(curves.values())).steps
    head = " | ".join(f"{s // 1000}k" if s % 1000 == 0 else str(s) for s in steps)
    lines += [
        f"| setting | task | seeds | {head} |",
        "|---|---|---:|" + "---:|" * len(steps),
    ]
    for (setting, task), curve in curves.items():
        cells = " | ".join(_cell(curve, i) for i in range(len(curve.steps)))
        lines.append(f"| {setting} | {task} | {curve.seeds} | {cells} |")
    if study.budget_setting is not None:
        lines += ["", _budget_line(study, curves, steps[-1])]
    lines.append("")
    return "\n".join(lines)


def curves_figure(study: CurveStudy, curves: Mapping[tuple[str, str], MeanCurve]):
    """One panel per task: success against steps, a line per setting with its seeds' spread,
    and the budget B once every task of the budget's setting has runs."""
    from matplotlib.figure import Figure

    tasks = [t for t in study.tasks if any(t == k[1] for k in curves)]
    chosen = {t: c for (s, t), c in curves.items() if s == study.budget_setting}
    whole = study.budget_setting is not None and set(chosen) == set(study.tasks)
    budget = choose_budget(chosen, study.tolerance) if whole else None
    fig = Figure(figsize=(4.2 * max(len(tasks), 1), 3.4), layout="constrained")
    axes = fig.subplots(1, max(len(tasks), 1), squeeze=False)[0]
    for ax, task in zip(axes, tasks, strict=False):
        for i, setting in enumerate(study.settings):
            curve = curves.get((setting, task))
            if curve is None:
                continue
            x = [s / 1000 for s in curve.steps]
            lo = [m - s for m, s in zip(curve.mean, curve.std, strict=True)]
            hi = [m + s for m, s in zip(curve.mean, curve.std, strict=True)]
            ax.plot(x, curve.mean, marker="o", ms=3, color=f"C{i}", label=setting)
            ax.fill_between(x, lo, hi, color=f"C{i}", alpha=0.2, lw=0)
        if budget is not None:
            ax.axvline(budget / 1000, color="grey", ls="--", lw=1)
            ax.text(budget / 1000, 3, f" B = {budget // 1000}k", color="grey", fontsize=8)
        ax.set_title(task)
        ax.set_xlabel("training steps (thousands)")
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("success % (mean ± std over seeds)")
    axes[0].legend(loc="center right")
    return fig


def _points(folder: Path, study: CurveStudy):
    """(setting, task, seed, point) of every evaluation of every finished run, in order."""
    for setting in study.settings:
        for task in study.tasks:
            for seed, curve in _run_curves(folder, setting, task):
                for point in curve:
                    yield setting, task, seed, point


def write_curves_report(folder: Path) -> str:
    """Write ``curves.md``, ``curves.csv`` (one row per run and step) and ``curves.png`` in a
    study folder from its runs; returns the markdown."""
    folder = Path(folder)
    study = CurveStudy.read(folder)
    curves = load_curves(folder, study)
    text = curves_markdown(study, curves)
    atomic_write_text(folder / "curves.md", text)
    table = io.StringIO(newline="")
    writer = csv.writer(table)
    writer.writerow(["setting", "task", "seed", "step", "success", "episode_length"])
    for setting, task, seed, point in _points(folder, study):
        row = [point["step"], point["success"], point.get("episode_length")]
        writer.writerow([setting, task, seed, *row])
    atomic_write_text(folder / "curves.csv", table.getvalue())
    if curves:
        write_figure(curves_figure(study, curves), folder / "curves.png", dpi=110)
    return text
