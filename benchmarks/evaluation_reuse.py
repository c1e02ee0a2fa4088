"""What reusing rollouts saves at the ends of a finished stream's tasks: each row of R measured
again from the run's task checkpoints through the product's own row evaluation
(:meth:`~hispo_pl.callbacks.RolloutEvaluation.evaluate_row`, with the run's episodes and
seed), reusing the rollouts of a policy that did not change and, right after it, rolling out
every entry, each checked bit for bit against the run's committed R:

    python benchmarks/evaluation_reuse.py results/grid/antmaze-1/runs/ftn/seed0 [--threads 1]

The run directory needs its ``task_XX.ckpt`` files and ``config.yaml`` (a grid's work folder).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
import yaml

from hispo_pl.benchmark.derive import run_rollout_evaluation
from hispo_pl.evaluation import RolloutEvaluator
from hispo_pl.modules import GoalConditionedBC
from hispo_pl.rundir import RunDir


class MeasuredRows:
    """One way of measuring rows: its own evaluation callback (whose reuse spans the rows),
    the rows, the rollouts each ran and its seconds."""

    def __init__(self, config: dict, reuse: bool):
        self.evaluation, self.reuse = run_rollout_evaluation(config), reuse
        self.rows: list[list[float]] = []
        self.ran: list[int] = []
        self.seconds: list[float] = []

    def measure(self, run: RunDir, tasks: list[str], i: int, calls: list) -> None:
        module = GoalConditionedBC.from_checkpoint_file(str(run.checkpoint(i)))
        if not self.reuse:
            module.acting_digest = lambda task: None
        before, start = len(calls), time.perf_counter()
        self.rows.append([r.success for r in self.evaluation.evaluate_row(tasks, module, i)])
        self.seconds.append(time.perf_counter() - start)
        self.ran.append(len(calls) - before)


def measure_rows(run: RunDir) -> tuple[MeasuredRows, MeasuredRows]:
    """Every row of ``run`` measured reusing rollouts and then every entry, row by row (so the
    two see the same load on the machine)."""
    config = yaml.safe_load(run.config_file.read_text()) or {}
    tasks = list(run.stream_results().stream)
    reused, every = MeasuredRows(config, True), MeasuredRows(config, False)
    calls: list[int] = []
    rolled = RolloutEvaluator.run

    def counted(self, *args, **kwargs):
        calls.append(1)
        return rolled(self, *args, **kwargs)

    RolloutEvaluator.run = counted
    try:
        for i in range(len(tasks)):
            for way in (reused, every):
                way.measure(run, tasks, i, calls)
    finally:
        RolloutEvaluator.run = rolled
    return reused, every


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a finished run's directory, with checkpoints")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    run = RunDir(args.run)
    committed = [list(map(float, row)) for row in run.stream_results().R]
    reused, every = measure_rows(run)
    print(f"{args.run}: {len(committed)} tasks, {args.threads} thread(s)")
    print("row | rollouts reused / every entry | seconds reused / every entry | ratio")
    for i in range(len(committed)):
        print(
            f"{i + 1:>3} | {reused.ran[i]:>2} / {every.ran[i]:>2} | "
            f"{reused.seconds[i]:7.1f} / {every.seconds[i]:7.1f} | "
            f"{reused.seconds[i] / every.seconds[i]:.2f}"
        )
    a, b = sum(reused.seconds), sum(every.seconds)
    print(f"all | {sum(reused.ran)} / {sum(every.ran)} | {a:.1f} / {b:.1f} | {a / b:.2f}")
    for way in (reused, every):
        name = "reused" if way.reuse else "every entry"
        print(f"R {name} equals the run's committed R: {way.rows == committed}")


if __name__ == "__main__":
    main()
