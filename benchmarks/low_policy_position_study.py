"""Why a maze change keeps its low anchor: how much of an old low policy's error on a new
maze comes from absolute positions it never saw.

The low policy sees [features(subgoal − pos), obs] and PointMaze's obs holds the absolute
position (x, y). A low policy trained on one maze is scored (deterministic mean, squared
error against the data's action, as the pruning search scores it) on HER batches of another
task, split by whether each sample's position lies inside the bounding box of the positions
of the maze the policy was trained on.

    python benchmarks/low_policy_position_study.py \
        --ckpt runs/pointmaze-1-refine/seed1/task_04.ckpt --as-task 1 \
        --trained-on "pointmaze-umaze-N[500]" --task "pointmaze-large-N[500]" --own-task 2

``--as-task`` is the (1-based) stream task whose low weights are scored, ``--own-task`` the
stream task trained on ``--task`` (its own low weights, the reference).
"""

from __future__ import annotations

import argparse

import torch

from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.data.datasets import load_episodes
from hispo_pl.data.tasks import parse_task
from hispo_pl.modules import GoalConditionedBC
from hispo_pl.modules.hispo import HiSPO


@torch.no_grad()
def per_sample_low_error(module: HiSPO, batch: dict, task: int) -> torch.Tensor:
    """Squared error of the low policy of stream task ``task`` (0-based) on each sample."""
    x, target = module._io("low", batch)
    alpha = module.alpha_for(module.subspace_of("low"), task)
    module.policies["low"].eval()
    mean, _ = module.policies["low"](x, alpha)
    return (mean - target).pow(2).sum(-1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--ckpt", required=True, help="a HiSPO stream checkpoint (task_XX.ckpt)")
    parser.add_argument("--as-task", type=int, required=True, help="stream task scored (1-based)")
    parser.add_argument("--own-task", type=int, required=True, help="stream task of --task")
    parser.add_argument("--trained-on", required=True, help="task spec of --as-task's data")
    parser.add_argument("--task", required=True, help="task spec whose data is scored")
    parser.add_argument("--batches", type=int, default=16)
    parser.add_argument(
        "--waysteps",
        type=int,
        default=None,
        help="relabel --task's subgoals this far ahead "
        "(default: its maze's own value; the maze of --trained-on may use another)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)

    module = GoalConditionedBC.from_checkpoint_file(args.ckpt)
    if not isinstance(module, HiSPO):
        raise SystemExit(f"{args.ckpt} holds a {type(module).__name__}, not a HiSPO module")
    seen = load_episodes(parse_task(args.trained_on)).for_task(parse_task(args.trained_on))
    lo = torch.as_tensor(seen.positions.min(0)).float()
    hi = torch.as_tensor(seen.positions.max(0)).float()

    dm = TaskDataModule(task=args.task, batch_size=1024, waysteps=args.waysteps)
    dm.setup()
    batches = dm.fixed_batches(args.batches, seed=0)
    old, own, inside = [], [], []
    for batch in batches:
        old.append(per_sample_low_error(module, batch, args.as_task - 1))
        own.append(per_sample_low_error(module, batch, args.own_task - 1))
        pos = batch["position"]
        inside.append(((pos >= lo) & (pos <= hi)).all(-1))
    old, own, inside = torch.cat(old), torch.cat(own), torch.cat(inside)
    print(
        f"positions of {args.trained_on}: "
        f"x in [{lo[0]:.2f}, {hi[0]:.2f}], y in [{lo[1]:.2f}, {hi[1]:.2f}]"
    )
    print(
        f"{args.task}, {len(old)} HER samples, subgoals {dm.her.waysteps} steps ahead; "
        "low-policy squared error (mean):"
    )
    print(
        f"| samples | share | task {args.as_task}'s low (trained on {args.trained_on}) "
        f"| task {args.own_task}'s own low | ratio |"
    )
    print("|---|---|---|---|---|")
    for name, mask in (("all", torch.ones_like(inside)), ("inside", inside), ("outside", ~inside)):
        if mask.any():
            a, b = old[mask].mean().item(), own[mask].mean().item()
            print(
                f"| {name} | {mask.float().mean().item():.0%} | {a:.3f} | {b:.3f} | {a / b:.1f}× |"
            )


if __name__ == "__main__":
    main()
