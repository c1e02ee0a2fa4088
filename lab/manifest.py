"""Where each reference result came from: a ``MANIFEST.md`` per reference folder of
``docs/results`` listing, per run, the code's commit, the command and the machine, read from
the run's own ``run.json`` alone (its commit recorded at launch, ``made_on``; for runs launched
before launches recorded it, ``committed_in``: the commit that committed the run). Generated,
never typed: ``python -m lab manifests``."""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass
from pathlib import Path

from hispo_pl.benchmark.markdown import cell, code_cell
from hispo_pl.benchmark.plan import launch_commits
from hispo_pl.io import atomic_write_text
from hispo_pl.results import LaunchRecord
from hispo_pl.rundir import RunDir

# the streams' reference runs (and the grid's reports over them); every other folder of
# docs/results is a study
REFERENCE_FOLDERS = (
    "pointmaze-1",
    "pointmaze-2",
    "antmaze-1",
    "antmaze-2",
    "videogame-1",
    "videogame-2",
    "pointmaze-1-paper",
    "pointmaze-2-paper",
    "antmaze-1-paper",
    "grid-paper",
    "paper-protocol/pointmaze-1",
    "paper-protocol/pointmaze-2",
    "paper-protocol/grid-paper-protocol",
    "demo",
)
MANIFEST = "MANIFEST.md"


@dataclass(frozen=True)
class Provenance:
    """One row of a manifest: a run (or a folder of reports) and where it came from (the
    command as markdown: code, or why there is none)."""

    run: str
    commit: str
    command: str
    machine: str
    trained_in: str | None = None  # the run directory, where the run recorded one


def fit_command(argv: list[str]) -> str:
    """A run's recorded ``python -m hispo_pl.cli ...`` arguments as the ``hispo-pl`` command a
    checkout runs: config paths from ``configs/`` on, the rest as recorded."""
    args = [str(a) for a in argv]
    args = args[2:] if args[:2] == ["-m", "hispo_pl.cli"] else args
    shown = [a[a.index("configs/") :] if "/configs/" in a else a for a in args]
    return "hispo-pl " + " ".join(shown)


def machine_text(machine: dict | None) -> str:
    """``platform, N CPUs, torch V, MuJoCo V`` from a run's recorded machine (MuJoCo where it
    was recorded: another version collects other data and rolls out other successes)."""
    if not machine:
        return "not recorded"
    platform = machine.get("platform")
    parts = [str(platform) if platform else None]
    parts.append(f"{machine['cpus']} CPUs" if machine.get("cpus") else None)
    parts.append(f"torch {machine['torch']}" if machine.get("torch") else None)
    parts.append(f"MuJoCo {machine['mujoco']}" if machine.get("mujoco") else None)
    return ", ".join(p for p in parts if p)


def short_commit(commit: str | None) -> str:
    """A commit's first 7 digits, ``+dirty`` kept; "not recorded" for none."""
    if not commit:
        return "not recorded"
    return f"{commit[:7]}{'+dirty' if commit.endswith('+dirty') else ''}"


def commit_text(record: LaunchRecord) -> str:
    """The commit a run was made on (short, ``+dirty`` kept; a resumed run's earlier ones
    after it), else the one that committed it."""
    if record.commit:
        made = short_commit(record.commit)
        # every launch's commit but the last, once per change (a run.json written before
        # plan.earlier_than may name its own commit as an earlier one)
        earlier = [short_commit(c) for c in launch_commits(record)[:-1]]
        return f"{made} (resumed; earlier: {', '.join(earlier)})" if earlier else made
    if record.committed_in:
        return f"{record.committed_in} (committed)"
    return "not recorded"


LOGGER_FLAGS = tuple(f"--trainer.logger.init_args.{k}" for k in ("save_dir", "name", "version"))


def trained_in(argv: list[str]) -> str | None:
    """The run directory a run trained in (its checkpoints and TensorBoard logs), from its
    command's logger flags: the folder, from this repository's git-ignored ``results/`` on, of
    which the reference folder holds the committed copy; None without the flags.

    Example:
        >>> trained_in(["--trainer.logger.init_args.save_dir", "/work/main/results/p/s/runs",
        ...             "--trainer.logger.init_args.name", "ftn",
        ...             "--trainer.logger.init_args.version", "seed0"])
        'results/p/s/runs/ftn/seed0'
    """
    given = {flag: value for flag, value in itertools.pairwise(argv) if flag in LOGGER_FLAGS}
    if len(given) < len(LOGGER_FLAGS):
        return None
    parts = Path(*(given[flag] for flag in LOGGER_FLAGS)).parts
    return "/".join(parts[parts.index("results") :] if "results" in parts else parts)


def run_provenance(run_dir: Path, folder: Path) -> Provenance:
    """Where the run in ``run_dir`` came from, by its ``run.json``."""
    run = RunDir(run_dir)
    record = run.read_run_record()
    name = run_dir.relative_to(folder).as_posix()
    argv = record.argv if record.argv and isinstance(record.argv, list) else None
    if argv:
        command = code_cell(fit_command(argv))
    elif run.config_file.exists():
        command = f"not recorded; its settings: {code_cell(f'{name}/{run.config_file.name}')}"
    else:
        command = "not recorded"
    machine = machine_text(record.machine if isinstance(record.machine, dict) else None)
    where = trained_in(argv) if argv else None
    return Provenance(name, commit_text(record), command, machine, where)


def folder_provenance(folder: Path) -> list[Provenance]:
    """A reference folder's rows: one per run under it, or, for a folder of grid reports
    (``grid.json``, no runs), one for the reports and the command that rebuilds them."""
    runs = sorted(p.parent for p in folder.rglob(RunDir.RESULTS))
    if runs:
        return [run_provenance(r, folder) for r in runs]
    grid_file = folder / "grid.json"
    if not grid_file.exists():
        return []
    name = json.loads(grid_file.read_text())["name"]
    return [
        Provenance(
            "(reports)",
            "the runs'",
            f"`python -m lab grid-reports {name}`",
            "built from the streams' runs",
        )
    ]


def manifest_markdown(folder: Path) -> str:
    """The ``MANIFEST.md`` of a reference folder."""
    lines = [
        f"# {folder.name}: where each run came from",
        "",
        "Generated by `python -m lab manifests` from each run's `run.json`: the commit it was",
        "launched from (or, where the launch recorded none, the commit that committed it), the",
        "run directory it trained in (git-ignored: checkpoints and logs; this folder holds its",
        "small files), the command and the machine. Do not edit by hand.",
        "",
        "| run | trained in | commit | machine | command |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {cell(r.run)} | {code_cell(r.trained_in) if r.trained_in else 'not recorded'} "
        f"| {cell(r.commit)} | {cell(r.machine)} | {r.command} |"
        for r in folder_provenance(folder)
    ]
    return "\n".join(lines) + "\n"


def write_manifests(root: Path) -> list[Path]:
    """Write the ``MANIFEST.md`` of every reference folder there is under ``root``."""
    written = []
    for name in REFERENCE_FOLDERS:
        folder = Path(root) / name
        if folder.is_dir():
            atomic_write_text(folder / MANIFEST, manifest_markdown(folder))
            written.append(folder / MANIFEST)
    return written
