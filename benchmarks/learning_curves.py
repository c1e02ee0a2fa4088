"""Learning curves of single-task runs: how many steps a recipe needs before each maze's
success stops moving, and the budget B that follows (:mod:`hispo_pl.benchmark.curves`).

Each (setting, maze, seed) is one ``hispo-pl fit`` of ``configs/<setting>/<family>-<maze>.yaml``
evaluated every ``--every`` steps, launched and resumed by ``single_task_table.py`` (a finished
run is skipped). The paper's recipe on PointMaze, HBC then flat BC, two seeds, 100,000 steps::

    python benchmarks/learning_curves.py --tasks pointmaze --settings hbc,bc --seeds 0,1 \\
        --steps 100000 --every 10000 --out results/curves --export docs/results/curves \\
        -- --preset paper

writes ``curves.md`` (success per step, mean ± std over seeds, and B), ``curves.csv`` and
``curves.png`` into ``--export`` beside each finished run's small files (``result.json``,
``config.yaml``, ``run.json``). ``--report-only`` rebuilds them from ``--export`` alone;
``--collect`` exports the runs finished so far (another process may still run the rest).
Arguments after ``--`` go to every fit.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

from hispo_pl.benchmark.curves import CURVES_FILE, write_curves_report
from hispo_pl.io import copy_files, real_folder
from hispo_pl.tasks import parse_task


def _single_task_table():
    """The runner beside this script (the folder is not a package)."""
    if "single_task_table" not in sys.modules:
        path = Path(__file__).with_name("single_task_table.py")
        spec = importlib.util.spec_from_file_location("single_task_table", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
    return sys.modules["single_task_table"]


EXPORTED = ("result.json", "config.yaml", "run.json")


def export_runs(out: Path, dest: Path) -> list[Path]:
    """Copy the small files of every finished single-task run under ``out/runs`` to the same
    place under ``dest/runs``, as every export does (a link at either end is not followed)."""
    written = []
    for result in sorted((Path(out) / "runs").glob("*/seed*/result.json")):
        source = result.parent
        target = real_folder(Path(dest) / source.relative_to(out), dest)
        pairs = [(source / n, target / n) for n in EXPORTED if (source / n).is_file()]
        written += copy_files(pairs)
    return written


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", required=True, help="comma list of task specs / family names")
    parser.add_argument("--settings", default="hbc,bc", help="config folders, comma list")
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--steps", type=int, default=100_000, help="steps per run")
    parser.add_argument("--every", type=int, default=10_000, help="steps between evaluations")
    parser.add_argument("--tolerance", type=float, default=2.0, help="success points for B")
    parser.add_argument(
        "--no-budget",
        action="store_true",
        help="a study of what a setting changes at a budget already chosen: choose none",
    )
    parser.add_argument("--out", type=Path, default=Path("results/curves"))
    parser.add_argument("--export", type=Path, required=True)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--config-dir", type=Path, default=Path("configs"))
    parser.add_argument("--report-only", action="store_true", help="rebuild from --export alone")
    parser.add_argument(
        "--collect", action="store_true", help="export the runs finished under --out, launch none"
    )
    args = parser.parse_args(argv)
    settings = [s.strip() for s in args.settings.split(",") if s.strip()]
    runner = _single_task_table()
    tasks = [parse_task(t) for t in runner.expand_tasks(args.tasks.split(","))]
    if len({t.family for t in tasks}) != 1:
        parser.error("--tasks: one family at a time (its configs are <setting>/<family>-<maze>)")
    if args.collect:
        export_runs(args.out, args.export)
    elif not args.report_only:
        for setting in settings:  # the budget's setting first: its curves choose B
            config = str(args.config_dir / setting / f"{tasks[0].family}-{{maze}}.yaml")
            runner.main(
                ["--config", config, "--tasks", ",".join(map(str, tasks)), "--seeds", args.seeds,
                 "--out", str(args.out), "--workers", str(args.workers), "--",
                 *extra, "--trainer.max_steps", str(args.steps), "--eval_every", str(args.every)]
            )  # fmt: skip
        export_runs(args.out, args.export)
    args.export.mkdir(parents=True, exist_ok=True)
    study = {
        "settings": settings,
        "tasks": [f"{t.family}-{t.maze}" for t in tasks],
        "budget_setting": None if args.no_budget else settings[0],
        "tolerance": args.tolerance,
    }
    (args.export / CURVES_FILE).write_text(json.dumps(study, indent=1) + "\n")
    print(write_curves_report(args.export))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
