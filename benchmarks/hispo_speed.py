"""HiSPO speed on this machine: the Dirichlet search, and training steps against HBC.

    python benchmarks/hispo_speed.py [--threads 1] [--candidates 1024] [--batches 16]
        [--batch-size 1024] [--anchors 4] [--one-at-a-time-sample 64] [--steps 100]

1. Scores ``--candidates`` weight vectors over ``--anchors`` anchors (low subspace, the
   expensive one) on ``--batches`` batches: vectorised (``HiSPO.score_alphas``, chunks of
   candidates in one batched forward) against one candidate at a time (an unbatched forward per
   candidate and batch). The one-at-a-time time is measured on ``--one-at-a-time-sample``
   candidates and scaled up.
2. Gradient steps per second of HiSPO (with ``--anchors`` anchors) and of HBC, same batches.
Synthetic batches: speed does not depend on the data.
"""

from __future__ import annotations

import argparse
import time

import torch

from hispo_pl.decisions import previous_subspace_candidates
from hispo_pl.modules import HBC, HiSPO


def batch(n: int, obs_dim: int = 4, action_dim: int = 2) -> dict[str, torch.Tensor]:
    return {
        "observation": torch.randn(n, obs_dim),
        "position": torch.randn(n, 2),
        "goal": torch.randn(n, 2),
        "subgoal": torch.randn(n, 2),
        "action": torch.rand(n, action_dim) * 2 - 1,
    }


def steps_per_s(model, batches, n: int) -> float:
    opt = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=3e-4)
    model.train()
    for i in range(n + 5):
        if i == 5:
            t = time.perf_counter()
        loss = model.losses(batches[i % len(batches)])["loss"]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return n / (time.perf_counter() - t)


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--candidates", type=int, default=1024)
    p.add_argument("--batches", type=int, default=16)
    p.add_argument("--batch-size", type=int, default=1024)
    p.add_argument("--anchors", type=int, default=4)
    p.add_argument("--one-at-a-time-sample", type=int, default=64)
    p.add_argument("--steps", type=int, default=100)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)

    model = HiSPO(4, 2)
    for _ in range(args.anchors - 1):
        for name in model.subspace_names:
            model.add_anchor(name)
    model.eval()
    batches = [batch(args.batch_size) for _ in range(args.batches)]
    cands = previous_subspace_candidates(
        args.candidates, args.anchors, torch.Generator().manual_seed(0)
    )
    print(
        f"threads={args.threads} anchors={args.anchors} candidates={args.candidates} "
        f"batches={args.batches}x{args.batch_size}"
    )

    t = time.perf_counter()
    vec = torch.stack([model.score_alphas("low", cands, b) for b in batches]).mean(0)
    t_vec = time.perf_counter() - t

    sample = cands[: args.one_at_a_time_sample]
    t = time.perf_counter()
    with torch.no_grad():
        single = torch.stack(
            [
                torch.stack([model.score_alphas("low", a[None], b)[0] for b in batches]).mean()
                for a in sample
            ]
        )
    t_one = (time.perf_counter() - t) * args.candidates / len(sample)
    assert torch.allclose(single, vec[: len(sample)], rtol=1e-4, atol=1e-6)
    print(
        f"search (low subspace): vectorised {t_vec:.1f} s, one at a time {t_one:.1f} s "
        f"(estimated from {len(sample)}), speed-up x{t_one / t_vec:.1f}"
    )

    train_batches = [batch(args.batch_size) for _ in range(8)]
    hispo = HiSPO(4, 2)
    for _ in range(args.anchors - 1):
        for name in hispo.subspace_names:
            hispo.add_anchor(name)
    hbc = HBC(4, 2)
    r_hispo, r_hbc = (
        steps_per_s(hispo, train_batches, args.steps),
        steps_per_s(hbc, train_batches, args.steps),
    )
    print(
        f"training: HiSPO {r_hispo:.1f} steps/s, HBC {r_hbc:.1f} steps/s, "
        f"ratio {r_hispo / r_hbc:.2f}"
    )


if __name__ == "__main__":
    main()
