"""A grid's planning against what is already committed, pure (:func:`plan_cells` reads results
through a function, :func:`committed_reader` makes one): its cells (one run each), the value a
sweep chose, what is done, to run, to derive or branch and waiting, and the benchmark run of a
cell. :mod:`.grid` defines the grid; :mod:`.grid_run` runs and exports.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import RunDirError
from ..rundir import RunDir
from .configs import saved_setting
from .derive import sibling_derivations
from .grid import SWEEPS_DIR, Grid, Sweep
from .plan import PlannedRun, plan_run, planned_tasks, stream_config_path, stream_fit_args


@dataclass(frozen=True)
class Cell:
    """One run of a grid: ``label`` names its folder (the method, or a sweep's value)."""

    stream: str
    label: str
    method: str
    seed: int
    extra: tuple[str, ...] = ()
    sweep: bool = False

    @property
    def name(self) -> str:
        return f"{self.stream}/{self.label}/seed{self.seed}"

    def result_dir(self, root: Path) -> Path:
        """Where its committed files live under the results root."""
        stream_dir = Path(root) / self.stream
        return (
            (stream_dir / SWEEPS_DIR if self.sweep else stream_dir)
            / self.label
            / (f"seed{self.seed}")
        )


def chosen_value(sweep: Sweep, per: dict[float, float | None]) -> float | None:
    """The value of ``sweep`` with the best PER (``per[value]``; None while not run), None
    until every value has a result; a tie goes to the value listed first."""
    scores = [per.get(v) for v in sweep.values]
    if any(s is None for s in scores):
        return None
    return sweep.values[max(range(len(scores)), key=lambda i: (scores[i], -i))]


def _flag(sweep: Sweep, value: float) -> tuple[str, ...]:
    return tuple(arg for key in sweep.keys for arg in (f"--{key}", f"{value:g}"))


@dataclass
class GridPlan:
    """What a grid still needs: runs to train, runs to copy from an identical one (target,
    source), keep-last runs to derive from their keep-all sibling's checkpoints (target,
    source: :mod:`~hispo_pl.benchmark.derive`), runs of a sweep tree to branch before they
    train on (target, source, shared tasks: :mod:`~hispo_pl.benchmark.branch`; each is in
    ``todo`` too), and lines for what waits on something else."""

    todo: list[Cell] = field(default_factory=list)
    branched: list[tuple[Cell, Cell, int]] = field(default_factory=list)
    derived: list[tuple[Cell, Cell]] = field(default_factory=list)
    from_sibling: list[tuple[Cell, Cell]] = field(default_factory=list)
    waiting: list[str] = field(default_factory=list)
    done: list[Cell] = field(default_factory=list)


def plan_cells(
    grid: Grid,
    streams: Sequence[str],
    committed_per: Callable[[Cell], float | None],
    sibling: Callable[[Cell], Cell | None] = lambda cell: None,
    derivable: Callable[[Cell], bool] = lambda cell: False,
    started: Callable[[Cell], bool] = lambda cell: False,
    branch_source: Callable[[Cell, list[Cell]], tuple[Cell, int] | None] = lambda c, done: None,
) -> GridPlan:
    """Every cell of ``streams``, sorted into done (``committed_per`` gives its PER), to run,
    to derive and waiting. Streams outer, then the grid's methods, then seeds. A cell with a
    ``sibling`` to run or a ``derivable`` one done is derived from it
    (:func:`~hispo_pl.benchmark.derive.sibling_derivations`). In a branch sweep, a value not
    ``started`` is branched from the ``branch_source`` among the done and ``derivable`` values
    (the one it shares most tasks with), and waits while the first value has not finished."""
    plan = GridPlan()
    for stream in streams:
        for method in grid.methods:
            sweep = grid.sweeps.get(method)
            if sweep is None:
                cells = [Cell(stream, method, method, s) for s in grid.seeds]
                for cell in cells:
                    (plan.done if committed_per(cell) is not None else plan.todo).append(cell)
                continue
            sweep_cells = {
                v: Cell(stream, sweep.label(v), method, sweep.seed, _flag(sweep, v), True)
                for v in sweep.values
            }
            if sweep.branch:
                _plan_tree(plan, list(sweep_cells.values()), committed_per, derivable, started,
                           branch_source)  # fmt: skip
            else:
                for cell in sweep_cells.values():
                    (plan.done if committed_per(cell) is not None else plan.todo).append(cell)
            best = chosen_value(sweep, {v: committed_per(c) for v, c in sweep_cells.items()})
            if best is None:
                plan.waiting.append(
                    f"{stream}/{method}: {len(grid.seeds)} seed(s) wait for the {sweep.name} sweep"
                )
                continue
            for seed in grid.seeds:
                cell = Cell(stream, method, method, seed, _flag(sweep, best))
                if committed_per(cell) is not None:
                    plan.done.append(cell)
                elif seed == sweep.seed:
                    plan.derived.append((cell, sweep_cells[best]))
                else:
                    plan.todo.append(cell)
    plan.todo, plan.from_sibling = sibling_derivations(plan.todo, plan.done, sibling, derivable)
    return plan


def _plan_tree(
    plan: GridPlan,
    cells: list[Cell],
    committed_per: Callable[[Cell], float | None],
    derivable: Callable[[Cell], bool],
    started: Callable[[Cell], bool],
    branch_source: Callable[[Cell, list[Cell]], tuple[Cell, int] | None],
) -> None:
    """A branch sweep's cells into ``plan``: the first value (the root) and every started run
    train; another value is branched from the finished run it shares most tasks with, waits
    for the root while that has not finished, and trains from the start when it shares none
    with a finished run (or none has its checkpoints left)."""
    done = [c for c in cells if committed_per(c) is not None]
    plan.done += done
    finished = [c for c in done if derivable(c)]
    for i, cell in enumerate(cells):
        if cell in done:
            continue
        if i == 0 or started(cell):
            plan.todo.append(cell)
            continue
        found = branch_source(cell, finished)
        if found is not None:
            plan.branched.append((cell, *found))
            plan.todo.append(cell)
        elif cells[0] not in done:
            plan.waiting.append(f"{cell.name} waits for the tree's first value {cells[0].label}")
        else:
            plan.todo.append(cell)


def cell_run(
    cell: Cell, grid: Grid, config_dir: Path, work: Path, num_threads: int = 1
) -> PlannedRun:
    """The benchmark run of ``cell``, logging to ``work/<stream>/runs/<label>/seed<S>``."""
    config_dir = Path(config_dir)
    return plan_run(
        stream_config_path(cell.stream, config_dir),
        (config_dir / "methods" / f"{cell.method}.yaml").resolve(),
        cell.label,
        cell.seed,
        Path(work) / cell.stream,
        num_threads,
        grid.steps_per_task,
        (*stream_fit_args(cell.stream), *grid.extra, *cell.extra),
    )


def committed_reader(grid: Grid, config_dir: Path, root: Path) -> Callable[[Cell], float | None]:
    """``committed_per(cell)``: the PER of the cell's committed run under ``root``, or None
    when there is none, its files cannot be read, it trained other tasks than the grid's
    stream (an earlier version of the stream) or at another budget, or, for a cell with a
    setting of its own, it ran another value of it. A cell without a committed PER is run
    again."""
    tasks: dict[str, list[str]] = {}
    budgets: dict[str, int | None] = {}

    def committed_per(cell: Cell) -> float | None:
        run = RunDir(cell.result_dir(root))
        if not run.has_results():
            return None
        try:
            results, meta = run.stream_results(), run.read_run_record()
        except RunDirError:
            return None
        if cell.stream not in tasks:
            planned = cell_run(cell, grid, config_dir, root)
            tasks[cell.stream], budgets[cell.stream] = (
                planned_tasks(planned),
                planned.steps_per_task,
            )
        if results.stream != tasks[cell.stream]:
            return None
        steps = meta.steps_per_task
        if steps is not None and steps != budgets[cell.stream]:
            return None
        for key, value in zip(cell.extra[::2], cell.extra[1::2], strict=True):
            saved = saved_setting(run.config_file, key.removeprefix("--"))
            if saved is None or float(saved) != float(value):
                return None
        return float(results.metrics["PER"])

    return committed_per


def describe(plan: GridPlan, estimate: Callable[[Cell], float | None]) -> list[str]:
    """The plan as printed lines: per stream, what is done, to run (with its estimated
    minutes from committed runs of the same method), derived and waiting."""
    lines = []
    streams = dict.fromkeys(
        c.stream
        for c in [*plan.done, *plan.todo] + [t for t, _ in plan.derived + plan.from_sibling]
    )
    for stream in streams:
        todo = [c for c in plan.todo if c.stream == stream]
        minutes = [estimate(c) for c in todo]
        known = [m for m in minutes if m is not None]
        cost = f" (about {sum(known) / 60:.1f} h of runs)" if known else ""
        if known and len(known) < len(minutes):
            cost = f" (about {sum(known) / 60:.1f} h for the {len(known)} with a timing)"
        lines.append(
            f"[grid] {stream}: {sum(c.stream == stream for c in plan.done)} done, "
            f"{len(todo)} to run{cost}, "
            f"{sum(t.stream == stream for t, _ in plan.derived)} to copy from their sweep, "
            f"{sum(t.stream == stream for t, _ in plan.from_sibling)} to derive from a sibling"
        )
    lines += [f"[grid] {line}" for line in plan.waiting]
    return lines
