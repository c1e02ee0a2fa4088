"""Which training choices make the high policy learn faster? Trains only a fresh high policy
(the part that limits HBC on M and L) for ``--steps`` steps and evaluates it with the low
policy of an already trained HBC checkpoint, over 100 seeded episodes.

    python benchmarks/high_policy_study.py --ckpt RUN/checkpoints/last.ckpt \\
        --task pointmaze-medium [--steps 10000] [--hidden 64] [--lr 1e-3] [--dropout 0.1]
        [--loss nll|mse] [--fourier 0] [--her-strategy exponential] [--her-temperature T]

Prints one ``RESULT`` line: the settings, the success rate, the training time.
"""

from __future__ import annotations

import argparse
import math
import time

import torch
from torch import nn

from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.data.sampler import HERSampler
from hispo_pl.evaluation import RolloutEvaluator
from hispo_pl.modules.hbc import HBC, GoalConditionedBC
from hispo_pl.nn.mlp import GaussianPolicy, gaussian_nll


class FourierFeatures(nn.Module):
    """sin / cos of random projections of (position, goal): a sharper spatial input."""

    def __init__(self, n: int, sigma: float, goal_dim: int = 2):
        super().__init__()
        g = torch.Generator().manual_seed(0)
        self.register_buffer("B", torch.randn(2 * goal_dim, n, generator=g) * sigma)

    def forward(self, position, goal):
        z = 2 * math.pi * torch.cat([position, goal], -1) @ self.B
        return torch.cat([z.sin(), z.cos()], -1)


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--ckpt", required=True, help="a trained HBC checkpoint (its low policy)")
    p.add_argument("--task", required=True)
    p.add_argument("--steps", type=int, default=10000)
    p.add_argument("--hidden", type=int, default=64)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--dropout", type=float, default=0.1)
    p.add_argument("--loss", choices=["nll", "mse"], default="nll")
    p.add_argument("--fourier", type=int, default=0, help="Fourier features (0: none)")
    p.add_argument("--sigma", type=float, default=0.5, help="their frequency scale (1/m)")
    p.add_argument("--her-strategy", default="exponential")
    p.add_argument("--her-temperature", type=float, default=None)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)

    hbc = GoalConditionedBC.from_checkpoint_file(args.ckpt)
    dm = TaskDataModule(
        task=args.task, her_temperature=args.her_temperature, her_strategy=args.her_strategy
    )
    dm.setup("fit")
    sampler = HERSampler(dm.data, dm.her, dm.batch_size, seed=0)
    ff = FourierFeatures(args.fourier, args.sigma) if args.fourier else None

    def high_input(obs, pos, goal):
        x = HBC.high_input(obs, pos, goal)
        return torch.cat([x, ff(pos, goal)], -1) if ff is not None else x

    b = sampler.sample()
    in_dim = high_input(b["observation"], b["position"], b["goal"]).shape[-1]
    high = GaussianPolicy(in_dim, args.hidden, 2, args.dropout)
    opt = torch.optim.Adam(high.parameters(), lr=args.lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(opt, args.steps)
    start = time.perf_counter()
    for _ in range(args.steps):
        b = sampler.sample()
        mean, log_std = high(high_input(b["observation"], b["position"], b["goal"]))
        offset = b["subgoal"] - b["position"]
        if args.loss == "mse":
            loss = (mean - offset).pow(2).sum(-1).mean()
        else:
            loss = gaussian_nll(mean, log_std, offset)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        schedule.step()
    train_s = time.perf_counter() - start

    high.eval()
    hbc.eval()

    @torch.no_grad()
    def policy(obs, pos, goal):
        offset, _ = high(high_input(obs, pos, goal))
        return hbc.net.low(hbc.low_input(obs, offset, hbc.net.low_obs))[0]

    result = RolloutEvaluator(args.task, episodes=100, seed=0).run(policy)
    settings = {k: v for k, v in vars(args).items() if k != "ckpt"}
    print(f"RESULT {settings} success={result.success:.2f} train_s={train_s:.0f}")


if __name__ == "__main__":
    main()
