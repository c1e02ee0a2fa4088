"""A grid's reports, rebuilt from the committed run files: the aggregate over its streams
with interquartile means and stratified bootstrap intervals, the sweeps, what the runs cost,
and for the grids that have them the zero-shot tests, memory after each task and growth.
Written to ``<root>/grid-<name>/`` with the grid's definition (``grid.json``), so that a report
can be rebuilt from the committed files alone."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..io import atomic_write_text, real_folder, write_figure
from ..metrics import METRICS
from .finished_runs import MethodRow, RunRecord, aggregate, load_records, per_run_metrics
from .grid import GRID_FILE, Grid
from .grid_cost import cost_markdown, sweeps_markdown
from .growth_curves import growth_data, has_random_streams
from .growth_figures import write_growth_figures
from .growth_report import (
    findings_markdown,
    growth_markdown,
    memory_per_task_markdown,
    repeats_markdown,
    search_time_markdown,
)
from .tables import derived_footnote, derived_method
from .transfer_report import PAC_METHOD, zero_shot_markdown

BOOTSTRAP_REPS = 2000  # stratified bootstrap resamples per interval
BOOTSTRAP_SEED = 0


def report_dir(grid: Grid, root: Path) -> Path:
    return Path(root) / f"grid-{grid.name}"


class Committed:
    """The runs committed under ``root``: each stream's read once and measured once, for every
    report of a grid."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self._measured: dict[str, list[tuple[RunRecord, dict, str | None]]] = {}
        self._rows: dict[str, dict[str, MethodRow]] = {}
        self.cache: dict = {}  # what other reports compute from these runs, once (claims' stats)

    def measured(self, stream: str) -> list[tuple[RunRecord, dict, str | None]]:
        """Each finished run of ``stream`` with its metrics and FWT reference
        (:func:`~.finished_runs.per_run_metrics`); none if the stream has no folder."""
        if stream not in self._measured:
            folder = self.root / stream
            records = load_records(folder)[0] if folder.is_dir() else []
            self._measured[stream] = per_run_metrics(records)
        return self._measured[stream]

    def records(self, stream: str) -> list[RunRecord]:
        return [r for r, _, _ in self.measured(stream)]

    def methods(self, stream: str) -> dict[str, MethodRow]:
        """Per method of ``stream``: its metrics' mean ± std over seeds (:func:`aggregate`)."""
        if stream not in self._rows:
            rows, _ = aggregate(self.records(stream), self.measured(stream))
            self._rows[stream] = {row.method: row for row in rows}
        return self._rows[stream]


@contextmanager
def _seeded_numpy(seed: int):
    """rliable draws from numpy's global generator: seed it for one interval, then restore
    it, so a report is the same on every rebuild and leaves no trace on the caller."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def iqm_interval(scores: np.ndarray, reps: int = BOOTSTRAP_REPS) -> tuple[float, float, float]:
    """Interquartile mean of ``scores`` (runs × streams) and its 95 % stratified bootstrap
    interval (runs resampled within each stream), by rliable.

    Raises:
        ImportError: rliable is not installed (``pip install 'hispo-pl[stats]'``)."""
    from rliable import library as rly
    from rliable import metrics

    with _seeded_numpy(BOOTSTRAP_SEED):
        point, interval = rly.get_interval_estimates(
            {"m": np.asarray(scores, dtype=float)},
            lambda x: np.array([metrics.aggregate_iqm(x)]),
            reps=reps,
        )
    return float(point["m"][0]), float(interval["m"][0, 0]), float(interval["m"][1, 0])


@dataclass
class AggregateRow:
    """One method over the streams where it has every seed of the grid: the mean of each
    metric ×100 (a ratio for MEM) that every run has, and the IQM of PER; its runs derived
    from another method's instead of trained, as (stream, seed, source method)."""

    method: str
    streams: list[str]
    means: dict[str, float]
    iqm: tuple[float, float, float]  # PER ×100: point, low, high
    derived: list[tuple[str, int, str]] = field(default_factory=list)


def aggregate_rows(grid: Grid, committed: Committed) -> list[AggregateRow]:
    """Per method of the grid: the mean of each metric over its runs on the streams where it
    has all the grid's seeds (the paper's Table 1 averages the same way), and the IQM of PER
    over those streams × seeds with its interval. Computed once per set of committed runs
    (the bootstrap is the dear part), whichever report or figure asks first."""
    key = ("aggregate", grid.streams, grid.methods, grid.seeds)
    if key not in committed.cache:
        committed.cache[key] = _aggregate_rows(grid, committed)
    return committed.cache[key]


def _aggregate_rows(grid: Grid, committed: Committed) -> list[AggregateRow]:
    measured: dict[tuple[str, str], dict[int, dict]] = {}
    derived: dict[tuple[str, str], dict[int, str]] = {}
    for stream in grid.streams:
        for record, metrics, _ in committed.measured(stream):
            measured.setdefault((stream, record.method), {})[record.seed] = metrics
            if record.derived_from:
                derived.setdefault((stream, record.method), {})[record.seed] = record.derived_from
    rows = []
    for method in grid.methods:
        streams = [s for s in grid.streams if set(grid.seeds) <= set(measured.get((s, method), {}))]
        if not streams:
            continue
        runs = [measured[(s, method)][seed] for s in streams for seed in grid.seeds]
        scores = np.array(
            [[100 * measured[(s, method)][seed]["PER"] for s in streams] for seed in grid.seeds]
        )
        means = {
            m.name: float(np.mean([m.scale * r[m.name] for r in runs]))
            for m in METRICS
            if all(m.name in r for r in runs)
        }
        sources = [
            (s, seed, source)
            for s in streams
            for seed, source in sorted(derived.get((s, method), {}).items())
            if seed in grid.seeds
        ]
        rows.append(AggregateRow(method, streams, means, iqm_interval(scores), sources))
    return rows


def aggregate_subgrids(grid: Grid) -> dict[str, Grid]:
    """Per named aggregate of ``grid`` (its ``aggregates``), the grid over those streams alone,
    named so that its report says which streams it is of."""
    return {
        name: replace(grid, name=f"{grid.name}, {name}", streams=streams, aggregates={})
        for name, streams in grid.aggregates.items()
    }


def _num(value: float | None, digits: int = 1) -> str:
    return "" if value is None else f"{value:.{digits}f}"


@dataclass(frozen=True)
class AggregateColumn:
    """A column that a caller adds to the aggregate, after the IQM: its header and its cell of
    one method's row (figures published elsewhere, say, beside ours)."""

    header: str
    cell: Callable[[AggregateRow], str]


def aggregate_markdown(
    grid: Grid,
    rows: Sequence[AggregateRow],
    columns: Sequence[AggregateColumn] = (),
    note: str = "",
) -> str:
    """The grid's aggregate: per method, the mean of each metric over its streams and the IQM
    of PER with its interval; ``columns`` after them, ``note`` at the end of the legend."""
    n_streams = len(grid.streams)
    names = " | ".join(m.name for m in METRICS)
    extra = "".join(f" {c.header} |" for c in columns)
    lines = [
        f"# Aggregate: grid {grid.name}\n",
        f"| method | streams | {names} | PER IQM [95 % CI] |{extra}",
        "|---|---:|" + "---:|" * len(METRICS) + "---|" + "---:|" * len(columns),
    ]
    for row in rows:
        point, low, high = row.iqm
        cells = [
            derived_method(row.method, row.derived),
            f"{len(row.streams)} of {n_streams}",
            *(_num(row.means.get(m.name), m.digits) for m in METRICS),
            f"{point:.1f} [{low:.1f}, {high:.1f}]",
            *(c.cell(row) for c in columns),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    legend = (
        f"\nMeans over every run of a method on the streams where it has all {len(grid.seeds)} "
        f"seeds, of the grid's {', '.join(grid.streams)}; success ×100, MEM as a ratio. IQM: the "
        "interquartile mean of PER over those streams × seeds, with a 95 % stratified "
        f"bootstrap interval (rliable, {BOOTSTRAP_REPS} resamples of the seeds within each "
        f"stream).{' ' + note if note else ''}\n"
    )
    notes = [
        derived_footnote(row.method, row.derived, len(row.streams) * len(grid.seeds))
        for row in rows
        if row.derived
    ]
    return "\n".join(lines) + "\n" + legend + "".join(f"\n{note}\n" for note in notes)


def plot_iqm_vs_memory(rows: Sequence[AggregateRow], path: Path, title: str) -> bool:
    """PER's IQM with its interval against mean MEM (False: no matplotlib)."""
    try:
        from ..perf_memory_figures import iqm_vs_memory_figure
    except ImportError:
        return False
    write_figure(iqm_vs_memory_figure(rows, title), path, dpi=150, bbox_inches="tight")
    return True


GROWTH_REPORTS = ("growth.md", "growth-findings.md", "search-time.md", "repeats.md")  # random


def growth(grid: Grid, committed: Committed):
    """The growth report's data of a grid with a random stream (:mod:`.growth_report`), once
    per set of committed runs; None for other grids."""
    if not has_random_streams(grid.streams):
        return None
    if "growth" not in committed.cache:
        committed.cache["growth"] = growth_data(grid, committed)
    return committed.cache["growth"]


def grid_reports(
    grid: Grid, root: Path, committed: Committed | None = None
) -> tuple[dict[str, str], list[AggregateRow]]:
    """Every report's text (by file name; empty reports left out) and the aggregate rows."""
    committed = committed or Committed(root)
    rows = aggregate_rows(grid, committed)
    texts = {
        "aggregate.md": aggregate_markdown(grid, rows),
        **{
            f"aggregate-{name}.md": aggregate_markdown(sub, aggregate_rows(sub, committed))
            for name, sub in aggregate_subgrids(grid).items()
        },
        "sweeps.md": sweeps_markdown(grid, root),
        "cost.md": cost_markdown(grid, committed),
        "zero-shot.md": zero_shot_markdown(committed, grid.streams)
        if PAC_METHOD in grid.methods
        else "",
    }
    if not has_random_streams(grid.streams):  # a random grid's growth report says more
        texts["memory-per-task.md"] = memory_per_task_markdown(grid, committed)
    data = growth(grid, committed)
    if data is not None:
        texts |= dict(
            zip(
                GROWTH_REPORTS,
                (
                    growth_markdown(grid, data),
                    findings_markdown(grid, data),
                    search_time_markdown(grid, data),
                    repeats_markdown(grid, data),
                ),
                strict=True,
            )
        )
    return {k: v for k, v in texts.items() if v}, rows


GridReports = Callable[[Grid, Path, Committed], tuple[dict[str, str], list[AggregateRow]]]


def write_grid_report(
    grid: Grid, root: Path, figures: bool = True, reports: GridReports | None = None
) -> list[Path]:
    """Write the reports, ``grid.json`` and (``figures``) ``per_vs_memory.png`` (and, for a
    grid with a random stream, the growth figures) into ``<root>/grid-<name>/``; ``reports``
    gives the texts in place of :func:`grid_reports` (one that adds its own). Returns the
    files written."""
    out = report_dir(grid, root)
    real_folder(out, root)  # a link there is replaced: the reports stay under root
    committed = Committed(root)
    texts, rows = (reports or grid_reports)(grid, root, committed)
    written = []
    atomic_write_text(out / GRID_FILE, json.dumps(grid.to_dict(), indent=1) + "\n")
    written.append(out / GRID_FILE)
    for name, text in texts.items():
        atomic_write_text(out / name, text)
        written.append(out / name)
    title = f"PER against memory: grid {grid.name}"
    if figures and rows and plot_iqm_vs_memory(rows, out / "per_vs_memory.png", title):
        written.append(out / "per_vs_memory.png")
    for name, sub in aggregate_subgrids(grid).items() if figures else ():
        path, sub_rows = out / f"per_vs_memory-{name}.png", aggregate_rows(sub, committed)
        if sub_rows and plot_iqm_vs_memory(sub_rows, path, f"PER against memory: {sub.name}"):
            written.append(path)
    data = growth(grid, committed)
    if figures and data is not None:
        written += write_growth_figures(grid, data, out)
    return written
