"""What the dearest methods' training steps cost, against their arithmetic.

    python benchmarks/method_cost.py [--task pointmaze-umaze] [--columns 4] [--steps 30]
        [--rounds 3] [--batch-size 1024] [--threads 1]

A PNN step on task ``k`` runs the ``k`` frozen columns before it (no gradients) and the newest
column with its laterals from all of them (gradients), so its work grows about quadratically
with the task. A CSP step is CSPO's plus its critic's (IQL: V and twin Q trained, the target
Q and V at the next state without gradients). For HBC (one network pair, what SCN trains per
task), PNN with 1 to ``--columns`` columns, CSPO and CSP (one anchor each), this prints, in
one run:

- the step's floating-point operations, counted by torch (``FlopCounterMode``) over the
  product's own forward and backward (``module.losses``), and their ratio to HBC's;
- gradient steps/s of the product's step (sampler, losses, backward, Adam as the module
  builds it), median over ``--rounds`` alternating blocks, and the time ratio to HBC's.

A time ratio that follows the operations' ratio says the step spends its time on the maths
the method asks for, not on overhead a faster implementation could remove.
"""

from __future__ import annotations

import argparse
import statistics
import time


def build(method: str, obs_dim: int, action_dim: int):
    """HBC, CSPO, CSP, or PNN grown to ``PNN-k``'s ``k`` columns (the newest trainable)."""
    from hispo_pl.modules import CSP, CSPO, HBC, PNN

    if method in ("HBC", "CSPO", "CSP"):
        return {"HBC": HBC, "CSPO": CSPO, "CSP": CSP}[method](obs_dim, action_dim)
    module = PNN(obs_dim, action_dim)
    for task in range(int(method.split("-")[1])):
        if task:
            module.finish_task(task - 1)
        module.start_task(task)
    return module


def step_flops(model, batch) -> int:
    """Floating-point operations of one forward and backward of ``model``'s losses."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        model.losses(batch)["loss"].backward()
    model.zero_grad(set_to_none=True)
    return counter.get_total_flops()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="pointmaze-umaze")
    parser.add_argument("--columns", type=int, default=4, help="PNN columns, 1 to this")
    parser.add_argument("--steps", type=int, default=30, help="timed steps per block")
    parser.add_argument("--rounds", type=int, default=3, help="alternating blocks per figure")
    parser.add_argument("--batch-size", type=int, default=1024)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()

    import torch

    from hispo_pl.data.datasets import load_episodes
    from hispo_pl.data.generation import generate_missing
    from hispo_pl.data.sampler import HERConfig, HERSampler
    from hispo_pl.tasks import parse_task

    torch.set_num_threads(args.threads)
    task = parse_task(args.task)
    generate_missing(task)  # as a fit does: collect the maze's data on first use
    her = HERConfig(task.defaults.waysteps, task.defaults.her_temperature)
    # transitions for CSP's critic; the other keys are the same batches without them
    sampler = HERSampler(load_episodes(task), her, args.batch_size, seed=0, transitions=True)
    fam = task.env_family

    methods = ["HBC", *(f"PNN-{k}" for k in range(1, args.columns + 1)), "CSPO", "CSP"]
    models, flops = {}, {}
    for method in methods:
        torch.manual_seed(0)
        model = build(method, fam.obs_dim, fam.action_dim).train()
        flops[method] = step_flops(model, sampler.sample())
        built = model.configure_optimizers()
        models[method] = model, built["optimizer"] if isinstance(built, dict) else built

    def rate(method: str) -> float:
        model, opt = models[method]

        def step():
            batch = sampler.sample()
            loss = model.losses(batch)["loss"]
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            model.on_train_batch_end(None, batch, 0)  # CSP's target networks follow

        for _ in range(3):
            step()
        start = time.perf_counter()
        for _ in range(args.steps):
            step()
        return args.steps / (time.perf_counter() - start)

    rates: dict[str, list[float]] = {m: [] for m in methods}
    for r in range(args.rounds):
        for method in methods if r % 2 == 0 else methods[::-1]:
            rates[method].append(rate(method))
    med = {m: statistics.median(v) for m, v in rates.items()}

    print(
        f"task {args.task}, batch {args.batch_size}, {args.threads} thread(s), "
        f"{args.steps} steps x {args.rounds} rounds; ratios against HBC"
    )
    print(f"{'method':8} {'GFLOP/step':>10} {'x ops':>6} {'steps/s':>8} {'x time':>7}")
    for method in methods:
        print(
            f"{method:8} {flops[method] / 1e9:10.3f} {flops[method] / flops['HBC']:6.2f} "
            f"{med[method]:8.1f} {med['HBC'] / med[method]:7.2f}"
        )


if __name__ == "__main__":
    main()
