"""Why a maze change keeps its low anchor: how well a low policy trained on one PointMaze
maze imitates the expert on another, by what it sees and by its subgoal horizon.

For each (input, waysteps) setting a low policy (the HBC low network: features of the true
subgoal offset [+ observation] → action) is trained from scratch on the first task and one
on the second, for the same steps; both are then scored as the pruning search scores a low
anchor (deterministic mean, squared error summed over the action, 16 fixed batches of 1,024)
on the second task's data, and the ratio old / own is what SubspacePruning compares with
1 + ε. Inputs: ``position`` = gymnasium's full vector (x, y, vx, vy), what our policies see;
``velocity`` = (vx, vy) only, a low policy that cannot tell where in the maze it is.

``--control`` adds, per input, the same comparison on one task: the first task's policy
against a copy trained ``--steps`` more on the same task, both scored on that task. A ratio
above 1 + ε there means the budget, not the task change, decides: an anchor that is still
improving loses to any further-trained one.

    python benchmarks/low_transfer_study.py --steps 3000 \
        --first "pointmaze-umaze-N[500]" --second "pointmaze-large-N[500]"
"""

from __future__ import annotations

import argparse
import copy
import time

import torch

from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.data.datasets import load_episodes
from hispo_pl.data.sampler import HERSampler
from hispo_pl.data.tasks import parse_task
from hispo_pl.nn import eval_mode
from hispo_pl.nn.mlp import GaussianPolicy, goal_features

INPUTS = ("position", "velocity")


def low_input(batch: dict[str, torch.Tensor], seen: str) -> torch.Tensor:
    """The low policy's input from a batch of the env's full observation vector."""
    obs = batch["observation"] if seen == "position" else batch["observation"][:, 2:]
    return torch.cat([goal_features(batch["subgoal"] - batch["position"]), obs], -1)


def sampler(task: str, waysteps: int | None, seed: int = 0) -> HERSampler:
    """HER batches over the dataset's own (x, y, vx, vy) observations (variant N only)."""
    t = parse_task(task)
    if t.variant != "N":
        raise SystemExit(f"{task}: the study needs the normal variant")
    cfg = TaskDataModule(task=task, waysteps=waysteps).her_config(t)  # training's relabelling
    return HERSampler(load_episodes(t), cfg, batch_size=1024, seed=seed)


def scoring_batches(task: str, waysteps: int | None) -> list[dict]:
    """The 16 fixed batches a low policy is scored on (their own seed, apart from training's)."""
    data = sampler(task, waysteps, seed=100)
    return [data.sample() for _ in range(16)]


def train_low(
    task: str, seen: str, waysteps: int | None, steps: int, start: GaussianPolicy | None = None
) -> GaussianPolicy:
    """A low policy trained like HBC's (Adam 1e-3, cosine over ``steps``), from scratch or
    from a copy of ``start``."""
    torch.manual_seed(0)
    data = sampler(task, waysteps)
    if start is None:
        policy = GaussianPolicy(low_input(data.sample(8), seen).shape[-1], 256, 2)
    else:
        policy = copy.deepcopy(start)
    opt = torch.optim.Adam(policy.parameters(), lr=1e-3)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    for _ in range(steps):
        batch = data.sample()
        mean, log_std = policy(low_input(batch, seen))
        loss = policy.loss(mean, log_std, batch["action"])
        opt.zero_grad()
        loss.backward()
        opt.step()
        schedule.step()
    return policy


@torch.no_grad()
def score(policy: GaussianPolicy, batches: list[dict], seen: str) -> float:
    """Mean squared error of the deterministic action over ``batches``."""
    with eval_mode(policy):
        errors = [
            (policy(low_input(b, seen))[0] - b["action"]).pow(2).sum(-1).mean() for b in batches
        ]
    return float(torch.stack(errors).mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--first", default="pointmaze-umaze-N[500]")
    parser.add_argument("--second", default="pointmaze-large-N[500]")
    parser.add_argument("--steps", type=int, default=3000, help="gradient steps per policy")
    parser.add_argument(
        "--waysteps",
        type=int,
        nargs="+",
        default=[0, 25],
        help="subgoal horizons to compare; 0 = each maze's own (the paper's)",
    )
    parser.add_argument("--inputs", nargs="+", choices=INPUTS, default=list(INPUTS))
    parser.add_argument(
        "--control", action="store_true", help="also: first task's policy vs itself trained more"
    )
    parser.add_argument("--num_threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.num_threads)

    print("| low input | waysteps | old on second | own on second | old / own | seconds |")
    print("|---|---|---:|---:|---:|---:|")
    for seen in args.inputs:
        for waysteps in args.waysteps:
            start = time.perf_counter()
            horizon = waysteps or None
            old = train_low(args.first, seen, horizon, args.steps)
            own = train_low(args.second, seen, horizon, args.steps)
            batches = scoring_batches(args.second, horizon)
            l_old, l_own = score(old, batches, seen), score(own, batches, seen)
            print(
                f"| {seen} | {waysteps or 'per maze'} | {l_old:.3f} | {l_own:.3f} | "
                f"{l_old / l_own:.2f} | {time.perf_counter() - start:.0f} |",
                flush=True,
            )
            if args.control:
                start = time.perf_counter()
                more = train_low(args.first, seen, horizon, args.steps, start=old)
                batches = scoring_batches(args.first, horizon)
                l_old, l_more = score(old, batches, seen), score(more, batches, seen)
                print(
                    f"| {seen} (control: first task, trained more) | {waysteps or 'per maze'} | "
                    f"{l_old:.3f} | {l_more:.3f} | {l_old / l_more:.2f} | "
                    f"{time.perf_counter() - start:.0f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
