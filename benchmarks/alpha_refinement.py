"""Is a point of the grown subspace better than the weights a HiSPO task was trained with?

For task K of a finished stream run, loads ``task_K.ckpt`` and rolls out task K's policy with
three anchor-weight choices per subspace: the stored weights, the best of a race over the grown
subspace (the stored weights, the newest anchor alone and 1,024 Dirichlet draws over every
anchor, scored on 16 batches of task K: what ``DirichletEvaluation(refine_current=True)``
does), and the newest anchor alone. Prints success over 100 seeded episodes and the loss.

    python benchmarks/alpha_refinement.py --run runs/pointmaze-1/seed0 --task 4
"""

from __future__ import annotations

import argparse

import torch

from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.decisions import extended_subspace_candidates
from hispo_pl.evaluation import RolloutEvaluator, module_policy
from hispo_pl.modules import GoalConditionedBC
from hispo_pl.nn import eval_mode
from hispo_pl.rundir import RunDir, task_label
from hispo_pl.search import race_subspace
from hispo_pl.tasks import parse_task


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--run", required=True, help="a finished HiSPO stream run dir")
    p.add_argument("--task", type=int, required=True, help="task K (1-based)")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    run, k = RunDir(args.run), args.task - 1
    stream = run.read_progress()["stream"]
    module = GoalConditionedBC.from_checkpoint_file(str(run.checkpoint(k)))
    dm = TaskDataModule(task=stream[k], stream=stream)
    dm.setup("fit")
    batches = dm.fixed_batches(16, seed=0)
    probe = {key: v[:256] for key, v in batches[0].items()}
    generator = torch.Generator().manual_seed(0)
    evaluator = RolloutEvaluator(parse_task(stream[k]), args.episodes, seed=0)
    stored = {n: module.task_alphas(n)[k].clone() for n in module.subspace_names}
    newest = {n: torch.eye(module.n_anchors(n))[-1] for n in module.subspace_names}
    searched = {}
    with eval_mode(module):
        for name in module.subspace_names:
            cands = extended_subspace_candidates(1024, stored[name], generator)
            searched[name] = cands[race_subspace(module, name, cands, batches, probe, 32).best]
    print(f"task {task_label(k)}: {stream[k]} ({args.episodes} episodes)")
    for label, alphas in (("stored", stored), ("searched", searched), ("newest", newest)):
        for name, alpha in alphas.items():
            rows = module.task_alphas(name).clone()
            rows[k] = alpha
            module._set_task_alphas(name, rows)
        result = evaluator.run(module_policy(module, task=k))
        with eval_mode(module):
            loss = {
                n: round(float(module.score_alphas(n, a[None], batches[0])[0]), 4)
                for n, a in alphas.items()
            }
        weights = {n: [round(x, 2) for x in a.tolist()] for n, a in alphas.items()}
        print(f"  {label:<9} success {100 * result.success:5.1f} %  loss {loss}  weights {weights}")


if __name__ == "__main__":
    main()
