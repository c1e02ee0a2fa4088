"""How far is the best point of a finished HiSPO run's subspace from the data of each next task?

For each task k ≥ 2 of a stream run, loads the checkpoint written after task k-1, searches its
subspaces (1,024 Dirichlet candidates raced on 4 batches of task k, as ZeroShotTransfer does)
and prints quantiles of the prediction distance d(a, â) and the PAC rate P[d <= eps] for a few
eps: what ZeroShotTransfer's eps_high / eps_low / delta must separate (a repeated task should
pass, a new variant fail).

    python benchmarks/pac_calibration.py --run runs/pointmaze-2/seed0
"""

from __future__ import annotations

import argparse

import torch

from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.decisions import pac_rate
from hispo_pl.modules import GoalConditionedBC
from hispo_pl.nn import eval_mode
from hispo_pl.nn.subspace import sample_dirichlet
from hispo_pl.rundir import RunDir, task_label
from hispo_pl.search import race_subspace


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument(
        "--run", required=True, help="a finished stream run dir (progress.json, task_XX.ckpt)"
    )
    p.add_argument("--eps", type=float, nargs="+", default=[0.25, 0.5, 1.0])
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    run = RunDir(args.run)
    stream = run.read_progress()["stream"]
    for k in range(1, len(stream)):  # task k's data, scored with the anchors after task k - 1
        module = GoalConditionedBC.from_checkpoint_file(str(run.checkpoint(k - 1)))
        dm = TaskDataModule(task=stream[k], stream=stream)
        dm.setup("fit")
        batches = dm.fixed_batches(4, seed=0)
        probe = {key: v[:256] for key, v in batches[0].items()}
        generator = torch.Generator().manual_seed(0)
        with eval_mode(module):
            for name in module.subspace_names:
                cands = sample_dirichlet(1024, module.n_anchors(name), generator)
                best = cands[race_subspace(module, name, cands, batches, probe, 32).best]
                per_policy = [module.prediction_distances(name, best, b) for b in batches]
                for policy in per_policy[0]:
                    d = torch.cat([x[policy] for x in per_policy])
                    q = torch.quantile(d, torch.tensor([0.5, 0.9, 0.95])).tolist()
                    rates = "  ".join(f"P[d<={e}] {pac_rate(d, e):.3f}" for e in args.eps)
                    print(
                        f"T{task_label(k - 1):02d} -> T{task_label(k):02d} {stream[k]:<28} "
                        f"{policy:<4} "
                        f"d quantiles 50/90/95 {q[0]:.3f} / {q[1]:.3f} / {q[2]:.3f}  {rates}"
                    )


if __name__ == "__main__":
    main()
