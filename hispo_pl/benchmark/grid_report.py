"""A grid's reports, rebuilt from the committed run files: the aggregate over its streams
with interquartile means and stratified bootstrap intervals (the paper's Table 1 beside),
each stream's table beside the paper's (its Tables 6–8 and 2), the sweeps, and what the runs
cost. Written to ``<root>/grid-<name>/`` with the grid's definition (``grid.json``), so
``--report-only --docs`` can rebuild a page's embeds from the committed files alone."""

from __future__ import annotations

import json
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io import atomic_write_text
from ..rundir import RunDir
from . import paper
from .grid import GRID_FILE, SWEEPS_DIR, Grid
from .records import RunRecord, load_records, mean_std, per_run_metrics
from .tables import run_minutes

BOOTSTRAP_REPS = 2000  # stratified bootstrap resamples per interval
BOOTSTRAP_SEED = 0
PHASES = ("training", "evaluation", "search")


def report_dir(grid: Grid, root: Path) -> Path:
    return Path(root) / f"grid-{grid.name}"


def stream_records(root: Path, stream: str) -> list[RunRecord]:
    """The finished runs committed for ``stream`` under ``root`` (none if it has no folder)."""
    if not (Path(root) / stream).is_dir():
        return []
    return load_records(Path(root) / stream)[0]


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
    """One method over the streams where it has every seed of the grid."""

    method: str
    streams: list[str]
    PER: float
    BWT: float
    FWT: float | None
    MEM: float | None
    iqm: tuple[float, float, float]  # PER ×100: point, low, high


def aggregate_rows(grid: Grid, by_stream: dict[str, list[RunRecord]]) -> list[AggregateRow]:
    """Per method of the grid: the mean of PER, BWT, FWT (×100) and MEM over its runs on the
    streams where it has all the grid's seeds (the paper's Table 1 averages the same way), and
    the IQM of PER over those streams × seeds with its interval."""
    measured: dict[tuple[str, str], dict[int, dict]] = {}
    for stream, records in by_stream.items():
        for record, metrics, _ in per_run_metrics(records):
            measured.setdefault((stream, record.method), {})[record.seed] = metrics
    rows = []
    for method in grid.methods:
        streams = [s for s in by_stream if set(grid.seeds) <= set(measured.get((s, method), {}))]
        if not streams:
            continue
        runs = [measured[(s, method)][seed] for s in streams for seed in grid.seeds]
        scores = np.array(
            [[100 * measured[(s, method)][seed]["PER"] for s in streams] for seed in grid.seeds]
        )
        rows.append(
            AggregateRow(
                method,
                streams,
                float(np.mean([100 * m["PER"] for m in runs])),
                float(np.mean([100 * m["BWT"] for m in runs])),
                float(np.mean([100 * m["FWT"] for m in runs]))
                if all("FWT" in m for m in runs)
                else None,
                float(np.mean([m["MEM"] for m in runs])) if all("MEM" in m for m in runs) else None,
                iqm_interval(scores),
            )
        )
    return rows


def _num(value: float | None, digits: int = 1) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def aggregate_markdown(grid: Grid, rows: Sequence[AggregateRow]) -> str:
    """The paper's Table 1 over the grid's streams, with IQM intervals and the paper's row."""
    n_streams = len(grid.streams)
    lines = [
        f"# Aggregate: grid {grid.name}\n",
        "| method | streams | PER | BWT | FWT | MEM | PER IQM [95 % CI] | paper PER | paper BWT "
        "| paper FWT |",
        "|---|---:|---:|---:|---:|---:|---|---:|---:|---:|",
    ]
    for row in rows:
        ours = paper.AGGREGATE.get(row.method)
        point, low, high = row.iqm
        lines.append(
            f"| {row.method} | {len(row.streams)} of {n_streams} | {_num(row.PER)} | "
            f"{_num(row.BWT)} | {_num(row.FWT)} | {_num(row.MEM, 2)} | "
            f"{point:.1f} [{low:.1f}, {high:.1f}] | "
            + " | ".join(_num(v) for v in (ours or (None, None, None)))
            + " |"
        )
    legend = (
        f"\nMeans over every run of a method on the streams where it has all {len(grid.seeds)} "
        f"seeds, of the grid's {', '.join(grid.streams)}; success ×100, MEM as a ratio. IQM: the "
        "interquartile mean of PER over those streams × seeds, with a 95 % stratified "
        f"bootstrap interval (rliable, {BOOTSTRAP_REPS} resamples of the seeds within each "
        "stream). The paper's columns are its Table 1, averaged over its six streams (AntMaze "
        "included) and three seeds each; FZ there is frz here.\n"
    )
    return "\n".join(lines) + "\n" + legend


def _stat(value: tuple[float, float] | None, digits: int = 1) -> str:
    return "" if value is None else f"{value[0]:.{digits}f} ± {value[1]:.{digits}f}"


def _ours(records: Sequence[RunRecord]) -> dict[str, dict[str, tuple[float, float] | None]]:
    """Per method: (mean, std) of PER, BWT, FWT ×100 and MEM over its seeds."""
    by_method: dict[str, list[dict]] = {}
    for record, metrics, _ in per_run_metrics(records):
        by_method.setdefault(record.method, []).append(metrics)
    found = {}
    for method, runs in by_method.items():
        cells: dict[str, tuple[float, float] | None] = {}
        for name, scale in (("PER", 100), ("BWT", 100), ("FWT", 100), ("MEM", 1)):
            values = [scale * m[name] for m in runs if name in m]
            cells[name] = mean_std(values) if len(values) == len(runs) else None
        cells["seeds"] = (len(runs), 0.0)
        found[method] = cells
    return found


def beside_paper_markdown(root: Path) -> str:
    """The paper's per-stream tables (its Tables 6–8) and its AntMaze ablation (Table 2) with
    our committed figures in the column next to each of its own; empty where not run."""
    lines = ["# Beside the paper\n"]
    for stream, table in paper.PER_STREAM.items():
        ours = _ours(stream_records(root, stream))
        table_no = {"pointmaze": 6, "antmaze": 7, "videogame": 8}[stream.split("-")[0]]
        lines += [
            f"### {stream} (the paper's Table {table_no})\n",
            "| method | seeds here | PER paper | PER here | BWT paper | BWT here | FWT paper | "
            "FWT here | MEM paper | MEM here |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for method in [*table, *sorted(set(ours) - set(table))]:
            theirs = paper.paper_row(stream, method) or {}
            mine = ours.get(method, {})
            cells = []
            for name in paper.METRICS:
                digits = 2 if name == "MEM" else 1
                seeds = mine.get("seeds", (0, 0))[0]
                here = mine.get(name)
                text = (
                    ""
                    if here is None
                    else (f"{here[0]:.{digits}f}" if seeds == 1 else _stat(here, digits))
                )
                cells += [_stat(theirs.get(name), 1), text]
            seeds = mine.get("seeds")
            lines.append(
                f"| {method} | {'' if seeds is None else seeds[0]} | " + " | ".join(cells) + " |"
            )
        lines.append("")
    antmaze = [r for s in ("antmaze-1", "antmaze-2") for r in stream_records(root, s)]
    lines += [
        "### AntMaze ablation (the paper's Table 2)\n",
        "| method | runs here | PER paper | PER here | MEM paper | MEM here |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for method, (per, mem) in paper.ANTMAZE_ABLATION.items():
        mine = [m for r, m, _ in per_run_metrics(antmaze) if r.method == method]
        here_per = mean_std([100 * m["PER"] for m in mine]) if mine else None
        here_mem = mean_std([m["MEM"] for m in mine]) if mine else None
        lines.append(
            f"| {method} | {len(mine)} | {_stat(per)} | {_stat(here_per)} | {_stat(mem)} | "
            f"{_stat(here_mem, 2)} |"
        )
    legend = (
        "\nThe paper's figures as printed (mean ± std over three seeds; FZ is frz; its "
        "VideoGame-2 MEM column for FTN, FRZ, L2 and EWC reads 1.7, 2.7, 2.7 and 1.9, as "
        "printed). Ours: mean ± std (population) over the seeds committed under docs/results "
        "(one seed: its value), success ×100. Table 2 pools the runs of AntMaze-1 and "
        "AntMaze-2. The protocols differ (data, budget, success test, inputs, tuning): see "
        "the table of differences on this page.\n"
    )
    return "\n".join(lines) + legend


SUMMARY_METHODS = ("hispo", "scn", "ftn", "pnn", "cspo", "csp", "hilow")
NAMES = {"hispo": "HiSPO", "scn": "SCN", "ftn": "FTN", "pnn": "PNN", "cspo": "CSPO"}
NAMES |= {"csp": "CSP", "hilow": "HiLOW"}


def summary_markdown(root: Path) -> str:
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
        ours = _ours(stream_records(root, stream))
        pers = [ours[m]["PER"][0] for m in SUMMARY_METHODS if m in ours and ours[m]["PER"]]
        best = max(pers, default=None)
        cells = []
        for method in SUMMARY_METHODS:
            row = ours.get(method)
            if row is None or row["PER"] is None:
                cells.append("–")
                continue
            seeds = int(row["seeds"][0])
            per = f"{row['PER'][0]:.1f}" if seeds == 1 else _stat(row["PER"])
            text = per + ("" if row["MEM"] is None else f" / {row['MEM'][0]:.2f}")
            if seeds != 3:
                text += f" ({seeds} seed{'s' if seeds > 1 else ''})"
            cells.append(f"**{text}**" if row["PER"][0] == best else text)
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
    return float(run.read_results()["PER"]) if run.has_results() else None


def sweeps_markdown(grid: Grid, root: Path) -> str:
    """Each sweep's PER per stream and value (on its seed); the chosen value in bold. Empty
    for a grid without sweeps."""
    from .grid import chosen_value

    if not grid.sweeps:
        return ""
    lines = [f"# Sweeps: grid {grid.name}\n"]
    for method, sweep in grid.sweeps.items():
        lines += [
            f"### {method}: {sweep.name} (`--{sweep.key}`), seed {sweep.seed}\n",
            "| stream | " + " | ".join(f"{v:g}" for v in sweep.values) + " | chosen |",
            "|---|" + "---:|" * (len(sweep.values) + 1),
        ]
        for stream in grid.streams:
            pers = {v: sweep_per(root, stream, sweep.label(v), sweep.seed) for v in sweep.values}
            best = chosen_value(sweep, pers)
            cells = [
                "" if p is None else (f"**{100 * p:.1f}**" if v == best else f"{100 * p:.1f}")
                for v, p in pers.items()
            ]
            lines.append(
                f"| {stream} | " + " | ".join(cells) + f" | {'' if best is None else f'{best:g}'} |"
            )
        lines.append("")
    legend = (
        "PER ×100 of each value on one seed; the chosen value (the best PER, the first listed "
        "on a tie) is what every seed of the method runs at.\n"
    )
    return "\n".join(lines) + legend


def cost_markdown(grid: Grid, root: Path) -> str:
    """What the committed runs of the grid cost: wall hours per method (sweeps included) and
    the share of training, in-fit evaluation and the subspace search."""
    per_method: dict[str, list[RunRecord]] = {}
    for stream in grid.streams:
        for record in stream_records(root, stream):
            if record.method in grid.methods:
                per_method.setdefault(record.method, []).append(record)
        for seed_dir in sorted((Path(root) / stream / SWEEPS_DIR).glob("*/seed*")):
            run = RunDir(seed_dir)
            if run.has_results():
                method = seed_dir.parent.name.split("-")[0]
                per_method.setdefault(method, []).append(RunRecord(method, 0, run.read_results()))
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
            for task in r.results.get("phase_time_s") or []:
                for p in PHASES:
                    phases[p] += float(task.get(p, 0.0))
        spent = sum(phases.values()) or 1.0
        shares = [f"{100 * phases[p] / spent:.0f} %" for p in PHASES]
        lines.append(
            f"| {method} | {len(records)} | {minutes / 60:.1f} | {minutes / len(records):.1f} | "
            + " | ".join(shares)
            + " |"
        )
        total_runs += len(records)
        total_minutes += minutes
    if total_runs == 0:
        return ""
    lines.append(f"| all | {total_runs} | {total_minutes / 60:.1f} | | | | |")
    legend = (
        "\nWall time of the committed runs (the sum of their tasks' wall times: one torch "
        "thread each, two runs at a time on 2 CPU cores), sweeps included; the shares split "
        "each task's time between gradient steps, the rollout evaluation after each task and "
        "the subspace search before its decision.\n"
    )
    return "\n".join(lines) + "\n" + legend


def plot_iqm_vs_memory(rows: Sequence[AggregateRow], path: Path, title: str) -> bool:
    """PER's IQM with its interval against mean MEM, one marker per method."""
    try:
        from matplotlib.figure import Figure
    except ImportError:
        return False
    fig = Figure(figsize=(6.4, 4.6))
    ax = fig.add_subplot()
    markers = "osD^vP*Xh<>p"
    for i, row in enumerate(r for r in rows if r.MEM is not None):
        point, low, high = row.iqm
        ax.errorbar(
            row.MEM,
            point,
            yerr=[[point - low], [high - point]],
            fmt=markers[i % len(markers)],
            capsize=3,
            label=f"{row.method} ({len(row.streams)} streams)",
        )
    ax.ticklabel_format(useOffset=False)
    ax.set_ylim(0, 102)  # room for the markers at 100 %
    ax.set_xlabel("MEM (mean stored size / one single-task model)")
    ax.set_ylabel("PER IQM (success %), 95 % CI")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="lower right")
    fig.savefig(path, dpi=150, bbox_inches="tight")
    return True


REPORTS = ("summary.md", "aggregate.md", "beside-paper.md", "sweeps.md", "cost.md")


def grid_reports(grid: Grid, root: Path) -> tuple[dict[str, str], list[AggregateRow]]:
    """Every report's text (by file name; empty reports left out) and the aggregate rows."""
    by_stream = {s: stream_records(root, s) for s in grid.streams}
    rows = aggregate_rows(grid, by_stream)
    texts = {
        "summary.md": summary_markdown(root),
        "aggregate.md": aggregate_markdown(grid, rows),
        "beside-paper.md": beside_paper_markdown(root),
        "sweeps.md": sweeps_markdown(grid, root),
        "cost.md": cost_markdown(grid, root),
    }
    return {k: v for k, v in texts.items() if v}, rows


def write_grid_report(grid: Grid, root: Path, figures: bool = True) -> list[Path]:
    """Write the reports, ``grid.json`` and (``figures``) ``per_vs_memory.png`` into
    ``<root>/grid-<name>/``. Returns the files written."""
    out = report_dir(grid, root)
    out.mkdir(parents=True, exist_ok=True)
    texts, rows = grid_reports(grid, root)
    written = []
    atomic_write_text(out / GRID_FILE, json.dumps(grid.to_dict(), indent=1) + "\n")
    written.append(out / GRID_FILE)
    for name, text in texts.items():
        atomic_write_text(out / name, text)
        written.append(out / name)
    title = f"PER against memory: grid {grid.name}"
    if figures and rows and plot_iqm_vs_memory(rows, out / "per_vs_memory.png", title):
        written.append(out / "per_vs_memory.png")
    return written
