"""Does a task act better with its stored anchor weights or with its own new anchor alone?

A HiSPO checkpoint stores, per task and subspace, the weights its policy acts with (the
Dirichlet search's choice). This probe rolls a task out, through the product's evaluator, with
those weights and with the task's newest anchor alone (its vertex) in the high subspace, the
low one, or both. If the vertex acts better, the search chose badly; if it acts worse, what the
task reached lives in the mixture, i.e. in how the subspace was trained.

    python benchmarks/vertex_probe.py --ckpt RUN/task_02.ckpt --as-task 2 --task amazeville-HXOO
"""

from __future__ import annotations

import argparse
import json

import torch

from hispo_pl.evaluation import RolloutEvaluator, module_policy
from hispo_pl.modules.hbc import GoalConditionedBC
from hispo_pl.modules.hispo import HiSPO


def vertex(alpha: torch.Tensor) -> torch.Tensor:
    """The newest anchor a task weighs (its last non-zero weight) alone."""
    out = torch.zeros_like(alpha)
    out[int(alpha.nonzero().max())] = 1.0
    return out


def weight_variants(stored: dict[str, torch.Tensor]) -> dict[str, dict[str, torch.Tensor]]:
    """The stored weights and the three ways of replacing them by the vertex."""
    high, low = stored["high"], stored["low"]
    return {
        "stored": {"high": high, "low": low},
        "high vertex": {"high": vertex(high), "low": low},
        "low vertex": {"high": high, "low": vertex(low)},
        "both vertices": {"high": vertex(high), "low": vertex(low)},
    }


def probe(module: HiSPO, task_index: int, evaluator: RolloutEvaluator) -> list[dict]:
    """Success of each weight variant of task ``task_index`` (0-based)."""
    stored = {s: module.task_alphas(s)[task_index].clone() for s in module.subspace_names}
    rows = []
    for name, alphas in weight_variants(stored).items():
        for subspace, alpha in alphas.items():
            module.set_task_alpha(task_index, subspace, alpha)
        result = evaluator.run(module_policy(module, task=task_index))
        weights = {s: [round(x, 3) for x in a.tolist()] for s, a in alphas.items()}
        rows.append({"weights": name, "alphas": weights, "success": result.success})
    for subspace, alpha in stored.items():
        module.set_task_alpha(task_index, subspace, alpha)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ckpt", required=True, help="a task_XX.ckpt of a HiSPO stream run")
    parser.add_argument("--as-task", type=int, required=True, help="the stream's task (1-based)")
    parser.add_argument("--task", required=True, help="task spec to roll out on")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--num_threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.num_threads)
    module = GoalConditionedBC.from_checkpoint_file(args.ckpt)
    if not isinstance(module, HiSPO) or set(module.subspace_names) != {"high", "low"}:
        parser.error(f"{args.ckpt} is not a two-subspace HiSPO checkpoint")
    if not 1 <= args.as_task <= module.n_tasks:
        parser.error(f"--as-task must be within 1..{module.n_tasks} for this checkpoint")
    module.eval()
    evaluator = RolloutEvaluator(args.task, args.episodes, args.seed)
    for row in probe(module, args.as_task - 1, evaluator):
        print(json.dumps(row))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
