"""Single-task success of several settings on many mazes, side by side: one ``hispo-pl fit``
per (setting, task, seed), run in parallel processes by the benchmark's runner
(:mod:`hispo_pl.benchmark`: a finished run is skipped, each run's output goes to ``fit.log`` in
its run directory), then ``table.md`` and ``table.csv`` (success mean ± std over seeds).

A setting is a config file (the paper's HBC-vs-BC table, appendix E.1)::

    python benchmarks/single_task_table.py --config configs/hbc/amazeville.yaml \\
        --config configs/bc/amazeville.yaml --tasks amazeville --out results/amazeville-single \\
        --workers 2 -- --trainer.max_steps 10000 --data.batch_size 512

or one config with named overrides (``--setting NAME='--flag value ...'``, one column each)::

    python benchmarks/single_task_table.py --config 'configs/hbc/pointmaze-{maze}.yaml' \\
        --setting episode='--data.goal_horizon episode' --setting segment='' \\
        --tasks pointmaze-medium-N,pointmaze-large-N --seeds 0,1 --out results/relabel

``{maze}`` in a config path stands for each task's maze. ``--tasks`` takes task specs and
family names (a family = all its mazes). Arguments after ``--`` go to every fit.
``--report-only`` rebuilds the tables from the runs' results under ``--out``.
"""

from __future__ import annotations

import argparse
import csv
import shlex
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hispo_pl.benchmark import (
    FIT_MODULE,
    RUNS_DIR,
    PlannedRun,
    finished_run_dirs,
    pending_runs,
    provenance,
    record_status,
    run_env,
    run_local,
)
from hispo_pl.results import TaskFitResult
from hispo_pl.rundir import RunDir
from hispo_pl.task_families import FAMILIES
from hispo_pl.tasks import parse_task

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # a script of the checkout: its lab/
from lab.provenance import checkout_commit  # noqa: E402


@dataclass(frozen=True)
class Setting:
    """One column of the table: a config (``{maze}`` filled per task) and overrides."""

    name: str
    config: str
    overrides: tuple[str, ...] = ()

    def config_for(self, task: str) -> Path:
        return Path(self.config.format(maze=parse_task(task).maze))


def expand_tasks(items: list[str]) -> list[str]:
    """Task specs, a family name standing for all its mazes (at the family's default size)."""
    out = []
    for item in items:
        if item in FAMILIES:
            out += [f"{item}-{maze}" for maze in FAMILIES[item].mazes]
        else:
            out.append(str(parse_task(item)))
    return out


def parse_settings(configs: list[str], named: list[str]) -> list[Setting]:
    """``--config`` files as settings named by their folder (hbc, bc), or, with ``--setting``,
    one setting per ``NAME=OVERRIDES`` on the one config."""
    if not named:
        return [Setting(Path(c).parent.name, c) for c in configs]
    if len(configs) != 1:
        raise SystemExit("--setting needs exactly one --config")
    settings = []
    for item in named:
        name, sep, overrides = item.partition("=")
        if not sep or not name:
            raise SystemExit(f"--setting {item!r}: expected NAME='--flag value ...'")
        settings.append(Setting(name, configs[0], tuple(shlex.split(overrides))))
    return settings


def run_name(setting: Setting, task: str) -> str:
    """``hbc-amazeville-HOOO``: the setting and the task's maze."""
    t = parse_task(task)
    return f"{setting.name}-{t.family}-{t.maze}"


def run_dir(out: Path, setting: Setting, task: str, seed: int) -> RunDir:
    return RunDir(out / RUNS_DIR / run_name(setting, task) / f"seed{seed}")


def fit_argv(setting: Setting, task: str, seed: int, out: Path, extra: list[str]) -> list[str]:
    return [
        *FIT_MODULE, "fit", "--config", str(setting.config_for(task)),
        "--data.task", task,
        "--seed_everything", str(seed),
        "--trainer.logger.init_args.save_dir", str(out / RUNS_DIR),
        "--trainer.logger.init_args.name", run_name(setting, task),
        "--trainer.logger.init_args.version", f"seed{seed}",
        *setting.overrides,
        *extra,
    ]  # fmt: skip


def plan_runs(
    settings: list[Setting], tasks: list[str], seeds: list[int], out: Path, extra: list[str]
) -> list[PlannedRun]:
    """One single-task run of the benchmark's runner per (task, setting, seed)."""
    return [
        PlannedRun(
            run_name(setting, task),
            seed,
            run_dir(out, setting, task, seed).path,
            tuple(fit_argv(setting, task, seed, out, extra)),
            single_task=True,
        )
        for task in tasks
        for setting in settings
        for seed in seeds
    ]


def progress_lines(total: int, done: int) -> Callable[[PlannedRun, dict], None]:
    """What :func:`~hispo_pl.benchmark.run_local` calls for each finished run: a line with its
    success, or with where its log is when it failed."""
    start = time.perf_counter()

    def report(run: PlannedRun, outcome: dict) -> None:
        nonlocal done
        done += 1
        r = outcome["results"]
        if r is None:
            why = f"failed (exit {outcome['returncode']})"
            record_status(run, f"{why}; log: {run.log_path}")
            print(f"[{done}/{total}] {run.run_dir} {why}; see {run.log_path}", flush=True)
            return
        print(
            f"[{done}/{total}] {run.method} seed {run.seed}: "
            f"{100 * r['success']:.0f} % ({r['seconds']:.0f} s)  "
            f"{time.perf_counter() - start:.0f} s elapsed",
            flush=True,
        )

    return report


def collect_results(out: Path, settings: list[Setting], tasks: list[str]) -> dict:
    """(setting name, task) -> the results of every finished seed under ``out``."""
    by_name: dict[str, list[TaskFitResult]] = {}
    for path in finished_run_dirs(out, RunDir.RESULT):
        by_name.setdefault(path.parent.name, []).append(RunDir(path).read_result())
    return {
        (setting.name, task): by_name[run_name(setting, task)]
        for setting in settings
        for task in tasks
        if run_name(setting, task) in by_name
    }


def write_tables(out: Path, settings: list[Setting], tasks: list[str], results: dict) -> str:
    """Success % mean ± std over seeds (and mean episode length) per task and setting, as
    markdown and CSV (one CSV row per run)."""
    names = [s.name for s in settings]
    lines = [
        "| task | " + " | ".join(f"{n} success % (length)" for n in names) + " | seeds | steps |",
        "|---|" + "---:|" * (len(names) + 2),
    ]
    rows = []
    for task in tasks:
        cells, steps, seeds = [], "", ""
        for name in names:
            runs = results.get((name, task), [])
            if not runs:
                cells.append("–")
                continue
            success = [100 * r.success for r in runs]
            length = statistics.fmean(r.episode_length for r in runs)
            spread = f" ± {statistics.pstdev(success):.1f}" if len(runs) > 1 else ""
            cells.append(f"{statistics.fmean(success):.1f}{spread} ({length:.0f})")
            steps, seeds = str(int(runs[0].step)), str(len(runs))
            rows += [{"task": task, "setting": name, **r.to_json()} for r in runs]
        lines.append(f"| {task} | " + " | ".join(cells) + f" | {seeds} | {steps} |")
    table = "\n".join(lines) + "\n"
    (out / "table.md").write_text(table)
    if rows:
        with (out / "table.csv").open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return table


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", action="append", required=True)
    parser.add_argument("--setting", action="append", default=[], help="NAME='--flag value'")
    parser.add_argument("--tasks", required=True, help="comma list of task specs / family names")
    parser.add_argument("--seeds", default="0", help="comma list of seeds")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--report-only", action="store_true")
    args = parser.parse_args(argv)
    settings = parse_settings(args.config, args.setting)
    tasks = expand_tasks(args.tasks.split(","))
    seeds = [int(s) for s in args.seeds.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.report_only:
        runs = plan_runs(settings, tasks, seeds, args.out, extra)
        todo = pending_runs(runs, stream=None, made_on=provenance().merged(checkout_commit()))
        report = progress_lines(len(runs), len(runs) - len(todo))
        run_local(todo, args.workers, report, run_env(1))
    results = collect_results(args.out, settings, tasks)
    print(write_tables(args.out, settings, tasks, results))
    expected = len(settings) * len(tasks) * len(seeds)
    return 0 if sum(len(v) for v in results.values()) >= expected else 1


if __name__ == "__main__":
    raise SystemExit(main())
