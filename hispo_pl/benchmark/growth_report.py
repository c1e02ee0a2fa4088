"""Memory and performance against tasks on a grid's long streams (the paper's Figure 2d).

MEM after each task is measured in the runs of the methods that decide their memory (HiSPO,
CSPO, HiLOW: each run's ``mem_per_task``) and grown from the structure of those whose memory
follows from it (SCN, FTN, PNN: :mod:`.growth`), with the structure checked against the SCN
runs; PER after each task comes from each run's success matrix. The grid report writes them for
a grid with a random stream (:func:`has_random_streams`): ``growth.md`` (the fitted growth per
method and stream, the check, the runs not committed yet), ``growth-findings.md`` (what the runs
show, in sentences filled from them), ``memory_growth.png`` and ``per_after_task.png``.

    data = growth_data(grid, Committed(root))
    print(growth_markdown(grid, data))
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..results import CriticDecision, Decision, LossDecision, ZeroShotDecision
from ..tasks import parse_random_stream, parse_task, stream_specs

STRUCTURAL = ("scn", "ftn", "pnn")  # memory from the structure alone (grown, not trained)
FIGURES = ("memory_growth.png", "per_after_task.png")
_ANCHORED = (LossDecision, CriticDecision, ZeroShotDecision)  # records that count anchors


def has_random_streams(streams: Sequence[str]) -> bool:
    """Whether a grid's streams include a random one: a study of long streams, which gets the
    growth report."""
    return any(parse_random_stream(s) is not None for s in streams)


def family_of(stream: str) -> str:
    """The task family a stream draws from: ``random-antmaze-8@3`` → ``antmaze``."""
    random = parse_random_stream(stream)
    return random[0] if random else parse_task(stream_specs(stream)[0]).family


def per_after_each_task(R: Sequence[Sequence[float | None]]) -> list[float]:
    """PER after each task ``k``: the mean success over the tasks seen so far, ``R[k][:k+1]``.

    Example:
        >>> per_after_each_task([[1.0, 0.0], [0.5, 1.0]])
        [1.0, 0.75]
    """
    return [float(np.mean([float(v) for v in row[: k + 1]])) for k, row in enumerate(R)]


def anchors_after_each_task(decisions: Sequence[Decision], n_tasks: int) -> list[int] | None:
    """The anchors a run holds after each task, summed over its subspaces (each subspace's
    count after its last decision of the task, kept until its next); None for a run that made
    no decision on anchors (SCN, PNN)."""
    counts: dict[str, int] = {}
    after: list[int] = []
    anchored = [d for d in decisions if isinstance(d, _ANCHORED) and d.anchors is not None]
    if not anchored:
        return None
    for task in range(n_tasks):
        for d in anchored:
            if d.task == task:
                counts[d.subspace] = int(d.anchors)
        after.append(sum(counts.values()))
    return after


@dataclass(frozen=True)
class Growth:
    """How a curve of values after each task grows: per task over the first half of the
    stream (tasks 2..h, h = n // 2) and over the last half (tasks h+1..n), the least-squares
    slope over all n tasks, and the last value. Each is linear in the curve, so the growth of
    the mean curve over seeds is the mean of the seeds' growths."""

    first_half: float | None
    last_half: float | None
    slope: float | None
    final: float

    @classmethod
    def of(cls, values: Sequence[float]) -> Growth:
        """Example:
        >>> Growth.of([1.0, 2.0, 2.5, 3.0])
        Growth(first_half=1.0, last_half=0.5, slope=0.65, final=3.0)
        """
        v = np.asarray(values, dtype=float)
        n, h = len(v), len(v) // 2
        first = float((v[h - 1] - v[0]) / (h - 1)) if h >= 2 else None
        last = float((v[-1] - v[h - 1]) / (n - h)) if h >= 1 else None
        slope = float(np.polyfit(np.arange(1, n + 1), v, 1)[0]) if n >= 2 else None
        return cls(first, last, None if slope is None else round(slope, 12), float(v[-1]))


@dataclass(frozen=True)
class RunCurves:
    """One committed run's curves after each task: MEM (None: not measured after every task),
    PER (from its success matrix) and the anchors it holds (None: it decides none)."""

    stream: str
    method: str
    seed: int
    memory: list[float] | None
    per: list[float]
    anchors: list[int] | None


@dataclass
class GrowthData:
    """What the growth report draws from: each committed run's curves, the structural memory of
    SCN / FTN / PNN per (family, method) for the family's longest stream, and the grid's cells
    not committed yet as (stream, method, seed)."""

    runs: list[RunCurves]
    structure: dict[tuple[str, str], list[float]] = field(default_factory=dict)
    missing: list[tuple[str, str, int]] = field(default_factory=list)
    families: dict[str, list[str]] = field(default_factory=dict)  # family -> its streams

    def of(self, family: str, method: str) -> list[RunCurves]:
        streams = self.families.get(family, [])
        return [r for r in self.runs if r.stream in streams and r.method == method]


def growth_data(grid, committed, config_dir: Path | None = None) -> GrowthData:
    """The curves of every committed run of ``grid`` (a :class:`~.grid.Grid`) under
    ``committed`` (a :class:`~.grid_report.Committed`), the structural memory of the methods
    whose memory follows from their structure (grown from ``config_dir``'s configs with the
    grid's fit arguments, as long as the family's longest committed run or, before any, its
    first stream), and the cells not committed yet."""
    from ..config_files import config_root
    from .growth import module_for, structural_memory
    from .plan import stream_config_path, stream_fit_args

    config_dir = Path(config_dir) if config_dir is not None else config_root()
    families: dict[str, list[str]] = {}
    for stream in grid.streams:
        families.setdefault(family_of(stream), []).append(stream)
    runs, missing = [], []
    for stream in grid.streams:
        done = {(r.method, r.seed): r for r in committed.records(stream)}
        for method in grid.methods:
            for seed in grid.seeds:
                record = done.get((method, seed))
                if record is None:
                    missing.append((stream, method, seed))
                    continue
                results = record.results
                memory = results.mem_per_task
                runs.append(
                    RunCurves(
                        stream,
                        method,
                        seed,
                        None if not memory or None in memory else [float(m) for m in memory],
                        per_after_each_task(results.R),
                        anchors_after_each_task(record.decisions, len(results.stream)),
                    )
                )
    structure = {}
    for family, streams in families.items():
        lengths = [len(r.per) for r in runs if r.stream in streams]
        n = max(lengths) if lengths else max(len(stream_specs(s)) for s in streams)
        stream = streams[0]
        for method in STRUCTURAL:
            method_config = config_dir / "methods" / f"{method}.yaml"
            if not method_config.is_file():
                continue
            configs = [stream_config_path(stream, config_dir), method_config]
            module = module_for(configs, *stream_fit_args(stream), *grid.extra)
            structure[(family, method)] = structural_memory(module, n)
    return GrowthData(runs, structure, missing, families)


# --- the report's text --------------------------------------------------------------------------


def _family_title(family: str, streams: Sequence[str]) -> str:
    lengths = sorted({len(stream_specs(s)) for s in streams})
    tasks = "/".join(map(str, lengths))
    return f"{family} ({len(streams)} stream{'s' * (len(streams) > 1)} of {tasks} tasks)"


def _num(value: float | None, digits: int = 2) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def _mean_curve(curves: Sequence[Sequence[float]]) -> list[float]:
    n = min(len(c) for c in curves)
    return [float(v) for v in np.mean([list(c)[:n] for c in curves], axis=0)]


def _row(method: str, stream: str, seeds: str, runs: Sequence[RunCurves]) -> str | None:
    memory = [r.memory for r in runs if r.memory is not None]
    anchors = [r.anchors for r in runs if r.anchors is not None]
    per = float(np.mean([r.per[-1] for r in runs])) * 100
    cells = ["", "", ""]
    if anchors:
        anc = Growth.of(_mean_curve(anchors))
        cells = [_num(anc.first_half), _num(anc.last_half), f"{anc.final:.0f}"]
    cells += ["", "", "", ""]
    if memory:
        mem = Growth.of(_mean_curve(memory))
        cells[3:] = [_num(v) for v in (mem.first_half, mem.last_half, mem.slope, mem.final)]
    cells.append(f"{per:.1f}")
    return f"| {method} | {stream} | {seeds} | " + " | ".join(cells) + " |"


def structure_check(data: GrowthData) -> str:
    """A sentence on how SCN's structural memory compares with its committed runs' measured
    MEM after each task; empty when no SCN run measured it."""
    gaps = []
    for family in data.families:
        grown = data.structure.get((family, "scn"))
        for run in data.of(family, "scn"):
            if grown is None or run.memory is None:
                continue
            ours = np.asarray(grown[: len(run.memory)])
            gaps.append((float(np.max(np.abs(ours / np.asarray(run.memory) - 1))), run))
    if not gaps:
        return ""
    worst, run = max(gaps, key=lambda g: g[0])
    if worst <= 1e-6:
        return (
            f"SCN's memory grown from its structure equals the measured MEM of its {len(gaps)} "
            f"committed run(s) after every task (largest relative gap {worst:.1e})."
        )
    return (
        f"SCN's memory grown from its structure differs from its committed runs' measured MEM "
        f"(largest relative gap {worst:.1%}, {run.stream} seed {run.seed}): the runs' "
        "configuration is not the one the structure was grown from."
    )


def missing_lines(data: GrowthData) -> list[str]:
    """One line per stream with cells not committed yet: which methods and seeds."""
    by_stream: dict[str, dict[str, list[int]]] = {}
    for stream, method, seed in data.missing:
        by_stream.setdefault(stream, {}).setdefault(method, []).append(seed)
    return [
        f"- {stream}: "
        + ", ".join(f"{m} (seed {', '.join(map(str, s))})" for m, s in methods.items())
        for stream, methods in by_stream.items()
    ]


def growth_markdown(grid, data: GrowthData) -> str:
    """The fitted growth per method and stream (measured runs, then the structural methods per
    family), the structure's check against SCN's runs, the figures and the runs missing."""
    lines = [
        f"# Memory growth: grid {grid.name}\n",
        "| method | stream | seeds | anchors / task, first half | anchors / task, last half | "
        "anchors at the end | MEM / task, first half | MEM / task, last half | MEM slope | "
        "final MEM | final PER |",
        "|---|---|---:|" + "---:|" * 8,
    ]
    for family, streams in data.families.items():
        for stream in streams:
            for method in grid.methods:
                runs = [r for r in data.runs if r.stream == stream and r.method == method]
                if runs:
                    lines.append(_row(method, stream, str(len(runs)), runs))
        for method in STRUCTURAL:
            grown = data.structure.get((family, method))
            if grown is None:
                continue
            mem = Growth.of(grown)
            cells = ["", "", "", *(_num(v) for v in (mem.first_half, mem.last_half, mem.slope))]
            name = f"random-{family}-{len(grown)}" if has_random_streams(streams) else family
            lines.append(
                f"| {method} (structure) | {name} | | "
                + " | ".join([*cells, _num(mem.final), ""])
                + " |"
            )
    legend = (
        "\nAfter each task of a stream of n tasks (h = n // 2): anchors held (summed over a "
        "method's subspaces) and MEM (stored size over one single-task model), each per task "
        "over the first half (tasks 2..h) and the last half (tasks h+1..n); the MEM slope is a "
        "least-squares line through MEM after every task; final PER is the mean success ×100 "
        "over the stream's tasks after its last. Means over the committed seeds. Rows "
        "'(structure)' are grown from the method's configuration without training "
        "(`hispo_pl.benchmark.growth`): they hold for any stream of the family of that length.\n"
    )
    lines.append(legend)
    check = structure_check(data)
    if check:
        lines.append(check + "\n")
    if data.runs:
        lines += [
            "![MEM against tasks, per stream family](memory_growth.png)\n",
            "![PER after each task, per stream family](per_after_task.png)\n",
        ]
    gaps = missing_lines(data)
    if gaps:
        total = len(data.missing) + len(data.runs)
        lines += [f"Runs not committed yet ({len(data.missing)} of {total}):\n", *gaps, ""]
    return "\n".join(lines)


def _sentence(method: str, family: str, data: GrowthData) -> str | None:
    runs = data.of(family, method)
    memory = [r.memory for r in runs if r.memory is not None]
    if not runs:
        return None
    per = 100 * float(np.mean([r.per[-1] for r in runs]))
    text = f"{method} ({len(runs)} run{'s' * (len(runs) > 1)})"
    if method in STRUCTURAL or not memory:
        return f"{text}: PER after the last task {per:.1f}."
    mem = Growth.of(_mean_curve(memory))
    if mem.first_half is None or mem.last_half is None:
        shape = f"ends at MEM {mem.final:.2f}"
    else:
        slowing = "slowing: sublinear" if mem.last_half < mem.first_half else "not slowing"
        shape = (
            f"adds {mem.last_half:.2f} MEM per task over the last half of a stream against "
            f"{mem.first_half:.2f} over the first ({slowing}) and ends at {mem.final:.2f}"
        )
    return f"{text} {shape}; PER after the last task {per:.1f}."


def findings_markdown(grid, data: GrowthData) -> str:
    """What the committed runs show, per family, in sentences filled from them; which runs are
    missing when some are, and no figure at all before any run."""
    lines = ["# What the runs show\n"]
    total = len(data.missing) + len(data.runs)
    if not data.runs:
        lines.append(
            f"No run of the grid {grid.name} is committed yet (0 of {total}): nothing is "
            "measured, so nothing is set beside the paper here; the runs still to make are "
            "listed under the table.\n"
        )
        return "\n".join(lines)
    if data.missing:
        lines.append(
            f"From {len(data.runs)} of the grid's {total} runs (the others are listed under the "
            "table), so each line holds only for the runs it counts.\n"
        )
    for family, streams in data.families.items():
        structure = []
        for method in STRUCTURAL:
            grown = data.structure.get((family, method))
            if grown is not None:
                last = Growth.of(grown).last_half
                structure.append(
                    f"{method} {grown[-1]:.2f} after {len(grown)} tasks"
                    + ("" if last is None else f" ({last:.2f} per task over the last half)")
                )
        sentences = [s for m in grid.methods if (s := _sentence(m, family, data))]
        if not sentences:
            continue
        with_runs = len({r.stream for r in data.runs if r.stream in streams})
        head = f"- **{_family_title(family, streams)}**, {with_runs} with runs: "
        lines.append(head + " ".join(sentences))
        if structure:
            lines.append(f"  From their structure: {'; '.join(structure)}.")
    lines.append("")
    return "\n".join(lines)


# --- the figures --------------------------------------------------------------------------------


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
    mean = np.multiply(_mean_curve(x_runs), scale)
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
        for method in STRUCTURAL:
            grown = data.structure.get((family, method))
            if grown is None:
                continue
            ax.plot(
                range(1, len(grown) + 1),
                grown,
                ls="--",
                lw=1.2,
                color=styles[method]["color"],
                label=f"{method} (structure)",
            )
            if method != "pnn":
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


# --- memory after each task on a grid's fixed streams (the paper's Figure 3) ---------------------

DECIDING = ("hispo", "hispo-pac", "hilow", "cspo", "csp")  # methods whose memory is decided


def memory_per_task_markdown(grid, committed) -> str:
    """MEM and anchors after each task of every stream of ``grid``, for the methods that decide
    their memory, mean over the committed seeds (MEM over the seeds that measured it after each
    task); empty when no such method has a run. The paper's Figure 3 draws this for HiLOW on an
    AntMaze stream."""
    lines = []
    for stream in grid.streams:
        for method in (m for m in DECIDING if m in grid.methods):
            runs = [r for r in committed.records(stream) if r.method == method]
            if not runs:
                continue
            n = len(runs[0].results.stream)
            mems = [r.results.mem_per_task for r in runs]
            mems = [m for m in mems if m and None not in m and len(m) == n]
            anchors = [anchors_after_each_task(r.decisions, n) for r in runs]
            anchors = [a for a in anchors if a is not None]
            mem = " → ".join(f"{v:.2f}" for v in _mean_curve(mems)) if mems else "not measured"
            held = " → ".join(f"{round(v, 2):g}" for v in _mean_curve(anchors)) if anchors else ""
            lines.append(f"| {stream} | {method} | {len(runs)} | {len(mems)} | {mem} | {held} |")
    if not lines:
        return ""
    head = [
        f"# Memory after each task: grid {grid.name}\n",
        "| stream | method | seeds | seeds measuring MEM per task | MEM after each task | "
        "anchors after each task |",
        "|---|---|---:|---:|---|---|",
    ]
    legend = (
        "\nMEM (stored size over one single-task model) and anchors held (summed over a "
        "method's subspaces, from its decisions) after each task, mean over seeds. Runs made "
        "before MEM was recorded after each task count for the anchors only. The paper's "
        "Figure 3 plots memory usage on an AntMaze stream to show that HiLOW's low-rank anchors "
        "make smaller updates than HiSPO's; its values are not in the paper's text, so this "
        "table stands beside its claim, not its numbers.\n"
    )
    return "\n".join(head + lines) + "\n" + legend
