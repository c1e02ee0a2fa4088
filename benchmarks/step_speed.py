"""Training-step speed against the machine's matmul floor: reference path vs fast path.

    python benchmarks/step_speed.py [--task pointmaze-umaze] [--threads 1 2] [--steps 40]
        [--rounds 3] [--batch-size 1024] [--episodes 20] [--antmaze]

Prints, in one run:

1. The matmul floor per thread count: the GEMMs of one training step (forward, weight and
   input gradients, for exactly the step's shapes) timed one by one with torch, summed, and
   given as steps/s (the speed of a step that did nothing but its matmuls); and a ceiling:
   the same matmuls plus the elementwise kernels the fast path calls for the step's maths
   (aten's LayerNorm → GELU → dropout forward and backward; the dropout masks' random
   bytes), each timed alone at its shapes.
2. Gradient steps/s of HBC, BC and HiSPO with 1 and 4 anchors (both subspaces grown), on
   the reference path (``hispo_pl.nn.fast.reference_path``: plain autograd modules, masks
   drawn byte by byte, the default Adam, a log call every step, glibc's default allocator
   settings) and on the fast path, as a bare loop (sampler + step) and through a Lightning
   Trainer (TaskDataModule, a TensorBoard logger, no progress bar; start-up not counted).
   Each path runs in its own worker process (the allocator setting is process-wide); the
   parent alternates between them in short blocks over ``--rounds`` rounds and prints the
   median, so that load from other jobs hits both alike.
3. The aggregate steps/s of two 1-thread fast workers running HBC side by side, against one
   2-thread worker (alternating rounds).
4. Rollout evaluation cost: episodes/s and env steps/s of an untrained HBC (episodes run to
   their step limit, the worst case) on the task, and on antmaze-umaze with ``--antmaze``.
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing as mp
import statistics
import tempfile
import time
import warnings
from contextlib import nullcontext

METHODS = ("HBC", "BC", "HiSPO-1", "HiSPO-4")
PATHS = ("reference", "fast")


def build(method: str, obs_dim: int, action_dim: int):
    from hispo_pl.modules import BC, HBC, HiSPO

    if method == "HBC":
        return HBC(obs_dim, action_dim)
    if method == "BC":
        return BC(obs_dim, action_dim)
    module = HiSPO(obs_dim, action_dim)
    for _ in range(int(method.split("-")[1]) - 1):
        for name in module.subspace_names:
            module.add_anchor(name)
    return module


def step_networks(method: str, dims: dict[str, int]) -> list[tuple[int, int, int]]:
    """(inputs, hidden, outputs) of each network a training step runs, read off the module's
    own layers (HiSPO's are HBC's: mixing the anchors is a few small products, left out)."""
    from hispo_pl.nn.mlp import ResidualMLP

    module = build("HBC" if method.startswith("HiSPO") else method, dims["obs"], dims["action"])
    nets = [m for m in module.modules() if isinstance(m, ResidualMLP)]
    return [(n.inp[0].in_features, n.inp[0].out_features, n.head.out_features) for n in nets]


def step_gemms(method: str, dims: dict[str, int], batch: int) -> list[tuple[str, tuple]]:
    """The matmuls of one training step: (kind, shapes) with kind ``fwd`` (addmm of
    [B, in] by [in, out]), ``dw`` ([out, B] by [B, in]) or ``dx`` ([B, out] by [out, in])."""
    out = []
    for n_in, h, n_out in step_networks(method, dims):
        layers = [(n_in, h), (h, h), (h, h), (h, n_out)]
        for i, (a, b) in enumerate(layers):
            out.append(("fwd", (batch, a, b)))
            out.append(("dw", (batch, a, b)))
            if i > 0:  # the network's input needs no gradient
                out.append(("dx", (batch, a, b)))
    return out


def median_seconds(fn, reps: int = 30) -> float:
    """Median seconds of one call of ``fn`` over ``reps`` calls, after three warm-up calls."""
    for _ in range(3):
        fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def time_gemms(gemms, reps: int = 30) -> float:
    """Seconds of one pass over ``gemms`` (each timed alone, median of ``reps``)."""
    import torch

    total = 0.0
    for kind, (batch, n_in, n_out) in gemms:
        x, w = torch.randn(batch, n_in), torch.randn(n_out, n_in)
        bias, grad = torch.randn(n_out), torch.randn(batch, n_out)
        if kind == "fwd":
            fn, operands = torch.addmm, (bias, x, w.t())
        elif kind == "dw" and n_in < n_out:  # the faster orientation, as the fast path takes it
            fn, operands = torch.mm, (x.t(), grad)
        elif kind == "dw":
            fn, operands = torch.mm, (grad.t(), x)
        else:
            fn, operands = torch.mm, (grad, w)
        total += median_seconds(lambda fn=fn, operands=operands: fn(*operands), reps)
    return total


def _network_kernels(h: int, batch: int) -> list:
    """One network's elementwise kernels, as calls: each layer's LayerNorm → GELU → dropout
    forward and backward once (the network has three; aten's kernels, as the fast path calls
    them), and its masks' random bytes."""
    import torch

    aten = torch.ops.aten
    z, grad = torch.randn(batch, h), torch.randn(batch, h)
    gamma, beta = torch.ones(h), torch.zeros(h)
    words = torch.empty(3 * batch * h // 8, dtype=torch.int64)  # as fast.dropout_bytes draws
    _, mu, rstd = aten.native_layer_norm(z, (h,), gamma, beta, 1e-5)
    return [
        lambda: aten.gelu(z),
        lambda: aten.gelu_backward(grad, z),
        lambda: aten.native_layer_norm(z, (h,), gamma, beta, 1e-5),
        lambda: aten.native_layer_norm_backward(
            grad, z, (h,), mu, rstd, gamma, beta, [True, True, True]
        ),
        lambda: words.random_(-(2**63), None),
    ]


def time_kernels(method: str, dims: dict[str, int], batch: int, reps: int = 30) -> float:
    """Seconds of the elementwise kernels the step's maths needs, each timed alone (median of
    ``reps``) at the step's shapes: per network, three layers' LayerNorm → GELU → dropout
    forward and backward, and one draw of random bytes for its three dropout masks. A step that
    calls these kernels spends at least this beside its matmuls."""
    total = 0.0
    for _, h, _ in step_networks(method, dims):
        *per_layer, masks = (median_seconds(fn, reps) for fn in _network_kernels(h, batch))
        total += 3 * sum(per_layer) + masks
    return total


def _worker(path: str, args: argparse.Namespace, conn) -> None:
    """Serves commands for one path until it receives ``None``."""
    import torch
    from lightning.pytorch.loggers import TensorBoardLogger
    from timing import trainer_steps_per_s

    from hispo_pl.data.datasets import load_episodes
    from hispo_pl.data.generation import generate_missing
    from hispo_pl.data.sampler import HERConfig, HERSampler
    from hispo_pl.nn import fast
    from hispo_pl.tasks import parse_task

    warnings.filterwarnings("ignore")
    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    with fast.reference_path() if path == "reference" else nullcontext():
        if path != "reference":
            fast.retain_freed_memory()
        task = parse_task(args.task)
        fam = task.env_family
        generate_missing(task)  # as a fit does: collect the maze's data on first use
        data = load_episodes(task)
        her = HERConfig(task.defaults.waysteps, task.defaults.her_temperature)
        sampler = HERSampler(data, her, args.batch_size, seed=0)
        logdir = tempfile.mkdtemp(prefix="step_speed_")
        bare_models: dict[str, tuple] = {}

        def bare(method: str, steps: int) -> float:
            if method not in bare_models:
                torch.manual_seed(0)
                model = build(method, fam.obs_dim, fam.action_dim)
                params = [p for p in model.parameters() if p.requires_grad]
                opt = torch.optim.Adam(params, lr=3e-4, fused=fast.enabled())
                bare_models[method] = model, opt
            model, opt = bare_models[method]

            def step():
                loss = model.losses(sampler.sample())["loss"]
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()

            for _ in range(3):
                step()
            t = time.perf_counter()
            for _ in range(steps):
                step()
            return steps / (time.perf_counter() - t)

        def trainer(method: str, steps: int) -> float:
            torch.manual_seed(0)
            model = build(method, fam.obs_dim, fam.action_dim)
            return trainer_steps_per_s(model, args.task, steps, 3, TensorBoardLogger(logdir))

        def rollout(task_name: str, episodes: int) -> tuple[float, float]:
            from hispo_pl.evaluation import RolloutEvaluator, module_policy

            t_task = parse_task(task_name)
            evaluator = RolloutEvaluator(t_task, episodes=episodes, seed=0)
            model = build("HBC", t_task.env_family.obs_dim, t_task.env_family.action_dim)
            t = time.perf_counter()
            result = evaluator.run(module_policy(model))
            dt = time.perf_counter() - t
            evaluator.close()
            return episodes / dt, result.episode_length * episodes / dt

        dims = {"obs": fam.obs_dim, "action": fam.action_dim, "goal": 2}
        while (cmd := conn.recv()) is not None:
            kind, threads, *rest = cmd
            torch.set_num_threads(threads)
            if kind == "bare":
                conn.send(bare(*rest))
            elif kind == "trainer":
                conn.send(trainer(*rest))
            elif kind == "floor":
                conn.send(1.0 / time_gemms(step_gemms(rest[0], dims, args.batch_size)))
            elif kind == "kernels":  # seconds, added to the floor's for the ceiling
                conn.send(time_kernels(rest[0], dims, args.batch_size))
            elif kind == "rollout":
                try:
                    conn.send(rollout(*rest))
                except Exception as err:  # an env that does not build here
                    conn.send(f"not measured ({type(err).__name__}: {err})")


class Worker:
    def __init__(self, path: str, args: argparse.Namespace):
        ctx = mp.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_worker, args=(path, args, child), daemon=True)
        self.proc.start()

    def send(self, *cmd) -> None:
        self.conn.send(cmd)

    def recv(self):
        return self.conn.recv()

    def call(self, *cmd):
        self.send(*cmd)
        return self.recv()

    def close(self) -> None:
        self.conn.send(None)
        self.proc.join()


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="pointmaze-umaze")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--steps", type=int, default=40, help="timed steps per block")
    parser.add_argument("--rounds", type=int, default=3, help="alternating blocks per figure")
    parser.add_argument("--batch-size", type=int, default=1024)
    parser.add_argument("--episodes", type=int, default=20, help="rollout episodes")
    parser.add_argument("--antmaze", action="store_true", help="also time antmaze rollouts")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    args = parser.parse_args()

    started = time.perf_counter()
    workers = {path: Worker(path, args) for path in PATHS}
    rates: dict[tuple, list[float]] = {}
    floors: dict[tuple, list[float]] = {}
    for threads in args.threads:
        for r in range(args.rounds):
            for method in args.methods:
                for bound in ("floor", "kernels") if method in ("HBC", "BC") else ():
                    floors.setdefault((threads, method, bound), []).append(
                        workers["fast"].call(bound, threads, method)
                    )
                for kind in ("bare", "trainer"):
                    order = PATHS if r % 2 == 0 else PATHS[::-1]
                    for path in order:
                        rate = workers[path].call(kind, threads, method, args.steps)
                        rates.setdefault((threads, method, kind, path), []).append(rate)
    med = {k: statistics.median(v) for k, v in rates.items()}
    floor = {k: statistics.median(v) for k, v in floors.items()}

    print(f"task {args.task}, batch {args.batch_size}, {args.steps} steps x {args.rounds} rounds")
    print(
        "steps/s (median); floor = the step's matmuls alone; ceiling = the matmuls plus the "
        "fast path's LayerNorm/GELU/dropout and mask-draw kernels, each timed alone; "
        "x = fast / reference"
    )
    head = (
        f"{'thr':>3} {'method':8} {'floor':>6} {'ceiling':>7} | "
        f"{'ref bare':>8} {'fast bare':>9} {'x':>5} | "
        f"{'ref Trainer':>11} {'fast Trainer':>12} {'x':>5} | {'fast/floor':>10} "
        f"{'Trainer/bare':>12} {'vs HBC':>6}"
    )
    print(head)
    for threads in args.threads:
        for method in args.methods:
            net = "BC" if method == "BC" else "HBC"
            fl = floor.get((threads, net, "floor"), float("nan"))
            ceiling = 1.0 / (1.0 / fl + floor.get((threads, net, "kernels"), float("nan")))
            rb, fb = med[threads, method, "bare", "reference"], med[threads, method, "bare", "fast"]
            rt = med[threads, method, "trainer", "reference"]
            ft = med[threads, method, "trainer", "fast"]
            hbc = med.get((threads, "HBC", "bare", "fast"), float("nan"))
            print(
                f"{threads:>3} {method:8} {fl:6.1f} {ceiling:7.1f} | "
                f"{rb:8.1f} {fb:9.1f} {fb / rb:5.2f} | "
                f"{rt:11.1f} {ft:12.1f} {ft / rt:5.2f} | {fb / fl:10.0%} {ft / fb:12.2f} "
                f"{fb / hbc:6.2f}"
            )

    if 1 in args.threads and 2 in args.threads:
        second = Worker("fast", args)
        pair, single = [], []
        for _ in range(args.rounds):
            for w in (workers["fast"], second):
                w.send("bare", 1, "HBC", 2 * args.steps)
            pair.append(sum(w.recv() for w in (workers["fast"], second)))
            single.append(workers["fast"].call("bare", 2, "HBC", 2 * args.steps))
        second.close()
        p, s = statistics.median(pair), statistics.median(single)
        print(
            f"HBC fast, bare: two 1-thread processes side by side {p:.1f} steps/s in all, "
            f"one 2-thread process {s:.1f} steps/s (ratio {p / s:.2f})"
        )

    tasks = [args.task] + (["antmaze-umaze"] if args.antmaze else [])
    for name in tasks:
        out = workers["fast"].call("rollout", 1, name, args.episodes)
        if isinstance(out, str):
            print(f"rollouts {name}: {out}")
        else:
            print(
                f"rollouts {name} (untrained HBC, {args.episodes} episodes, 1 thread): "
                f"{out[0]:.2f} episodes/s, {out[1]:.0f} env steps/s"
            )
    for w in workers.values():
        w.close()
    print(f"benchmark wall time {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
