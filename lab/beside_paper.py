"""The paper beside ours: its per-stream tables (Tables 7–9) and AntMaze ablation (Table 2)
with our committed figures next to each of its own, its columns added to a grid's aggregate
(Table 1), where it disagrees with itself, and the summary of where HiSPO stands."""

from __future__ import annotations

from collections.abc import Sequence
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path

from hispo_pl.benchmark.finished_runs import mean_std
from hispo_pl.benchmark.grid import Grid
from hispo_pl.benchmark.grid_report import (
    AggregateColumn,
    AggregateRow,
    Committed,
    aggregate_markdown,
    aggregate_rows,
    aggregate_subgrids,
)
from hispo_pl.benchmark.grid_report import grid_reports as product_reports
from hispo_pl.benchmark.tables import derived_footnote, derived_method, metric_cell
from hispo_pl.methods import shipped_method_name
from hispo_pl.metrics import METRIC

from . import paper


def _num(value: float | None) -> str:
    return "" if value is None else f"{value:.1f}"


def _table1(index: int) -> AggregateColumn:
    name = ("PER", "BWT", "FWT")[index]

    def cell(row: AggregateRow) -> str:
        theirs = paper.AGGREGATE.get(row.method)
        return _num(None if theirs is None else theirs[index])

    return AggregateColumn(f"paper {name}", cell)


# the paper's columns of an aggregate: its PER on the row's streams, then its Table 1
PAPER_COLUMNS = (
    AggregateColumn(
        "paper PER, these streams", lambda r: _num(paper.mean_per(r.method, r.streams))
    ),
    *(_table1(i) for i in range(3)),
)


def aggregate_note() -> str:
    """What the paper's columns of an aggregate are, for the end of its legend."""
    return (
        "The paper's PER on these streams is the mean of its per-stream PER "
        "(Tables 7–9) over the streams of our row; its PER, BWT and FWT are its Table 1, "
        "averaged over its six streams (AntMaze included) and three seeds each; FZ there is "
        f"frz here. {_table1_disagrees()}"
    )


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


# the methods the summary sets side by side, and how it names them
SUMMARY_METHODS = ("hispo", "scn", "ftn", "pnn", "cspo", "csp", "hilow")
NAMES = {m: shipped_method_name(m) for m in SUMMARY_METHODS}  # the registry's display names


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


BESIDE_FIGURE = "per_vs_memory-beside-paper.png"


def paper_points(rows: Sequence[AggregateRow]) -> dict[str, tuple[float, float]]:
    """Per method of ``rows``, the paper's ``(MEM, PER)`` averaged over the streams of its row
    (its per-stream tables); methods it has no figure for on one of them are left out."""
    points = {}
    for row in rows:
        mem, per = (paper.mean_of(m, row.method, list(row.streams)) for m in ("MEM", "PER"))
        if mem is not None and per is not None:
            points[row.method] = (mem, per)
    return points


def write_beside_paper_figure(grid: Grid, root: Path) -> Path | None:
    """The grid's PER-against-memory figure with the paper's point beside each method's
    (hollow, on the same streams): ``grid-<name>/per_vs_memory-beside-paper.png``. None when
    no method has both (or matplotlib is missing)."""
    try:
        from hispo_pl.perf_memory_figures import iqm_vs_memory_figure
    except ImportError:
        return None
    from hispo_pl.benchmark.grid_report import report_dir
    from hispo_pl.io import real_folder, write_figure

    rows = aggregate_rows(grid, Committed(root))
    points = paper_points(rows)
    if not points:
        return None
    title = f"PER against memory beside the paper: grid {grid.name}"
    figure = iqm_vs_memory_figure(rows, title, points, "the paper's, on the same streams")
    path = real_folder(report_dir(grid, root), root) / BESIDE_FIGURE
    write_figure(figure, path, dpi=150, bbox_inches="tight")
    return path


def grid_reports(grid: Grid, root: Path, committed: Committed) -> tuple[dict[str, str], list]:
    """A grid's reports as this repository commits them: the product's, the aggregates with
    the paper's columns, the summary and the tables beside the paper's; a grid that runs
    none of the paper's streams (random streams) has nothing to set beside them, so only the
    product's."""
    texts, rows = product_reports(grid, root, committed)
    if not set(grid.streams) & set(paper.PER_STREAM):
        return texts, rows

    def aggregate(sub: Grid, sub_rows: list[AggregateRow]) -> str:
        return aggregate_markdown(sub, sub_rows, PAPER_COLUMNS, aggregate_note())

    texts["aggregate.md"] = aggregate(grid, rows)
    for name, sub in aggregate_subgrids(grid).items():
        texts[f"aggregate-{name}.md"] = aggregate(sub, aggregate_rows(sub, committed))
    texts["summary.md"] = summary_markdown(committed)
    texts["beside-paper.md"] = beside_paper_markdown(committed, grid.streams)
    return texts, rows
