"""What a grid chose and what it cost, from the committed run files: each sweep's PER per
value with the value chosen, and the wall time of the runs per method, split between
training, evaluation and the subspace search."""

from __future__ import annotations

from pathlib import Path

from ..rundir import RunDir
from .finished_runs import RunRecord
from .grid import SWEEPS_DIR, Grid
from .grid_plan import chosen_value
from .tables import derived_footnote, derived_method, run_minutes

PHASES = ("training", "evaluation", "search")


def sweep_per(root: Path, stream: str, label: str, seed: int) -> float | None:
    run = RunDir(Path(root) / stream / SWEEPS_DIR / label / f"seed{seed}")
    return float(run.stream_results().metrics["PER"]) if run.has_results() else None


def tree_tasks(root: Path, stream: str, sweep) -> str:
    """A sweep tree's cost on one stream: the tasks its committed runs trained, of the
    tasks they hold (a branched run's ``run.json`` says how many it copied)."""
    trained = held = 0
    for value in sweep.values:
        run = RunDir(Path(root) / stream / SWEEPS_DIR / sweep.label(value) / f"seed{sweep.seed}")
        if not run.has_results():
            continue
        tasks = len(run.stream_results().stream)
        copied = run.read_run_record().branched_tasks or 0
        trained, held = trained + tasks - copied, held + tasks
    return f"{trained} of {held}" if held else ""


def sweeps_markdown(grid: Grid, root: Path) -> str:
    """Each sweep's PER per stream and value (on its seed); the chosen value in bold. Empty
    for a grid without sweeps."""
    if not grid.sweeps:
        return ""
    lines = [f"# Sweeps: grid {grid.name}\n"]
    for method, sweep in grid.sweeps.items():
        tree = " | tasks trained (of all values')" if sweep.branch else ""
        lines += [
            f"### {method}: {sweep.name} (`--{sweep.key}`), seed {sweep.seed}\n",
            "| stream | " + " | ".join(f"{v:g}" for v in sweep.values) + f" | chosen{tree} |",
            "|---|" + "---:|" * (len(sweep.values) + 1 + bool(tree)),
        ]
        for stream in grid.streams:
            pers = {v: sweep_per(root, stream, sweep.label(v), sweep.seed) for v in sweep.values}
            best = chosen_value(sweep, pers)
            cells = [
                "" if p is None else (f"**{100 * p:.1f}**" if v == best else f"{100 * p:.1f}")
                for v, p in pers.items()
            ]
            if sweep.branch:
                cells.append(
                    f"{'' if best is None else f'{best:g}'} | {tree_tasks(root, stream, sweep)}"
                )
            else:
                cells.append("" if best is None else f"{best:g}")
            lines.append(f"| {stream} | " + " | ".join(cells) + " |")
        lines.append("")
    legend = (
        "PER ×100 of each value on one seed; the chosen value (the best PER, the first listed "
        "on a tie) is what every seed of the method runs at.\n"
    )
    if any(sweep.branch for sweep in grid.sweeps.values()):
        legend += (
            "A tree's runs share the tasks they train alike (a pruning tolerance's: those before "
            "their first differing decision; the penalty's λ: task 1), copied from a finished "
            "value: its last column counts the tasks they trained, of all the tasks their runs "
            "hold.\n"
        )
    return "\n".join(lines) + legend


def _copied_from_sweep(record: RunRecord, root: Path) -> bool:
    """A seed copied from its sweep (``run.json`` names the sweep run it is): its time is
    counted once, with the sweep's runs."""
    parts = Path(record.meta.derived_from or "").parts
    if len(parts) < 3:  # not derived, or not from a grid's cell
        return False
    stream, label, seed = parts[-3:]
    return (root / stream / SWEEPS_DIR / label / seed).is_dir()


def _costed_runs(grid: Grid, committed) -> tuple[dict, dict]:
    """The committed runs the cost counts, per method as (stream, record), sweeps included
    and a seed copied from its sweep left out; and the derived ones, per method."""
    per_method: dict[str, list[tuple[str, RunRecord]]] = {}
    derived: dict[str, list[tuple[str, int, str]]] = {}
    for stream in grid.streams:
        for record in committed.records(stream):
            if record.method in grid.methods and not _copied_from_sweep(record, committed.root):
                per_method.setdefault(record.method, []).append((stream, record))
                if record.derived_from:
                    where = (stream, record.seed, record.derived_from)
                    derived.setdefault(record.method, []).append(where)
        for seed_dir in sorted((committed.root / stream / SWEEPS_DIR).glob("*/seed*")):
            run = RunDir(seed_dir)
            if run.has_results():
                method = seed_dir.parent.name.split("-")[0]
                record = RunRecord(method, 0, run.stream_results())
                per_method.setdefault(method, []).append((stream, record))
    return per_method, derived


def _parts_lines(grid: Grid, per_method: dict) -> list[str]:
    """Wall hours per part of the grid (its named sets of streams), for a grid with parts."""
    if not grid.parts:
        return []
    lines = ["", "| part | streams | runs | hours |", "|---|---|---:|---:|"]
    for part, streams in grid.parts.items():
        runs = [r for found in per_method.values() for s, r in found if s in streams]
        hours = sum(run_minutes(r) for r in runs) / 60
        lines.append(f"| {part} | {', '.join(streams)} | {len(runs)} | {hours:.1f} |")
    return lines


def cost_markdown(grid: Grid, committed) -> str:
    """What the committed runs of the grid cost: wall hours per method (sweeps included) and
    the share of training, in-fit evaluation and the subspace search; then per part."""
    per_method, derived = _costed_runs(grid, committed)
    lines = [
        f"# Cost: grid {grid.name}\n",
        "| method | runs | hours | minutes per run | training | evaluation | search |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    total_runs, total_minutes = 0, 0.0
    for method in [m for m in grid.methods if m in per_method]:
        records = [r for _, r in per_method[method]]
        minutes = sum(run_minutes(r) for r in records)
        phases = {p: 0.0 for p in PHASES}
        for r in records:
            for task in r.results.phase_time_s or []:
                for p in PHASES:
                    phases[p] += float(task.get(p, 0.0))
        spent = sum(phases.values()) or 1.0
        shares = [f"{100 * phases[p] / spent:.0f} %" for p in PHASES]
        lines.append(
            f"| {derived_method(method, derived.get(method))} | {len(records)} | "
            f"{minutes / 60:.1f} | {minutes / len(records):.1f} | " + " | ".join(shares) + " |"
        )
        total_runs += len(records)
        total_minutes += minutes
    if total_runs == 0:
        return ""
    lines.append(f"| all | {total_runs} | {total_minutes / 60:.1f} | | | | |")
    lines += _parts_lines(grid, per_method)
    legend = (
        "\nWall time of the committed runs (the sum of their tasks' wall times: one torch "
        "thread each, two runs at a time on 2 CPU cores), sweeps included and a seed copied "
        "from its sweep counted once; the shares split "
        "each task's time between gradient steps, the rollout evaluation after each task and "
        "the subspace search before its decision."
        + (" The parts' table sums the same runs per part of the grid." if grid.parts else "")
        + "\n"
    )
    notes = [
        derived_footnote(m, derived[m], len(per_method[m])) + " Their minutes are the "
        "re-evaluation they ran, not training."
        for m in derived
    ]
    return "\n".join(lines) + "\n" + legend + "".join(f"\n{note}\n" for note in notes)
