"""Single-task success of several configs on many mazes, side by side (the paper's HBC-vs-BC
table, appendix E.1): one ``hispo-pl fit`` per (config, task), run in parallel processes,
resumable (a run whose ``result.json`` exists is skipped), then ``table.md`` and ``table.csv``.

    python benchmarks/single_task_table.py --config configs/hbc/amazeville.yaml \\
        --config configs/bc/amazeville.yaml --tasks amazeville --out results/amazeville-single \\
        --workers 2 -- --trainer.max_steps 10000 --data.batch_size 512

``--tasks`` takes task specs and family names (a family = all its mazes). Arguments after
``--`` go to every fit.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from hispo_pl.data.tasks import FAMILIES, parse_task
from hispo_pl.rundir import RunDir


def expand_tasks(items: list[str]) -> list[str]:
    """Task specs, a family name standing for all its mazes (at the family's default size)."""
    out = []
    for item in items:
        if item in FAMILIES:
            out += [f"{item}-{maze}" for maze in FAMILIES[item].mazes]
        else:
            out.append(str(parse_task(item)))
    return out


def run_name(config: Path, task: str) -> str:
    """``hbc-amazeville-HOOO``: the config's folder (hbc, bc) and the task's maze."""
    t = parse_task(task)
    return f"{config.parent.name}-{t.family}-{t.maze}"


def fit_argv(config: Path, task: str, out: Path, extra: list[str]) -> list[str]:
    return [
        sys.executable, "-m", "hispo_pl.cli", "fit", "--config", str(config),
        "--data.task", task,
        "--trainer.logger.init_args.save_dir", str(out / "runs"),
        "--trainer.logger.init_args.name", run_name(config, task),
        "--trainer.logger.init_args.version", "0",
        *extra,
    ]  # fmt: skip


def run_dir(out: Path, config: Path, task: str) -> RunDir:
    return RunDir(out / "runs" / run_name(config, task) / "version_0")


def run_one(config: Path, task: str, out: Path, extra: list[str]) -> dict:
    run = run_dir(out, config, task)
    if run.result_file.exists():
        return run.read_result()
    log = out / "logs" / f"{run_name(config, task)}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as fh:
        proc = subprocess.run(fit_argv(config, task, out, extra), stdout=fh, stderr=fh)
    if proc.returncode != 0 or not run.result_file.exists():
        raise RuntimeError(f"{run_name(config, task)} failed (exit {proc.returncode}); see {log}")
    return run.read_result()


def write_tables(out: Path, configs: list[Path], tasks: list[str], results: dict) -> str:
    """Success % (mean episode length) per task and config, as markdown and CSV."""
    names = [c.parent.name for c in configs]
    lines = [
        "| task | " + " | ".join(f"{n} success % (length)" for n in names) + " | steps |",
        "|---|" + "---:|" * (len(names) + 1),
    ]
    rows = []
    for task in tasks:
        cells, steps = [], ""
        for config in configs:
            r = results.get((config, task))
            if r is None:
                cells.append("–")
                continue
            cells.append(f"{100 * r['success']:.0f} ({r['episode_length']:.0f})")
            steps = str(int(r["step"]))
            rows.append({"task": task, "config": config.parent.name, **r})
        lines.append(f"| {task} | " + " | ".join(cells) + f" | {steps} |")
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
    parser.add_argument("--config", action="append", type=Path, required=True)
    parser.add_argument("--tasks", required=True, help="comma list of task specs / family names")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    tasks = expand_tasks(args.tasks.split(","))
    jobs = [(c, t) for t in tasks for c in args.config]
    args.out.mkdir(parents=True, exist_ok=True)
    results: dict = {}
    start = time.perf_counter()
    with ThreadPoolExecutor(args.workers) as pool:
        futures = {pool.submit(run_one, c, t, args.out, extra): (c, t) for c, t in jobs}
        for done, future in enumerate(as_completed(futures), 1):
            config, task = futures[future]
            try:
                r = results[(config, task)] = future.result()
                print(
                    f"[{done}/{len(jobs)}] {run_name(config, task)}: {100 * r['success']:.0f} % "
                    f"({r['seconds']:.0f} s)  {time.perf_counter() - start:.0f} s elapsed",
                    flush=True,
                )
            except RuntimeError as err:
                print(f"[{done}/{len(jobs)}] {err}", flush=True)
    print(write_tables(args.out, args.config, tasks, results))
    return 0 if len(results) == len(jobs) else 1


if __name__ == "__main__":
    raise SystemExit(main())
