"""Running a benchmark grid: plan against what is committed, run what is left two lanes at a
time, export each run as it finishes into the committed results, and plan again until nothing
new can start. The plan itself (:mod:`.grid`) is pure."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

from ..io import atomic_write_text, copy_files, real_folder, refuse_linked
from ..results import LaunchRecord
from ..rundir import RunDir
from .derive import derivable_run, derive_run, keep_last_siblings
from .grid import Grid
from .grid_plan import Cell, cell_run, committed_reader, describe, plan_cells
from .plan import PLAN_FILE, PlannedRun, warn_provenance


def export_cell(run_dir: Path, cell: Cell, root: Path, derived_from: Cell | None = None) -> Path:
    """Copy a finished run's small files to the cell's committed place (and the stream's
    ``benchmark.json`` for its report title); a derived cell's ``run.json`` names its source.
    A link among the files is refused before anything is copied; a link under ``root`` where
    a file or folder goes is replaced, never written through.

    Raises:
        LinkedFileError: a file to copy is a symbolic link."""
    target = cell.result_dir(root)
    names = [n for n in RunDir.EXPORTED if os.path.lexists(Path(run_dir) / n)]
    pairs = [(Path(run_dir) / name, target / name) for name in names]
    refuse_linked(src for src, _ in pairs)
    real_folder(target, root)
    copy_files(pairs)
    if derived_from is not None:
        record = RunDir(target).read_run_record()
        record = record.replace(method=cell.label, derived_from=derived_from.name)
        RunDir(target).write_run_record(record)
    if RunDir(target).run_record_file.exists():
        warn_provenance(RunDir(target).read_run_record(), f"exporting {cell.name}")
    plan_file = Path(root) / cell.stream / PLAN_FILE
    if not plan_file.exists():
        atomic_write_text(plan_file, json.dumps({"stream": cell.stream}, indent=1))
    return target


def estimated_minutes(cell: Cell, root: Path, streams: Sequence[str]) -> float | None:
    """A cell's likely wall minutes from committed runs: the mean of its method on its stream,
    else of its method on the other streams, else of every run on its stream."""
    from .finished_runs import RunRecord
    from .tables import run_minutes

    def mean(pattern: str, where: Sequence[str]) -> float | None:
        found = []
        for stream in where:
            for seed_dir in sorted((Path(root) / stream).glob(pattern)):
                run = RunDir(seed_dir)
                if run.has_results():
                    found.append(run_minutes(RunRecord("", 0, run.stream_results())))
        return sum(found) / len(found) if found else None

    for pattern, where in (
        (f"{cell.method}/seed*", [cell.stream]),
        (f"{cell.method}/seed*", streams),
        ("*/seed*", [cell.stream]),
    ):
        minutes = mean(pattern, where)
        if minutes is not None:
            return minutes
    return None


def run_grid(
    grid: Grid,
    streams: Sequence[str],
    config_dir: Path,
    work: Path,
    root: Path,
    workers: int = 2,
    num_threads: int = 1,
    dry_run: bool = False,
    write_reports: Callable[[Sequence[str]], None] | None = None,
) -> int:
    """Plan, run what is left ``workers`` at a time, export each finished run, and plan again
    until nothing new can start (a sweep's end lets its method's seeds start). Returns the
    number of failed runs."""
    committed_per = committed_reader(grid, config_dir, root)
    sibling = grid_sibling(grid.methods, config_dir)
    derivable = grid_derivable(grid, config_dir, work, root)
    branch_source = grid_branch_source(grid, config_dir, work)

    def started(cell: Cell) -> bool:
        return RunDir(cell_run(cell, grid, config_dir, work).run_dir).progress_file.exists()

    def estimate(cell: Cell) -> float | None:
        return estimated_minutes(cell, root, grid.streams)

    failed = 0
    attempted: set[str] = set()
    while True:
        plan = plan_cells(grid, streams, committed_per, sibling, derivable, started, branch_source)
        for target, source, tasks in plan.branched if not dry_run else ():
            branch_cell(target, source, tasks, grid, config_dir, work, num_threads)
            print(f"[grid] {target.name}: its first {tasks} task(s) branched from {source.name}")
        for target, source in plan.derived if not dry_run else ():
            export_cell(source.result_dir(root), target, root, derived_from=source)
            print(f"[grid] {target.name}: the same run as {source.name}, copied")
        for target, source in plan.from_sibling if not dry_run else ():
            if committed_per(source) is not None:  # else once its sibling has trained
                out = derive_cell(target, source, grid, config_dir, work, root, num_threads)
                print(f"[grid] {target.name}: derived from {source.name}, exported to {out}")
        for line in describe(plan, estimate):
            print(line)
        for target, source, tasks in plan.branched if dry_run else ():
            print(
                f"[grid] {target.name}: would branch its first {tasks} task(s) from {source.name}"
            )
        todo = [c for c in plan.todo if c.name not in attempted]
        if dry_run:
            for cell in todo:
                run = cell_run(cell, grid, config_dir, work, num_threads)
                print(f"[grid] {cell.name}: {' '.join(run.command(sys.executable))}")
            return 0
        if not todo:
            break
        attempted |= {c.name for c in todo}
        failed += _run_cells(
            todo, grid, config_dir, work, root, workers, num_threads, write_reports
        )
    if write_reports is not None:
        write_reports(list(streams))
    return failed


def _run_cells(
    todo: Sequence[Cell],
    grid: Grid,
    config_dir: Path,
    work: Path,
    root: Path,
    workers: int,
    num_threads: int,
    write_reports: Callable[[Sequence[str]], None] | None,
) -> int:
    """Run ``todo`` ``workers`` at a time, exporting each as it finishes; the failures."""
    from .configs import prepare_datasets, runs_datasets
    from .finished_runs import warn_of_other_episodes
    from .launch import Reporter, run_env, run_local
    from .plan import pending_runs, provenance

    runs = [cell_run(c, grid, config_dir, work, num_threads) for c in todo]
    cells = {run.run_dir: cell for run, cell in zip(runs, todo, strict=True)}
    pending, made_on = [], provenance()
    for stream in dict.fromkeys(c.stream for c in todo):
        mine = [r for r in runs if cells[r.run_dir].stream == stream]
        pending += pending_runs(mine, stream, made_on)

    def export(run: PlannedRun, how: str = "exported to") -> None:
        cell = cells[run.run_dir]
        print(f"[grid] {cell.name}: {how} {export_cell(run.run_dir, cell, root)}")
        if write_reports is not None:
            write_reports([cell.stream])

    for run in runs:  # finished in ``work`` but stopped before its export
        if run not in pending and run.results_path.exists():
            export(run, "finished before its export, exported to")
    prepare_datasets(runs_datasets(pending))
    for stream in dict.fromkeys(cells[r.run_dir].stream for r in pending):
        mine = [r for r in pending if cells[r.run_dir].stream == stream]
        warn_of_other_episodes(stream, mine, [Path(root) / stream])
    reporter = Reporter(total=len(pending))

    def finished(run: PlannedRun, outcome: dict) -> None:
        reporter(run, outcome)
        if outcome["results"] is not None:
            export(run)

    try:
        run_local(pending, workers, finished, run_env(num_threads))
    finally:
        reporter.close()
    return len(reporter.failed)


def grid_sibling(methods: Sequence[str], config_dir: Path) -> Callable[[Cell], Cell | None]:
    """``sibling(cell)``: the keep-all cell of the same stream and seed whose run stands for
    a keep-last ``cell`` (:func:`keep_last_siblings` of the grid's method configs), or None."""
    import yaml

    configs = {}
    for method in methods:
        path = Path(config_dir) / "methods" / f"{method}.yaml"
        if path.is_file():
            configs[method] = yaml.safe_load(path.read_text()) or {}
    pairs = keep_last_siblings(configs)

    def sibling(cell):
        source = pairs.get(cell.method)
        if source is None or cell.extra or cell.sweep:
            return None
        return replace(cell, label=source, method=source)

    return sibling


def grid_derivable(grid: Grid, config_dir: Path, work: Path, root: Path) -> Callable[[Cell], bool]:
    """``derivable(cell)``: whether the grid's work directory still holds the cell's run with
    every checkpoint, the same run as the one committed under ``root``."""

    def derivable(cell) -> bool:
        run_dir = cell_run(cell, grid, config_dir, work).run_dir
        return derivable_run(run_dir, cell.result_dir(root))

    return derivable


def grid_branch_source(
    grid: Grid, config_dir: Path, work: Path
) -> Callable[[Cell, list[Cell]], tuple[Cell, int] | None]:
    """``branch_source(cell, finished)``: the run among ``finished`` (cells whose runs in
    ``work`` are whole) that ``cell``'s settings share most leading tasks with, and how many
    (:func:`~hispo_pl.benchmark.branch.best_source`); None when none shares a task."""
    from .branch import best_source, branch_settings

    def branch_source(cell: Cell, finished: list[Cell]) -> tuple[Cell, int] | None:
        candidates, by_name = {}, {}
        for done in finished:
            run = RunDir(cell_run(done, grid, config_dir, work).run_dir)
            candidates[done.name] = (run.decisions(), len(run.stream_results().stream))
            by_name[done.name] = done
        found = best_source(candidates, branch_settings(cell.extra))
        return None if found is None else (by_name[found[0]], found[1])

    return branch_source


def branch_cell(
    target: Cell,
    source: Cell,
    tasks: int,
    grid: Grid,
    config_dir: Path,
    work: Path,
    num_threads: int = 1,
) -> None:
    """Start ``target``'s run in ``work`` with ``source``'s first ``tasks`` tasks
    (:func:`~hispo_pl.benchmark.branch.branch_run`); the grid's runner then resumes it."""
    from .branch import branch_run, branch_settings

    run, made = (
        cell_run(target, grid, config_dir, work, num_threads),
        cell_run(source, grid, config_dir, work, num_threads),
    )
    record = LaunchRecord(branched_from=source.name)
    branch_run(made.run_dir, run.run_dir, tasks, branch_settings(target.extra), record)


def derive_cell(
    target: Cell,
    source: Cell,
    grid: Grid,
    config_dir: Path,
    work: Path,
    root: Path,
    num_threads: int = 1,
) -> Path:
    """Derive the grid cell ``target`` from its sibling ``source``'s run in ``work`` (its
    run directory where the grid would have trained it, with the ``run.json`` its launch would
    have written) and export it under ``root``; the exported directory."""
    import shlex
    import sys

    from .plan import provenance

    run, made = (
        cell_run(target, grid, config_dir, work, num_threads),
        cell_run(source, grid, config_dir, work, num_threads),
    )
    record = LaunchRecord.launched(
        method=run.method,
        seed=run.seed,
        stream=target.stream,
        steps_per_task=run.steps_per_task,
        argv=list(run.argv),
        command=shlex.join(run.command(sys.executable)),
    )
    record = record.merged(provenance()).replace(derived_from=source.name)
    derive_run(made.run_dir, run.run_dir, record)
    return export_cell(run.run_dir, target, root)
