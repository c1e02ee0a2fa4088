"""The report of a benchmark's output directory: tables, figure, unfinished runs, and the
reports embedded in the docs."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..errors import RunDirError, UserError
from ..io import atomic_write_text, copy_files, write_figure
from ..rundir import RunDir
from .claims import CLAIMS_FILE
from .curves import CURVES_FILE
from .grid import GRID_FILE
from .markdown import cell
from .plan import RUNS_DIR, planned_stream
from .records import MethodRow, RunRecord, aggregate, load_records
from .tables import (
    before_training_markdown,
    critic_markdown,
    decisions_markdown,
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

        from ..figures import perf_vs_memory_figure  # matplotlib, without pyplot
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
            status = run.read_run_record().get("status")
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
            table_markdown(rows, notes, stream) + unfinished_markdown(missing, unreadable),
        ),
        ("table.csv", table_csv(rows)),
        ("runtime.csv", runtime_csv(records)),
    ):
        atomic_write_text(out / name, text)
        written.append(out / name)
    for name, text in (
        ("before_training.md", before_training_markdown(records, stream)),
        ("decisions.md", decisions_markdown(records, stream)),
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


EMBED_BEGIN = "<!-- report: "  # <!-- report: docs/results/pointmaze-1/table.md -->
EMBED_END = "<!-- end report -->"


def embed_reports(doc: Path, root: Path = Path(".")) -> str:
    """``doc``'s text with every embedded report rebuilt: a block opened by
    ``<!-- report: DIR/NAME -->`` and closed by ``<!-- end report -->`` gets the file ``NAME``
    that :func:`write_report` builds from the runs under ``DIR`` (relative to ``root``), without
    its title line; a grid's report (its folder holds ``grid.json``) is rebuilt from the
    grid's committed runs, a learning-curve study's (its folder holds ``curves.json``) from its
    runs' curves, the claims (its folder holds ``claims.json``) from the two protocols' runs; a
    grid's folder without ``grid.json`` yet (``grid-<name>``) from the grid's definition, with
    no run or some. A report's relative links are rewritten to point from the page. Keeps a
    documentation page equal to what its committed run files give."""
    lines, out, i = Path(doc).read_text().splitlines(), [], 0
    while i < len(lines):
        line = lines[i]
        out.append(line)
        i += 1
        if not line.startswith(EMBED_BEGIN):
            continue
        target = Path(root) / line[len(EMBED_BEGIN) :].removesuffix("-->").strip()
        try:
            text = _embed_text(target).splitlines()
        except (ValueError, KeyError, TypeError, FileNotFoundError) as err:
            raise UserError(
                f"{doc}: the report of `{line.strip()}` cannot be built ({err}); fix the "
                "embed or the run files it names"
            ) from None
        text = [_relink(x, target.parent, Path(doc).parent) for x in text[1:]]
        out += [x for x in text if x or out[-1]]  # without the title, no doubled blank
        while i < len(lines) and lines[i] != EMBED_END:
            i += 1
        if i == len(lines):
            raise UserError(f"{doc}: `{line.strip()}` has no closing `{EMBED_END}`; add one")
    return "\n".join(out) + "\n"


_LINK = re.compile(r"(!?\[[^\]]*\]\()([^)\s]+)(\))")


def _relink(line: str, report: Path, page: Path) -> str:
    """A report's line with its relative links (written from the report's folder) pointing
    from the page that embeds it instead."""

    def move(match: re.Match) -> str:
        target = match.group(2)
        if "://" in target or target.startswith(("#", "/", "mailto:")):
            return match.group(0)
        moved = os.path.relpath(report / target, page)
        return f"{match.group(1)}{Path(moved).as_posix()}{match.group(3)}"

    return _LINK.sub(move, line)


def _embed_text(target: Path) -> str:
    """The report an embed names, by what its folder holds (:func:`embed_reports`)."""
    if (target.parent / GRID_FILE).exists() or _grid_before_runs(target.parent) is not None:
        return _grid_report_text(target)
    if (target.parent / CURVES_FILE).exists():
        return _curves_report_text(target)
    if (target.parent / CLAIMS_FILE).exists():
        return _claims_report_text(target)
    return _stream_report_text(target)


def _claims_report_text(target: Path) -> str:
    """The claims report rebuilt from the two roots its folder's ``claims.json`` names."""
    from .claims import claims_markdown

    if target.name != "claims.md":
        raise ValueError(f"{target}: a claims folder's report is claims.md")
    roots = json.loads((target.parent / CLAIMS_FILE).read_text())
    return claims_markdown(target.parent / roots["house"], target.parent / roots["protocol"])


def _curves_report_text(target: Path) -> str:
    """A learning-curve study's ``curves.md`` rebuilt from its committed runs."""
    from .curves import CurveStudy, curves_markdown, load_curves

    if target.name != "curves.md":
        raise ValueError(f"{target}: a learning-curve study's report is curves.md")
    study = CurveStudy.read(target.parent)
    return curves_markdown(study, load_curves(target.parent, study))


def _grid_report_text(target: Path) -> str:
    """The grid report ``target`` rebuilt from its ``grid.json`` and the committed runs."""
    from .grid import grid_from_dict
    from .grid_report import grid_reports

    grid = _grid_before_runs(target.parent)
    if grid is None:
        spec = json.loads((target.parent / GRID_FILE).read_text())
        grid = grid_from_dict(spec, spec.get("name", "grid"))
    texts, _ = grid_reports(grid, target.parent.parent)
    if target.name not in texts:
        raise ValueError(f"{target}: not a report of its grid ({', '.join(texts)})")
    return texts[target.name]


def _grid_before_runs(folder: Path):
    """The grid whose report folder ``folder`` (``grid-<name>``) will be, read from its
    definition (``configs/grids/<name>.yaml``) while no report of it is written there (no
    ``grid.json``): a page can embed the report of a grid before its runs, which then says
    what is missing. None for a folder with a ``grid.json``, or of no known grid."""
    from ..config_files import config_root
    from .grid import GRIDS_DIR, load_grid

    name = folder.name.removeprefix("grid-")
    if (folder / GRID_FILE).exists() or not folder.name.startswith("grid-"):
        return None
    if not (config_root() / GRIDS_DIR / f"{name}.yaml").is_file():
        return None
    return load_grid(name, config_root())


def _stream_report_text(target: Path) -> str:
    """The stream report ``target`` rebuilt from a copy of the runs beside it, so the
    committed report files are left as they are."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        pairs = [
            (src, Path(tmp) / src.relative_to(target.parent))
            for name in RunDir.EXPORTED
            for src in target.parent.glob(f"*/seed*/{name}")
        ]
        if not pairs:
            raise FileNotFoundError(f"no runs (<method>/seed<S>/) under {target.parent}")
        for _, dst in pairs:
            dst.parent.mkdir(parents=True, exist_ok=True)
        copy_files(pairs)
        stream = planned_stream(target.parent)
        write_report(Path(tmp), stream or target.parent.name, figures=False)
        return (Path(tmp) / target.name).read_text()
