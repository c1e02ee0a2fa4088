"""Reports embedded in this repository's pages: a block opened by
``<!-- report: DIR/NAME -->`` and closed by ``<!-- end report -->`` holds the report ``NAME``
rebuilt from the committed runs under ``DIR``, so a page always equals what its run files give
(``python -m lab rebuild-docs PAGE...``; the docs test compares every block)."""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path

from hispo_pl.benchmark.curves import CURVES_FILE, CurveStudy, curves_markdown, load_curves
from hispo_pl.benchmark.grid import GRID_FILE, GRIDS_DIR, grid_from_dict, load_grid
from hispo_pl.benchmark.grid_report import Committed
from hispo_pl.benchmark.plan import planned_stream
from hispo_pl.benchmark.report import write_report
from hispo_pl.config_files import config_root
from hispo_pl.errors import UserError
from hispo_pl.io import copy_files
from hispo_pl.rundir import RunDir

from . import beside_paper
from .claims import CLAIMS_FILE, claims_markdown

EMBED_BEGIN = "<!-- report: "  # <!-- report: docs/results/pointmaze-1/table.md -->
EMBED_END = "<!-- end report -->"


def embed_reports(doc: Path, root: Path = Path(".")) -> str:
    """``doc``'s text with every embedded report rebuilt: a block opened by
    ``<!-- report: DIR/NAME -->`` and closed by ``<!-- end report -->`` gets the file ``NAME``
    that ``write_report`` builds from the runs under ``DIR`` (relative to ``root``), without
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
    if target.name != "claims.md":
        raise ValueError(f"{target}: a claims folder's report is claims.md")
    roots = json.loads((target.parent / CLAIMS_FILE).read_text())
    return claims_markdown(target.parent / roots["house"], target.parent / roots["protocol"])


def _curves_report_text(target: Path) -> str:
    """A learning-curve study's ``curves.md`` rebuilt from its committed runs."""
    if target.name != "curves.md":
        raise ValueError(f"{target}: a learning-curve study's report is curves.md")
    study = CurveStudy.read(target.parent)
    return curves_markdown(study, load_curves(target.parent, study))


def _grid_report_text(target: Path) -> str:
    """The grid report ``target`` rebuilt from its ``grid.json`` and the committed runs."""
    grid = _grid_before_runs(target.parent)
    if grid is None:
        spec = json.loads((target.parent / GRID_FILE).read_text())
        grid = grid_from_dict(spec, spec.get("name", "grid"))
    root = target.parent.parent
    texts, _ = beside_paper.grid_reports(grid, root, Committed(root))
    if target.name not in texts:
        raise ValueError(f"{target}: not a report of its grid ({', '.join(texts)})")
    return texts[target.name]


def _grid_before_runs(folder: Path):
    """The grid whose report folder ``folder`` (``grid-<name>``) will be, read from its
    definition (``configs/grids/<name>.yaml``) while no report of it is written there (no
    ``grid.json``): a page can embed the report of a grid before its runs, which then says
    what is missing. None for a folder with a ``grid.json``, or of no known grid."""
    name = folder.name.removeprefix("grid-")
    if (folder / GRID_FILE).exists() or not folder.name.startswith("grid-"):
        return None
    if not (config_root() / GRIDS_DIR / f"{name}.yaml").is_file():
        return None
    return load_grid(name, config_root())


def _stream_report_text(target: Path) -> str:
    """The stream report ``target`` rebuilt from a copy of the runs beside it, so the
    committed report files are left as they are."""
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
