"""Where each reference result came from: a ``MANIFEST.md`` per reference folder of
``docs/results`` listing, per run, the code's commit, the command and the machine.

A run's ``run.json`` names them when the benchmark that launched it recorded provenance;
otherwise the commit is the one that committed the run's ``results.json`` (``git log``) and
the machine is not known. The files are generated, never typed:

    python -m hispo_pl.benchmark.manifest docs/results
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..io import atomic_write_text
from ..rundir import RunDir
from .markdown import cell, code_cell

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


def git_commit_of(path: Path) -> str | None:
    """The short hash of the last commit that changed ``path`` (a folder: its files but its
    manifest); None outside a checkout or for a file git does not hold."""
    spec = [path.name, f":(exclude){path.name}/{MANIFEST}"] if path.is_dir() else [path.name]
    try:
        done = subprocess.run(
            ["git", "-C", str(path.parent), "log", "-1", "--format=%h", "--", *spec],
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    if done.returncode != 0:
        return None
    return done.stdout.strip() or None


def fit_command(argv: list[str]) -> str:
    """A run's recorded ``python -m hispo_pl.cli ...`` arguments as the ``hispo-pl`` command a
    checkout runs: config paths from ``configs/`` on, the rest as recorded."""
    args = [str(a) for a in argv]
    args = args[2:] if args[:2] == ["-m", "hispo_pl.cli"] else args
    shown = [a[a.index("configs/") :] if "/configs/" in a else a for a in args]
    return "hispo-pl " + " ".join(shown)


def machine_text(machine: dict | None) -> str:
    """``platform, N CPUs, torch V`` from a run's recorded machine."""
    if not machine:
        return "not recorded"
    platform = machine.get("platform")
    parts = [str(platform) if platform else None]
    parts.append(f"{machine['cpus']} CPUs" if machine.get("cpus") else None)
    parts.append(f"torch {machine['torch']}" if machine.get("torch") else None)
    return ", ".join(p for p in parts if p)


def run_provenance(
    run_dir: Path, folder: Path, commit_of: Callable[[Path], str | None]
) -> Provenance:
    """Where the run in ``run_dir`` came from: its ``run.json`` provenance, else the commit
    that committed its ``results.json``."""
    run = RunDir(run_dir)
    record = run.read_run_record()
    if record.get("commit"):
        made = str(record["commit"])
        commit = f"{made[:7]}{'+dirty' if made.endswith('+dirty') else ''}"
    else:
        committed = commit_of(run.results_file)
        commit = f"{committed} (committed)" if committed else "not recorded"
    name = run_dir.relative_to(folder).as_posix()
    if record.get("argv") and isinstance(record["argv"], list):
        command = code_cell(fit_command(record["argv"]))
    elif run.config_file.exists():
        command = f"not recorded; its settings: {code_cell(f'{name}/{run.config_file.name}')}"
    else:
        command = "not recorded"
    machine = record.get("machine")
    return Provenance(
        name, commit, command, machine_text(machine if isinstance(machine, dict) else None)
    )


def folder_provenance(folder: Path, commit_of: Callable[[Path], str | None]) -> list[Provenance]:
    """A reference folder's rows: one per run under it, or, for a folder of grid reports
    (``grid.json``, no runs), one for the reports and the command that rebuilds them."""
    runs = sorted(p.parent for p in folder.rglob(RunDir.RESULTS))
    if runs:
        return [run_provenance(r, folder, commit_of) for r in runs]
    grid_file = folder / "grid.json"
    if not grid_file.exists():
        return []
    name = json.loads(grid_file.read_text())["name"]
    committed = commit_of(folder)
    return [
        Provenance(
            "(reports)",
            f"{committed} (committed)" if committed else "not recorded",
            f"`hispo-pl benchmark --grid {name} --export docs/results --report-only`",
            "built from the streams' runs",
        )
    ]


def manifest_markdown(folder: Path, commit_of: Callable[[Path], str | None]) -> str:
    """The ``MANIFEST.md`` of a reference folder."""
    rows = folder_provenance(folder, commit_of)
    lines = [
        f"# {folder.name}: where each run came from",
        "",
        "Generated by `python -m hispo_pl.benchmark.manifest` from the runs' `run.json` (commit,",
        "command, machine, when the benchmark recorded them) and otherwise from `git log` (the",
        "commit that committed the run's `results.json`). Do not edit by hand.",
        "",
        "| run | commit | machine | command |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| {cell(r.run)} | {cell(r.commit)} | {cell(r.machine)} | {r.command} |" for r in rows
    ]
    return "\n".join(lines) + "\n"


def write_manifests(root: Path, commit_of: Callable[[Path], str | None] = git_commit_of) -> None:
    """Write the ``MANIFEST.md`` of every reference folder there is under ``root``."""
    for name in REFERENCE_FOLDERS:
        folder = Path(root) / name
        if folder.is_dir():
            atomic_write_text(folder / MANIFEST, manifest_markdown(folder, commit_of))


if __name__ == "__main__":
    write_manifests(Path(sys.argv[1] if len(sys.argv) > 1 else "docs/results"))
