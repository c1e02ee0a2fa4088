"""HiSPO speed on this machine: the Dirichlet search, and training steps against HBC.

    python benchmarks/hispo_speed.py [--threads 1] [--candidates 1024] [--batches 16]
        [--batch-size 1024] [--anchors 4] [--one-at-a-time-sample 64] [--steps 100]
        [--survivors 32] [--probe-samples 256] [--precision bf16|32]

1. Searches ``--candidates`` weight vectors over ``--anchors`` anchors (low subspace, the
   expensive one) on ``--batches`` batches, three ways: one candidate at a time (an unbatched
   float32 forward per candidate and batch; timed on ``--one-at-a-time-sample`` candidates
   and scaled up), vectorised and exhaustive (``HiSPO.score_alphas``, chunks of candidates in
   one batched forward, float32), and the callback's default: vectorised and raced
   (``hispo_pl.search.race_candidates``: all candidates ranked on ``--probe-samples``, the
   ``--survivors`` best scored on every batch, in ``--precision``). It prints each time, the
   speed-ups over one at a time, and whether the race found the exhaustive winner.
2. Gradient steps per second of HiSPO (with ``--anchors`` anchors) and of HBC, same batches.
Synthetic batches: speed does not depend on the data.
"""

from __future__ import annotations

import argparse
import inspect
import time

import torch

from hispo_pl.decisions import previous_subspace_candidates
from hispo_pl.modules import HBC, HiSPO
from hispo_pl.search import race_candidates

DEFAULT_GROUPS = inspect.signature(HiSPO).parameters["alpha_groups"].default


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


def search_speed(args) -> None:
    torch.manual_seed(0)
    model = HiSPO(4, 2, anchor_init="random")  # distinct anchors: a real landscape
    for _ in range(args.anchors - 1):
        for name in model.subspace_names:
            model.add_anchor(name)
    model.eval()
    batches = [batch(args.batch_size) for _ in range(args.batches)]
    cands = previous_subspace_candidates(
        args.candidates, args.anchors, torch.Generator().manual_seed(0)
    )
    print(f"search: {args.candidates} candidates, {args.batches} batches")

    def scorer(precision: str):
        return lambda alphas, b: model.score_alphas("low", alphas, b, precision=precision)

    probe = {k: v[: args.probe_samples] for k, v in batches[0].items()}

    def timed(fn):
        t = time.perf_counter()
        out = fn()
        return out, time.perf_counter() - t

    full, t_vec = timed(lambda: race_candidates(scorer("32"), cands, batches))
    sample = cands[: args.one_at_a_time_sample]
    with torch.no_grad():
        single, t_one = timed(
            lambda: torch.stack(
                [
                    torch.stack([model.score_alphas("low", a[None], b)[0] for b in batches]).mean()
                    for a in sample
                ]
            )
        )
    t_one *= args.candidates / len(sample)
    exhaustive = full.losses  # no probe: every candidate, in candidate order
    assert torch.allclose(single, exhaustive[: len(sample)], rtol=1e-4, atol=1e-6)
    raced, t_race = timed(
        lambda: race_candidates(scorer(args.precision), cands, batches, probe, args.survivors)
    )
    print(
        f"search (low subspace), one candidate at a time (fp32): {t_one:.1f} s "
        f"(estimated from {len(sample)})"
    )
    print(f"  vectorised, exhaustive (fp32): {t_vec:.1f} s, speed-up x{t_one / t_vec:.1f}")
    print(
        f"  vectorised, raced (probe {args.probe_samples} samples, {args.survivors} survivors, "
        f"{args.precision}): {t_race:.1f} s, "
        f"speed-up x{t_one / t_race:.1f}"
    )
    print(
        f"  best candidate: exhaustive #{full.best} loss {full.best_loss:.5f}, "
        f"raced #{raced.best} loss {raced.best_loss:.5f} "
        f"(raced winner's exhaustive loss {exhaustive[raced.best]:.5f})"
    )


def training_speed(args) -> None:
    torch.manual_seed(0)
    train_batches = [batch(args.batch_size) for _ in range(8)]
    hispo = HiSPO(4, 2, alpha_groups=args.alpha_groups)
    for _ in range(args.anchors - 1):
        for name in hispo.subspace_names:
            hispo.add_anchor(name)
    hbc = HBC(4, 2)
    r_hispo, r_hbc = (
        steps_per_s(hispo, train_batches, args.steps),
        steps_per_s(hbc, train_batches, args.steps),
    )
    print(
        f"training ({args.alpha_groups} alpha groups): HiSPO {r_hispo:.1f} steps/s, "
        f"HBC {r_hbc:.1f} steps/s, "
        f"ratio {r_hispo / r_hbc:.2f}"
    )


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
    p.add_argument("--alpha-groups", type=int, default=DEFAULT_GROUPS)
    p.add_argument("--survivors", type=int, default=32)
    p.add_argument("--probe-samples", type=int, default=256)
    p.add_argument("--precision", choices=["32", "bf16"], default="bf16")
    p.add_argument("--only", choices=["search", "training"], help="run one of the two parts")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    print(f"threads={args.threads} anchors={args.anchors} batch size={args.batch_size}")
    if args.only != "training":
        search_speed(args)
    if args.only != "search":
        training_speed(args)


if __name__ == "__main__":
    main()
