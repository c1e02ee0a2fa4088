"""``hispo-pl benchmark``: every method × seed on one stream, then the paper's tables.

    hispo-pl benchmark --stream pointmaze-1 --methods all --seeds 3 --out results/pointmaze-1

Each run is one ``hispo-pl fit`` subprocess (the stream config, then the method config) that
logs to ``OUT/runs/<method>/seed<S>/``; ``fit`` itself resumes a stream at task granularity,
so the runner only skips runs whose ``results.json`` exists and reruns the others with the
same command. Runs go to local worker processes or, with ``--launcher ray``, to Ray remote
tasks. Afterwards ``OUT/table.md``, ``table.csv``, ``runtime.csv`` and ``perf_vs_memory.png``
are rebuilt from every ``results.json`` under ``OUT/runs`` (``--report-only`` does just that).
The same runner launches single-task fits, finished by their ``result.json``
(``PlannedRun.single_task``; ``benchmarks/single_task_table.py``).

Planning (methods, seeds, command lines) and aggregation (FWT against the SC run of the same
seed, mean ± std over seeds, table text) are pure functions; only the launchers touch
processes. numpy only at import, so Ray workers start quickly; matplotlib and ray lazily.

The package: ``plan`` (methods, seeds, commands, what is left to run), ``configs`` (settings
read from the runs' own YAML files), ``launch`` (local processes or Ray), ``finished_runs``
(finished runs and their aggregation), ``tables`` and ``report`` (what is written), ``parser``
and ``command_line`` (the command line). Every name is importable from ``hispo_pl.benchmark``
itself.
"""

from __future__ import annotations

from .command_line import main
from .configs import configured_max_steps, configured_value, datasets_needed, prepare_datasets
from .finished_runs import (
    MethodRow,
    RunRecord,
    aggregate,
    export_runs,
    finished_run_dirs,
    format_mean_std,
    load_records,
    mean_std,
    run_metrics,
    scratch_method_for,
)
from .launch import TAIL_LINES, Reporter, execute_run, record_status, run_env, run_local, run_ray
from .parser import build_parser, cpu_count
from .plan import (
    FIT_MODULE,
    PLAN_FILE,
    RUNS_DIR,
    PlannedRun,
    fit_argv,
    known_methods,
    parse_seeds,
    pending_runs,
    plan_runs,
    provenance,
    select_methods,
    stream_config_path,
)
from .report import (
    plot_perf_vs_memory,
    unfinished_markdown,
    unfinished_runs,
    write_report,
)
from .tables import (
    critic_markdown,
    loss_decisions_markdown,
    runtime_csv,
    table_csv,
    table_markdown,
)

__all__ = [
    "FIT_MODULE",
    "MethodRow",
    "PLAN_FILE",
    "PlannedRun",
    "RUNS_DIR",
    "Reporter",
    "RunRecord",
    "TAIL_LINES",
    "aggregate",
    "build_parser",
    "cpu_count",
    "configured_max_steps",
    "configured_value",
    "datasets_needed",
    "critic_markdown",
    "execute_run",
    "export_runs",
    "finished_run_dirs",
    "fit_argv",
    "format_mean_std",
    "known_methods",
    "load_records",
    "loss_decisions_markdown",
    "main",
    "mean_std",
    "parse_seeds",
    "pending_runs",
    "plan_runs",
    "provenance",
    "plot_perf_vs_memory",
    "prepare_datasets",
    "record_status",
    "run_env",
    "run_local",
    "run_metrics",
    "run_ray",
    "runtime_csv",
    "scratch_method_for",
    "select_methods",
    "stream_config_path",
    "table_csv",
    "table_markdown",
    "unfinished_markdown",
    "unfinished_runs",
    "write_report",
]
