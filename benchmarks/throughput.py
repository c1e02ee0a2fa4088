"""Throughput of the foundation on this machine: HER sampler and HBC / BC gradient steps.

    python benchmarks/throughput.py [--task pointmaze-umaze] [--threads 1 2] [--steps 200]

Prints batches of 1024 per second for the sampler, and gradient steps per second for HBC and
flat BC, both as a bare torch loop and through a Lightning Trainer (what `hispo-pl fit` runs),
for each torch thread count (the Trainer figure leaves out its start-up). Uses (and generates if
missing) the local expert dataset.
"""

from __future__ import annotations

import argparse
import logging
import time
import warnings

import torch
from timing import trainer_steps_per_s

from hispo_pl.data.datasets import load_episodes
from hispo_pl.data.generation import generate_missing
from hispo_pl.data.sampler import HERConfig, HERSampler
from hispo_pl.modules import BC, HBC
from hispo_pl.tasks import parse_task

WARMUP = 10  # untimed steps before a timing starts


def rate(fn, n: int, warmup: int = WARMUP) -> float:
    for _ in range(warmup):
        fn()
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return n / (time.perf_counter() - t)


def bare_steps_per_s(model, sampler: HERSampler, n: int) -> float:
    opt = torch.optim.Adam(model.parameters(), lr=3e-4)

    def step():
        loss = model.losses(sampler.sample())["loss"]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    return rate(step, n)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="pointmaze-umaze")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--batch-size", type=int, default=1024)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)

    task = parse_task(args.task)
    generate_missing(task)  # as a fit does: collect the maze's data on first use
    data = load_episodes(task)
    cfg = HERConfig(task.defaults.waysteps, task.defaults.her_temperature)
    sampler = HERSampler(data, cfg, args.batch_size, seed=0)
    fam = task.env_family
    print(f"task {task}: {len(data.sample_index)} samples, batch {args.batch_size}")
    for threads in args.threads:
        torch.set_num_threads(threads)
        torch.manual_seed(0)
        print(f"threads={threads} sampler batches/s {rate(sampler.sample, 20 * args.steps):8.1f}")
        for name, cls in (("HBC", HBC), ("BC", BC)):
            bare = bare_steps_per_s(cls(fam.obs_dim, fam.action_dim), sampler, args.steps)
            model = cls(fam.obs_dim, fam.action_dim)
            lit = trainer_steps_per_s(model, str(task), args.steps - WARMUP, WARMUP)
            print(f"threads={threads} {name:3s} grad steps/s  bare {bare:6.1f}  trainer {lit:6.1f}")


if __name__ == "__main__":
    main()
