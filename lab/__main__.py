"""``python -m lab``: rebuild what this repository commits from its committed run files, or
launch a benchmark whose runs record the checkout's commit.

    python -m lab rebuild                       # all of the below, in order
    python -m lab grid-reports paper            # docs/results/<stream>/ tables, grid-paper/
    python -m lab grid-reports random-streams --root docs/results/random-streams
    python -m lab claims                        # docs/results/claims/claims.md
    python -m lab manifests                     # docs/results/*/MANIFEST.md
    python -m lab rebuild-docs README.md docs/results.md   # the reports the pages embed
    python -m lab migrate [docs/results] [--check]  # run files of earlier formats -> current
    python -m lab config-drift --grid paper --part antmaze  # committed runs vs today's config
    python -m lab benchmark --grid paper --out results/grid --export docs/results
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from contextlib import suppress
from pathlib import Path

from hispo_pl.errors import UserError

RESULTS = Path("docs/results")
CLAIMS = RESULTS / "claims"
# the grids whose reports are committed, and the folder their runs are exported to
GRIDS = {"paper": RESULTS, "random-streams": RESULTS / "random-streams"}


def pages() -> list[Path]:
    """Every page of the repository that embeds a report."""
    from .embed import EMBED_BEGIN

    found = [Path("README.md"), *sorted(Path("docs").glob("*.md"))]
    found += sorted(Path("docs/studies").glob("*.md"))
    return [p for p in found if EMBED_BEGIN in p.read_text()]


def rebuild_docs(names: Sequence[str]) -> None:
    from hispo_pl.errors import ConfigError
    from hispo_pl.io import atomic_write_text

    from .embed import embed_reports

    for page in [Path(n) for n in names] or pages():
        if not page.is_file():
            raise ConfigError(f"{page}: no such page")
        text = embed_reports(page)
        if text != page.read_text():
            atomic_write_text(page, text)
            print(f"[lab] rebuilt the reports embedded in {page}")


def grid_reports(name: str, root: Path) -> None:
    """The tables of the grid's streams and the grid's reports, as this repository commits
    them (the paper's columns and tables beside ours)."""
    from hispo_pl.benchmark.grid import load_grid
    from hispo_pl.benchmark.grid_report import write_grid_report
    from hispo_pl.benchmark.report import write_report
    from hispo_pl.config_files import config_root

    from . import beside_paper

    grid = load_grid(name, config_root())
    for stream in grid.streams:
        with suppress(FileNotFoundError):  # nothing committed for it yet
            write_report(root / stream, stream)
    written = write_grid_report(grid, root, reports=beside_paper.grid_reports)
    for path in [*written, beside_paper.write_beside_paper_figure(grid, root)]:
        if path is not None:
            print(f"[lab] wrote {path}")


def claims(folder: Path) -> None:
    from .claims import write_claims_report

    write_claims_report(folder)
    print(f"[lab] wrote {folder / 'claims.md'}")


def manifests(root: Path) -> None:
    from .manifest import write_manifests

    for path in write_manifests(root):
        print(f"[lab] wrote {path}")


def benchmark(argv: Sequence[str]) -> int:
    """``hispo-pl benchmark ARGS``, each launched run's ``run.json`` recording the checkout's
    commit; a grid's reports then rewritten as this repository commits them."""
    from hispo_pl.benchmark import command_line, plan
    from hispo_pl.stopping import signals_stop_the_command, stop_exit_code

    from .provenance import checkout_commit

    plan.CODE_RECORDERS.append(checkout_commit)
    received: list[int] = []
    try:  # SIGTERM stops the runs as Ctrl-C does (their rerun resumes), as hispo-pl's does
        with signals_stop_the_command() as received:
            code = command_line.main(list(argv))
    except (KeyboardInterrupt, Exception) as err:
        stopped = stop_exit_code("python -m lab benchmark", err, received)
        if stopped is None:
            raise
        return stopped
    finally:  # for this launch only: the product itself records no commit
        plan.CODE_RECORDERS.remove(checkout_commit)
    args, _ = command_line.build_parser().parse_known_args(list(argv))
    if code == 0 and args.grid and args.export and not args.dry_run:
        grid_reports(args.grid, Path(args.export))
    return code


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m lab", description=__doc__.split("\n\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    verbs.add_parser("rebuild", help="grid reports, claims, manifests, then every page")
    docs = verbs.add_parser("rebuild-docs", help="rebuild the reports pages embed")
    docs.add_argument("pages", nargs="*", help="the pages (default: every page with an embed)")
    grid = verbs.add_parser("grid-reports", help="a grid's stream tables and reports")
    grid.add_argument("grid", nargs="?", default="paper")
    grid.add_argument("--root", type=Path, default=RESULTS)
    verbs.add_parser("claims", help=f"{CLAIMS}/claims.md")
    made = verbs.add_parser("manifests", help="the MANIFEST.md of every reference folder")
    made.add_argument("root", nargs="?", type=Path, default=RESULTS)
    moved = verbs.add_parser("migrate", help="rewrite run files of earlier formats as current")
    moved.add_argument("root", nargs="?", type=Path, default=RESULTS)
    moved.add_argument("--check", action="store_true", help="only say which files would change")
    drift = verbs.add_parser(
        "config-drift", help="whether a grid's committed runs trained as it would train them today"
    )
    drift.add_argument("--grid", default="paper")
    drift.add_argument("--part", default=None, help="a part or stream of the grid (default: all)")
    drift.add_argument("--root", type=Path, default=RESULTS, help="where its runs are committed")
    verbs.add_parser("benchmark", help="hispo-pl benchmark, recording the checkout's commit")
    argv = list(sys.argv[1:] if argv is None else argv)
    verb = argv[0] if argv[:1] == ["benchmark"] else None
    args = None if verb else parser.parse_args(argv)
    try:
        if verb:  # every other argument is the benchmark's
            return benchmark(argv[1:])
        if args.verb == "migrate":
            from .migrate import migrate

            return migrate(args.root, check=args.check)
        if args.verb == "config-drift":
            from .drift import report_drift

            return 1 if report_drift(args.grid, args.part, args.root) else 0
        run(args)
    except UserError as err:  # a flag, page or run file to fix: one line, as hispo-pl says it
        print(f"python -m lab {verb or args.verb}: {err}", file=sys.stderr)
        return 2
    return 0


def run(args: argparse.Namespace) -> None:
    from hispo_pl.console import lightning_notices_held

    with lightning_notices_held():  # the reports build modules (PNN's growth) through Lightning
        _run(args)


def _run(args: argparse.Namespace) -> None:
    if args.verb == "rebuild":
        for name, root in GRIDS.items():
            grid_reports(name, root)
        claims(CLAIMS)
        manifests(RESULTS)
        rebuild_docs([])
    elif args.verb == "rebuild-docs":
        rebuild_docs(args.pages)
    elif args.verb == "grid-reports":
        grid_reports(args.grid, args.root)
    elif args.verb == "claims":
        claims(CLAIMS)
    elif args.verb == "manifests":
        manifests(args.root)


if __name__ == "__main__":
    sys.exit(main())
