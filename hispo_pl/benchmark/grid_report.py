"""A grid's reports, rebuilt from the committed run files: the aggregate over its streams
with interquartile means and stratified bootstrap intervals (the paper's Table 1 beside),
each stream's table beside the paper's (its Tables 7–9 and 2), the sweeps, and what the runs
cost. Written to ``<root>/grid-<name>/`` with the grid's definition (``grid.json``), so
``--report-only --docs`` can rebuild a page's embeds from the committed files alone."""

from __future__ import annotations

import json
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

import numpy as np

from ..io import atomic_write_text, real_folder, write_figure
from ..metrics import METRIC, METRICS
from ..rundir import RunDir
from . import paper
from .grid import GRID_FILE, SWEEPS_DIR, Grid
from .growth_report import (
    findings_markdown,
    growth_data,
    growth_markdown,
    has_random_streams,
    memory_per_task_markdown,
    write_growth_figures,
)
from .records import MethodRow, RunRecord, aggregate, load_records, mean_std, per_run_metrics
from .tables import derived_footnote, derived_method, metric_cell, run_minutes
from .transfer_report import PAC_METHOD, zero_shot_markdown

BOOTSTRAP_REPS = 2000  # stratified bootstrap resamples per interval
BOOTSTRAP_SEED = 0
PHASES = ("training", "evaluation", "search")


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
        (:func:`~.records.per_run_metrics`); none if the stream has no folder."""
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
    over those streams × seeds with its interval."""
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


def aggregate_markdown(grid: Grid, rows: Sequence[AggregateRow]) -> str:
    """The paper's Table 1 over the grid's streams, with IQM intervals and the paper's row."""
    n_streams = len(grid.streams)
    names = " | ".join(m.name for m in METRICS)
    lines = [
        f"# Aggregate: grid {grid.name}\n",
        f"| method | streams | {names} | PER IQM [95 % CI] | paper PER, these streams | "
        "paper PER | paper BWT | paper FWT |",
        "|---|---:|" + "---:|" * len(METRICS) + "---|---:|---:|---:|---:|",
    ]
    for row in rows:
        theirs = paper.AGGREGATE.get(row.method)
        point, low, high = row.iqm
        means = " | ".join(_num(row.means.get(m.name), m.digits) for m in METRICS)
        lines.append(
            f"| {derived_method(row.method, row.derived)} | {len(row.streams)} of {n_streams} | "
            f"{means} | "
            f"{point:.1f} [{low:.1f}, {high:.1f}] | "
            + " | ".join(
                _num(v) for v in (paper.mean_per(row.method, row.streams), *(theirs or (None,) * 3))
            )
            + " |"
        )
    legend = (
        f"\nMeans over every run of a method on the streams where it has all {len(grid.seeds)} "
        f"seeds, of the grid's {', '.join(grid.streams)}; success ×100, MEM as a ratio. IQM: the "
        "interquartile mean of PER over those streams × seeds, with a 95 % stratified "
        f"bootstrap interval (rliable, {BOOTSTRAP_REPS} resamples of the seeds within each "
        "stream). The paper's PER on these streams is the mean of its per-stream PER "
        "(Tables 7–9) over the streams of our row; its PER, BWT and FWT are its Table 1, "
        "averaged over its six streams (AntMaze included) and three seeds each; FZ there is "
        f"frz here. {_table1_disagrees()}\n"
    )
    notes = [
        derived_footnote(row.method, row.derived, len(row.streams) * len(grid.seeds))
        for row in rows
        if row.derived
    ]
    return "\n".join(lines) + "\n" + legend + "".join(f"\n{note}\n" for note in notes)


def _printed_mean(values: Sequence[float]) -> Decimal:
    """The mean of figures printed to one decimal, rounded half up to one decimal, exactly."""
    mean = sum(Decimal(f"{v:.1f}") for v in values) / len(values)
    return mean.quantize(Decimal("0.1"), rounding=ROUND_HALF_UP)


def _table1_disagrees() -> str:
    """Where the paper's Table 1 PER is not the mean of its six per-stream PER (both as
    printed, to one decimal), largest gap first; empty where it is for every method."""
    gaps = []
    for method, (per, _, _) in paper.AGGREGATE.items():
        rows = [paper.paper_row(stream, method) for stream in paper.PER_STREAM]
        if any(row is None for row in rows):
            continue
        mean = _printed_mean([row["PER"][0] for row in rows])
        if mean != Decimal(f"{per:.1f}"):
            gaps.append((abs(mean - Decimal(f"{per:.1f}")), f"{method} {per:.1f} against {mean}"))
    if not gaps:
        return ""
    listed = ", ".join(text for _, text in sorted(gaps, reverse=True))
    return (
        "The paper disagrees with itself: for some methods its Table 1 PER is not the mean of "
        f"its per-stream PER over the six streams (Table 1 against that mean: {listed}), so a "
        "match with one of the two is not a match with the other."
    )


def _stat(value: tuple[float, float] | None, digits: int = 1) -> str:
    return "" if value is None else f"{value[0]:.{digits}f} ± {value[1]:.{digits}f}"


def beside_paper_markdown(committed: Committed, streams: Sequence[str] | None = None) -> str:
    """The paper's per-stream tables (its Tables 7–9) and its AntMaze ablation (Table 2) with
    our committed figures in the column next to each of its own; empty where not run. With
    ``streams`` (a grid's), a table of another stream is shown only where it has runs."""
    lines = ["# Beside the paper\n"]
    shown = [
        s for s in paper.PER_STREAM if streams is None or s in streams or committed.measured(s)
    ]
    for stream, table in ((s, paper.PER_STREAM[s]) for s in shown):
        ours = committed.methods(stream)
        table_no = {"pointmaze": 7, "antmaze": 8, "videogame": 9}[stream.split("-")[0]]
        lines += [
            f"### {stream} (the paper's Table {table_no})\n",
            "| method | seeds here | PER paper | PER here | BWT paper | BWT here | FWT paper | "
            "FWT here | MEM paper | MEM here |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for method in [*table, *sorted(set(ours) - set(table))]:
            theirs = paper.paper_row(stream, method) or {}
            mine = ours.get(method)
            cells = [c for n in paper.METRICS for c in (_stat(theirs.get(n)), metric_cell(mine, n))]
            seeds = "" if mine is None else len(mine.seeds)
            name = method if mine is None else derived_method(method, mine.derived)
            lines.append(f"| {name} | {seeds} | " + " | ".join(cells) + " |")
        for method, row in ours.items():
            if row.derived:
                derived = [("", seed, source) for seed, source in row.derived.items()]
                lines += ["", derived_footnote(method, derived, len(row.seeds))]
        lines.append("")
    antmaze = [run for s in ("antmaze-1", "antmaze-2") for run in committed.measured(s)]
    if streams is not None and not antmaze and not {"antmaze-1", "antmaze-2"} & set(streams):
        return "\n".join(lines) + _legend_without_ablation()
    lines += [
        "### AntMaze ablation (the paper's Table 2)\n",
        "| method | runs here | PER paper | PER here | MEM paper | MEM here |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for method, (per, mem) in paper.ANTMAZE_ABLATION.items():
        mine = [m for r, m, _ in antmaze if r.method == method]
        here_per = mean_std([100 * m["PER"] for m in mine]) if mine else None
        here_mem = mean_std([m["MEM"] for m in mine]) if mine else None
        lines.append(
            f"| {method} | {len(mine)} | {_stat(per)} | {_stat(here_per)} | {_stat(mem)} | "
            f"{_stat(here_mem, 2)} |"
        )
    disagrees = _table2_disagrees()
    legend = (
        ("\n\n" + disagrees + " " if disagrees else "\n")
        + "The paper's figures as printed (mean ± std over three seeds; FZ is frz; its "
        "VideoGame-2 MEM column for FTN, FRZ, L2 and EWC reads 1.7, 2.7, 2.7 and 1.9, as "
        "printed; on AntMaze its SC1 MEM and its L2 and EWC BWT read 0.0, as printed). "
        "Ours: mean ± std (population) over the seeds committed under docs/results (one "
        "seed: its value), success ×100. Table 2 pools the runs of AntMaze-1 and "
        "AntMaze-2. The protocols differ (data, budget, success test, inputs, tuning): see "
        "the table of differences on this page.\n"
    )
    return "\n".join(lines) + legend


def _legend_without_ablation() -> str:
    """The beside-the-paper legend of a grid with no AntMaze run (no Table 2 to set beside)."""
    return (
        "\nThe paper's figures as printed (mean ± std over three seeds; FZ is frz). Ours: mean "
        "± std (population) over the seeds committed under this grid's results folder (one "
        "seed: its value), success ×100.\n"
    )


def _table2_disagrees() -> str:
    """Where the paper's AntMaze ablation (Table 2) is not the mean of its per-stream AntMaze
    rows, PER and MEM as printed; empty where it is (or where those rows lack the method)."""
    notes = []
    for method, (per, mem) in paper.ANTMAZE_ABLATION.items():
        rows = [paper.paper_row(s, method) for s in paper.PER_STREAM if s.startswith("antmaze")]
        if not rows or any(row is None for row in rows):
            continue
        mean_per = _printed_mean([row["PER"][0] for row in rows])
        mean_mem = _printed_mean([row["MEM"][0] for row in rows])
        theirs, mean = f"{per[0]:.1f} / {mem[0]:.1f}", f"{mean_per} / {mean_mem}"
        if theirs != mean:
            notes.append(
                f"The paper disagrees with itself on {method}: its Table 2 gives PER / MEM "
                f"{theirs}, where its per-stream AntMaze rows average {mean}; ours stands "
                "beside Table 2's, so a match is with one of its two figures only."
            )
    return " ".join(notes)


SUMMARY_METHODS = ("hispo", "scn", "ftn", "pnn", "cspo", "csp", "hilow")
NAMES = {"hispo": "HiSPO", "scn": "SCN", "ftn": "FTN", "pnn": "PNN", "cspo": "CSPO"}
NAMES |= {"csp": "CSP", "hilow": "HiLOW"}


def summary_markdown(committed: Committed) -> str:
    """Where HiSPO stands: PER / MEM of the subspace methods and the expanding baselines on
    every stream of the paper's tables, the best PER of a row in bold, the paper's HiSPO in the
    last column."""
    head = " | ".join("HiSPO PER / MEM" if m == "hispo" else NAMES[m] for m in SUMMARY_METHODS)
    lines = [
        "# Where HiSPO stands\n",
        f"| stream | {head} | paper HiSPO |",
        "|---|" + "---|" * (len(SUMMARY_METHODS) + 1),
    ]
    for stream in paper.PER_STREAM:
        ours = {m: row for m, row in committed.methods(stream).items() if m in SUMMARY_METHODS}
        best = max((row.metrics["PER"][0] for row in ours.values()), default=None)
        cells = []
        for method in SUMMARY_METHODS:
            row = ours.get(method)
            if row is None:
                cells.append("–")
                continue
            seeds = len(row.seeds)
            text = metric_cell(row, "PER")
            if "MEM" in row.metrics:
                text += f" / {METRIC['MEM'].format(row.metrics['MEM'][0])}"
            if seeds != 3:
                text += f" ({seeds} seed{'s' if seeds > 1 else ''})"
            cells.append(f"**{text}**" if row.metrics["PER"][0] == best else text)
        theirs = paper.paper_row(stream, "hispo")
        reference = f"{theirs['PER'][0]:.1f} / {theirs['MEM'][0]:.1f}" if theirs else ""
        title = stream.replace("pointmaze", "PointMaze").replace("antmaze", "AntMaze")
        title = title.replace("videogame", "VideoGame")
        lines.append(f"| {title} | " + " | ".join(cells) + f" | {reference} |")
    legend = (
        "\nPER (success ×100, mean ± std over seeds) / MEM; three seeds where no count is "
        "given; the best PER of each stream in bold. Rebuilt from the runs under "
        "docs/results/<stream>/.\n"
    )
    return "\n".join(lines) + "\n" + legend


def sweep_per(root: Path, stream: str, label: str, seed: int) -> float | None:
    run = RunDir(Path(root) / stream / SWEEPS_DIR / label / f"seed{seed}")
    return float(run.stream_results().metrics["PER"]) if run.has_results() else None


def tree_tasks(root: Path, stream: str, sweep) -> str:
    """A tolerance tree's cost on one stream: the tasks its committed runs trained, of the
    tasks they hold (a branched run's ``run.json`` says how many it copied)."""
    trained = held = 0
    for value in sweep.values:
        run = RunDir(Path(root) / stream / SWEEPS_DIR / sweep.label(value) / f"seed{sweep.seed}")
        if not run.has_results():
            continue
        tasks = len(run.stream_results().stream)
        copied = int(run.read_run_record().get("branched_tasks") or 0)
        trained, held = trained + tasks - copied, held + tasks
    return f"{trained} of {held}" if held else ""


def sweeps_markdown(grid: Grid, root: Path) -> str:
    """Each sweep's PER per stream and value (on its seed); the chosen value in bold. Empty
    for a grid without sweeps."""
    from .grid import chosen_value

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
            "A tree's runs (a sweep of the pruning tolerance) share the tasks before their first "
            "differing decision: its last column counts the tasks they trained, of all the tasks "
            "their runs hold.\n"
        )
    return "\n".join(lines) + legend


def _copied_from_sweep(record: RunRecord, root: Path) -> bool:
    """A seed copied from its sweep (``run.json`` names the sweep run it is): its time is
    counted once, with the sweep's runs."""
    parts = Path(record.meta.get("derived_from") or "").parts
    if len(parts) < 3:  # not derived, or not from a grid's cell
        return False
    stream, label, seed = parts[-3:]
    return (root / stream / SWEEPS_DIR / label / seed).is_dir()


def cost_markdown(grid: Grid, committed: Committed) -> str:
    """What the committed runs of the grid cost: wall hours per method (sweeps included) and
    the share of training, in-fit evaluation and the subspace search."""
    per_method: dict[str, list[RunRecord]] = {}
    derived: dict[str, list[tuple[str, int, str]]] = {}
    for stream in grid.streams:
        for record in committed.records(stream):
            if record.method in grid.methods and not _copied_from_sweep(record, committed.root):
                per_method.setdefault(record.method, []).append(record)
                if record.derived_from:
                    where = (stream, record.seed, record.derived_from)
                    derived.setdefault(record.method, []).append(where)
        for seed_dir in sorted((committed.root / stream / SWEEPS_DIR).glob("*/seed*")):
            run = RunDir(seed_dir)
            if run.has_results():
                method = seed_dir.parent.name.split("-")[0]
                results = run.stream_results()
                per_method.setdefault(method, []).append(RunRecord(method, 0, results))
    lines = [
        f"# Cost: grid {grid.name}\n",
        "| method | runs | hours | minutes per run | training | evaluation | search |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    total_runs, total_minutes = 0, 0.0
    for method in [m for m in grid.methods if m in per_method]:
        records = per_method[method]
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
    legend = (
        "\nWall time of the committed runs (the sum of their tasks' wall times: one torch "
        "thread each, two runs at a time on 2 CPU cores), sweeps included and a seed copied "
        "from its sweep counted once; the shares split "
        "each task's time between gradient steps, the rollout evaluation after each task and "
        "the subspace search before its decision.\n"
    )
    notes = [
        derived_footnote(m, derived[m], len(per_method[m])) + " Their minutes are the "
        "re-evaluation they ran, not training."
        for m in derived
    ]
    return "\n".join(lines) + "\n" + legend + "".join(f"\n{note}\n" for note in notes)


def plot_iqm_vs_memory(rows: Sequence[AggregateRow], path: Path, title: str) -> bool:
    """PER's IQM with its interval against mean MEM (False: no matplotlib)."""
    try:
        from ..figures import iqm_vs_memory_figure
    except ImportError:
        return False
    write_figure(iqm_vs_memory_figure(rows, title), path, dpi=150, bbox_inches="tight")
    return True


GROWTH_REPORTS = ("growth.md", "growth-findings.md")  # a grid with a random stream's


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
        "summary.md": summary_markdown(committed),
        "aggregate.md": aggregate_markdown(grid, rows),
        **{
            f"aggregate-{name}.md": aggregate_markdown(sub, aggregate_rows(sub, committed))
            for name, sub in aggregate_subgrids(grid).items()
        },
        "beside-paper.md": beside_paper_markdown(committed, grid.streams),
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
                (growth_markdown(grid, data), findings_markdown(grid, data)),
                strict=True,
            )
        )
    return {k: v for k, v in texts.items() if v}, rows


def write_grid_report(grid: Grid, root: Path, figures: bool = True) -> list[Path]:
    """Write the reports, ``grid.json`` and (``figures``) ``per_vs_memory.png`` (and, for a
    grid with a random stream, the growth figures) into ``<root>/grid-<name>/``. Returns the
    files written."""
    out = report_dir(grid, root)
    real_folder(out, root)  # a link there is replaced: the reports stay under root
    committed = Committed(root)
    texts, rows = grid_reports(grid, root, committed)
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
