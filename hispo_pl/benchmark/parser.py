"""The ``hispo-pl benchmark`` command line: its options and their help."""

from __future__ import annotations

import argparse
import os

from ..cli_common import NUM_THREADS_FLAGS
from ..cli_errors import VerbParser


def cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def positive_int(text: str) -> int:
    """An option's count (runs at a time, threads, steps): an integer of at least 1.

    Example:
        >>> positive_int("2")
        2
    """
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, not {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = VerbParser(
        prog="hispo-pl benchmark",
        usage=(
            "hispo-pl benchmark --stream STREAM --out OUT [options] [-- fit overrides...]\n"
            "       hispo-pl benchmark --grid NAME --out WORK --export ROOT [--part PART] "
            "[options]"
        ),
        description=(
            "Run every (method, seed) of a stream as a `hispo-pl fit` subprocess logging to\n"
            "OUT/runs/<method>/seed<S>/ (resumable: runs with a results.json are skipped,\n"
            "interrupted ones resume), then write OUT/table.md and table.csv (PER, BWT, FWT\n"
            "x100 and MEM, mean ± std over seeds), runtime.csv and perf_vs_memory.png.\n"
            "Arguments after `--` are passed to every `hispo-pl fit`."
        ),
        epilog=(
            "examples:\n"
            "  hispo-pl benchmark --stream pointmaze-1 --methods all --seeds 3 "
            "--out results/pointmaze-1\n"
            "  hispo-pl benchmark --stream pointmaze-2 --methods hispo,scn --seeds 0,4 "
            "--out results/pm2 -- --data.batch_size 512\n"
            "  hispo-pl benchmark --stream pointmaze-1 --methods all --seeds 3 --out "
            "results/pointmaze-1 --launcher ray --address auto\n"
            "  hispo-pl benchmark --out results/pointmaze-1 --report-only\n"
            "  hispo-pl benchmark --grid paper --part pointmaze --out results/grid --export "
            "results/kept"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--stream",
        help="stream name (CONFIG_DIR/streams/<name>.yaml), a random stream "
        "random-<family>-<n>@<seed> (on its family's <family>-1.yaml), or a YAML path",
    )
    parser.add_argument(
        "--methods",
        default="all",
        help="'all' (every CONFIG_DIR/methods/*.yaml, sorted) or a comma list (default: all)",
    )
    parser.add_argument(
        "--seeds",
        help="a count N (seeds 0..N-1) or a comma list such as 0,4 (default: 3; with --grid: "
        "the grid's seeds, of which these select some)",
    )
    parser.add_argument("--out", help="output folder (runs/, tables, figure)")
    parser.add_argument(
        "--steps-per-task",
        type=positive_int,
        default=None,
        help="gradient steps per task (--trainer.max_steps); default: the stream config's own "
        "value (6000 in configs/streams/pointmaze-*.yaml; the authors' code's 100000)",
    )
    parser.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="local: runs at a time (default: CPU cores // threads, at least 1); ray with "
        "--address local: the private instance gets workers x threads CPUs",
    )
    parser.add_argument(
        *NUM_THREADS_FLAGS,  # as every verb takes it
        type=positive_int,
        default=1,
        help="torch threads (and Ray CPUs) per run, fit's --num_threads (default: 1)",
    )
    parser.add_argument(
        "--launcher",
        choices=("local", "ray"),
        default="local",
        help="local: parallel processes on this machine (default); ray: one Ray remote task "
        "per run",
    )
    parser.add_argument(
        "--address",
        default=None,
        help="ray: 'local' (a private instance), 'auto' (the running cluster) or "
        "ray://host:10001; default: RAY_ADDRESS, else a local instance",
    )
    parser.add_argument(
        "--config-dir",
        default=None,
        help="where streams/ and methods/ live (default: ./configs in a checkout, else the "
        "packaged configs)",
    )
    parser.add_argument(
        "--grid",
        metavar="NAME",
        default=None,
        help="run a grid (CONFIG_DIR/grids/<name>.yaml, e.g. paper) instead of one stream: "
        "every run not yet committed under --export ROOT, logging to --out WORK, each "
        "exported to ROOT/<stream>/ as it finishes; rerun to go on",
    )
    parser.add_argument(
        "--part",
        default=None,
        help="with --grid: only these streams (a part of the grid, such as pointmaze, or a "
        "stream; a comma list of either)",
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="print the planned fit commands; run nothing"
    )
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="only rebuild the tables and figure in OUT from the finished runs",
    )
    parser.add_argument(
        "--export",
        metavar="DEST",
        default=None,
        help="copy every finished run's small files (results, decisions, config) to "
        "DEST/<method>/seed<S>/ and write the report there (e.g. results/kept/pointmaze-1)",
    )
    return parser
