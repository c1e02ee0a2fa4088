"""The report of a benchmark's output directory: tables, figures and the runs that did not
finish or could not be read."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import RunDirError
from ..io import atomic_write_text, write_figure
from ..rundir import RunDir
from .finished_runs import MethodRow, RunRecord, aggregate, load_records, other_episodes
from .markdown import cell
from .plan import RUNS_DIR, planned_stream
from .tables import (
    before_training_markdown,
    critic_markdown,
    loss_decisions_markdown,
    memory_markdown,
    runtime_csv,
    table_csv,
    table_markdown,
)


def plot_perf_vs_memory(rows: Sequence[MethodRow], path: Path, stream: str = "") -> bool:
    """The paper's Figure 2: MEM on x, PER on y, one marker per method with error bars over
    seeds. Returns False (after a printed note) when matplotlib is not installed."""
    try:
        import matplotlib.figure  # noqa: F401  (checked here: figures may be imported already)

        from ..perf_memory_figures import perf_vs_memory_figure  # matplotlib, without pyplot
    except ImportError:
        print(
            "[benchmark] matplotlib is not installed: no perf_vs_memory.png (pip install "
            "matplotlib, or the dev extra); the tables are written"
        )
        return False
    fig = perf_vs_memory_figure(rows, stream)
    write_figure(fig, path, dpi=150, bbox_inches="tight")
    return True


def plot_success_matrices(records: Sequence[RunRecord], out: Path) -> list[Path]:
    """One heatmap per method, ``success_<method>.png``: R averaged over its seeds (the
    figure the paper's appendix shows per stream). Nothing without matplotlib."""
    try:
        from ..figures import success_matrix_figure
    except ImportError:
        return []
    by_method: dict[str, list[np.ndarray]] = {}
    tasks: dict[str, list[str]] = {}
    for record in records:
        by_method.setdefault(record.method, []).append(record.results.matrix)
        tasks.setdefault(record.method, list(record.results.stream))
    written = []
    for method, matrices in sorted(by_method.items()):
        if len({m.shape for m in matrices}) != 1:
            continue  # seeds of different streams: no mean to show
        mean = np.mean(matrices, axis=0)
        fig = success_matrix_figure(mean.tolist(), tasks[method])
        fig.axes[0].set_title(f"{method}: R, mean of {len(matrices)} seed(s)", fontsize=9)
        path = out / f"success_{method}.png"
        write_figure(fig, path, dpi=110, bbox_inches="tight")
        written.append(path)
    return written


def unfinished_runs(out: Path) -> list[tuple[str, int, str]]:
    """(method, seed, status) of every run the benchmark launched (it has a ``run.json``)
    without a ``results.json``: failed (with its exit status and log), or not finished."""
    found = []
    for meta_path in sorted((Path(out) / RUNS_DIR).glob(f"*/seed*/{RunDir.RUN_RECORD}")):
        seed_dir = meta_path.parent
        run = RunDir(seed_dir)
        if run.has_results():
            continue
        try:
            seed = int(seed_dir.name.removeprefix("seed"))
        except ValueError:
            continue
        try:
            status = run.read_run_record().status
        except RunDirError as err:
            status = f"unreadable: {err}"
        status = status or "not finished (interrupted, or still running)"
        found.append((seed_dir.parent.name, seed, status))
    return found


def unfinished_markdown(runs: Sequence[tuple[str, int, str]], unreadable: Sequence[str]) -> str:
    """The table.md sections listing runs without results and runs whose files cannot be
    read, so a failed method is never silently missing from the table."""
    lines = []
    if runs:
        lines += ["", "## Runs without results", "", "| method | seed | status |", "|---|---:|---|"]
        lines += [f"| {cell(method)} | {seed} | {cell(status)} |" for method, seed, status in runs]
    if unreadable:
        lines += ["", "## Runs that could not be read", ""]
        lines += [f"- {cell(line)}" for line in unreadable]
    return "\n".join(lines) + "\n" if lines else ""


def other_episodes_markdown(records: Sequence[RunRecord]) -> str:
    """The table.md section naming runs that trained on other episodes of the same dataset
    (:func:`~.finished_runs.other_episodes`), so a table never compares methods on different
    data unsaid."""
    lines = other_episodes(records)
    if not lines:
        return ""
    intro = (
        "These runs read the same dataset for a task but recorded other episodes (the digest "
        "of each task's episodes, `datasets` in `results.json`): the dataset was made again, on "
        "a machine or at versions that collect other episodes (docs/data.md). Their "
        "rows compare methods on different data."
    )
    items = "\n".join(f"- {cell(line)}" for line in lines)
    return f"\n## Runs that trained on other episodes\n\n{intro}\n\n{items}\n"


def write_report(out: Path, stream: str | None = None, figures: bool = True) -> list[Path]:
    """Rebuild ``table.md``, ``table.csv``, ``runtime.csv``, ``perf_vs_memory.png``, the
    success heatmaps and, where runs made decisions, ``decisions.md`` (loss rules) and
    ``critic.md`` (CSP's critic), and where runs measured it ``memory.md`` (MEM after each
    task) in ``out`` from every finished run under ``out/runs``
    (``figures=False``: the text files only). Returns the files written.

    Raises:
        FileNotFoundError: no finished run under ``out/runs``.
    """
    out = Path(out)
    records, unreadable = load_records(out)
    for line in unreadable:
        print(f"[benchmark] left out of the tables: {line}")
    missing = unfinished_runs(out)
    if not records and not missing and not unreadable:
        raise FileNotFoundError(
            f"no finished runs ({RUNS_DIR}/<method>/seed<S>/{RunDir.RESULTS}) under {out}"
        )
    if stream is None:
        stream = planned_stream(out) or ""
    rows, notes = aggregate(records)
    written = []
    for name, text in (
        (
            "table.md",
            table_markdown(rows, notes, stream)
            + other_episodes_markdown(records)
            + unfinished_markdown(missing, unreadable),
        ),
        ("table.csv", table_csv(rows)),
        ("runtime.csv", runtime_csv(records)),
    ):
        atomic_write_text(out / name, text)
        written.append(out / name)
    for name, text in (
        ("before_training.md", before_training_markdown(records, stream)),
        ("decisions.md", loss_decisions_markdown(records, stream)),
        ("critic.md", critic_markdown(records, stream)),
        ("memory.md", memory_markdown(records, stream)),
    ):
        if text:
            atomic_write_text(out / name, text)
            written.append(out / name)
    if figures and plot_perf_vs_memory(rows, out / "perf_vs_memory.png", stream):
        written.append(out / "perf_vs_memory.png")
        written += plot_success_matrices(records, out)
    return written
