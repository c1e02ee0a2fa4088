"""Training speed on a GPU: the reference, fast and captured steps side by side, bare and
through the Trainer, several runs sharing the device, and one stream end to end.

    python benchmarks/gpu_speed.py [--task pointmaze-umaze] [--batch-sizes 1024 8192]
        [--methods HBC HiSPO-1 HiSPO-4] [--steps 200] [--warmup 20] [--rounds 2] [--group 8]
        [--workers 1 2 4 8] [--stream pointmaze-1] [--stream-steps 6000] [--no-stream]
        [--cpu-batch-sizes 1024] [--cpu-steps 30] [--no-cpu] [--out DIR]

Prints, in one run (each section's wall time after it):

1. Steps/s of one training step (the module's losses, backward and Adam), bare (batches
   drawn on the device beforehand, cycled) and through a Lightning Trainer (``TaskDataModule``,
   a TensorBoard logger every 50 steps, no progress bar; start-up not counted), for HBC and
   HiSPO with 1 and 4 anchors (both subspaces grown), on three paths: ``reference``
   (``hispo_pl.nn.fast.reference_path``: plain autograd modules, the default Adam),
   ``fast`` (the default step) and ``captured`` (``--model.init_args.optim.captured true``:
   the step as one program, a CUDA graph replayed per step on CUDA, run eagerly on the CPU;
   through the Trainer with ``--data.sampler device``), plus ``captured xG`` (the same with
   ``--data.group G``: G updates per Trainer step). On the machine's first CUDA device at
   each ``--batch-sizes``, and on one CPU thread at each ``--cpu-batch-sizes``, so the
   same table says whether the captured step pays on the CPU. Without CUDA the GPU rows say
   ``skipped: no CUDA``.
2. N processes side by side on the one GPU, each running the bare captured HBC step at the
   first batch size (``--workers``): the aggregate steps/s and each process's peak GPU
   memory (what ``hispo-pl benchmark --workers N -- --trainer.accelerator gpu`` runs N of).
3. One stream (HiSPO, seed 0) at ``--stream-steps`` steps per task through ``hispo-pl fit``
   with ``--trainer.accelerator gpu``, the captured step, device batches and groups of G:
   its wall time per task, where the time went (training, search, evaluation), PER, BWT, MEM
   and anchors. On the GPU only (a CPU stream takes minutes per task: ``stream_speed.py``).

Data for the task and the stream is generated first if it is missing (timed apart). The
figures go to docs/performance.md. Section 1's step rates and their table are
``gpu_step_rates.py``'s.
"""

from __future__ import annotations

import argparse
import logging
import multiprocessing as mp
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # a script of the checkout: its siblings
from gpu_step_rates import build, table  # noqa: E402

METHODS = ("HBC", "HiSPO-1", "HiSPO-4")
NO_CUDA = "skipped: no CUDA"


def _worker(args, batch_size: int, barrier, queue) -> None:
    """Section 2: the bare captured HBC step for ``--worker-seconds`` after a common start."""
    import torch

    from hispo_pl.data.datasets import load_episodes
    from hispo_pl.data.sampler import DeviceHERSampler, HERConfig
    from hispo_pl.nn.program import TrainingProgram, lr_table
    from hispo_pl.tasks import parse_task

    torch.set_num_threads(1)
    task = parse_task(args.task)
    episodes = load_episodes(task).for_task(task)
    her = HERConfig(task.defaults.waysteps, task.defaults.her_temperature)
    module = build("HBC", task.env_family.obs_dim, task.env_family.action_dim).cuda().train()
    params = [p for p in module.parameters() if p.requires_grad]
    program = TrainingProgram(module.losses, params, lr_table(1e-3, "constant", None), "cuda")
    sampler = DeviceHERSampler(episodes, her, batch_size, seed=0, device="cuda")
    pool = [sampler.sample() for _ in range(8)]
    for i in range(args.warmup):
        program.run(pool[i % 8])
    torch.cuda.synchronize()
    barrier.wait()
    start, n = time.perf_counter(), 0
    while time.perf_counter() - start < args.worker_seconds:
        for _ in range(50):
            program.run(pool[n % 8])
            n += 1
        torch.cuda.synchronize()
    queue.put((n, time.perf_counter() - start, torch.cuda.max_memory_reserved() / 2**20))


def workers_section(args) -> list[str]:
    import torch

    if not torch.cuda.is_available():
        print(f"workers: {NO_CUDA}")
        return [f"workers: {NO_CUDA}"]
    batch_size = args.batch_sizes[0]
    args = argparse.Namespace(**{k: v for k, v in vars(args).items() if k != "episodes"})
    ctx = mp.get_context("spawn")
    lines = []
    for n in args.workers:
        barrier, queue = ctx.Barrier(n), ctx.Queue()
        procs = [
            ctx.Process(target=_worker, args=(args, batch_size, barrier, queue)) for _ in range(n)
        ]
        for p in procs:
            p.start()
        outs = [queue.get() for _ in procs]
        for p in procs:
            p.join()
        total = sum(steps / seconds for steps, seconds, _ in outs)
        memory = max(m for *_, m in outs)
        lines.append(
            f"{n:2d} processes: {total:8.1f} steps/s in all, {total / n:7.1f} each, "
            f"peak {memory:6.0f} MiB reserved per process"
        )
        print(lines[-1], flush=True)
    return lines


def stream_section(args) -> list[str]:
    """Section 3: one stream through ``hispo-pl fit`` on the GPU, captured, device batches."""
    import torch

    if not torch.cuda.is_available():
        print(f"stream: {NO_CUDA}")
        return [f"stream: {NO_CUDA}"]
    from hispo_pl.benchmark.launch import execute_run, run_env
    from hispo_pl.benchmark.plan import RUNS_DIR, fit_argv, stream_config_path
    from hispo_pl.metrics import METRIC
    from hispo_pl.rundir import RunDir

    root = Path(__file__).resolve().parents[1] / "configs"
    out = Path(args.out or tempfile.mkdtemp(prefix="gpu_speed_stream_")).resolve()
    name = f"hispo-captured-g{args.group}"
    extra = [
        "--trainer.accelerator",
        "gpu",
        "--model.init_args.optim.captured",
        "true",
        "--data.sampler",
        "device",
        "--data.group",
        str(args.group),
    ]
    argv = fit_argv(
        stream_config_path(args.stream, root),
        root / "methods" / "hispo.yaml",
        name,
        0,
        out,
        1,
        args.stream_steps,
        extra,
    )
    run_dir = RunDir(out / RUNS_DIR / name / "seed0")
    print(f"stream: python -m hispo_pl.cli {' '.join(argv)}", flush=True)
    outcome = execute_run(
        ["-m", "hispo_pl.cli", *argv], str(run_dir.fit_log), str(run_dir.results_file), run_env(1)
    )
    if outcome["results"] is None:
        line = f"stream: failed (exit {outcome['returncode']}); log {run_dir.fit_log}"
        print(line + "\n" + outcome["log_tail"], flush=True)
        return [line]
    results = run_dir.stream_results()
    lines = [
        f"stream {args.stream}, HiSPO seed 0, {args.stream_steps} steps per task: "
        f"{outcome['seconds'] / 60:.2f} min for the command"
    ]
    for i, (wall, phases) in enumerate(
        zip(results.wall_time_s, results.phase_time_s or [None] * 99, strict=False), start=1
    ):
        parts = ", ".join(f"{k} {v:.1f} s" for k, v in (phases or {}).items())
        rate = args.stream_steps / phases["training"] if phases and phases.get("training") else 0
        lines.append(f"  T{i:02d} {wall:6.1f} s ({parts}; {rate:.0f} training steps/s)")
    metrics = "  ".join(f"{k} {METRIC[k].format(v)}" for k, v in results.metrics.items())
    anchors = " ".join(f"{k}={v}" for k, v in (results.anchors or {}).items())
    lines.append(f"  {metrics}  anchors {anchors}; run files: {run_dir.path}")
    for line in lines:
        print(line, flush=True)
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="pointmaze-umaze")
    parser.add_argument("--batch-sizes", type=int, nargs="+", default=[1024, 8192])
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--steps", type=int, default=200, help="timed steps per GPU figure")
    parser.add_argument("--warmup", type=int, default=20, help="untimed steps before each")
    parser.add_argument("--rounds", type=int, default=2, help="bare rounds per figure (median)")
    parser.add_argument("--group", type=int, default=8, help="G of the captured xG column")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4, 8])
    parser.add_argument("--worker-seconds", type=float, default=8.0)
    parser.add_argument("--stream", default="pointmaze-1")
    parser.add_argument("--stream-steps", type=int, default=6000)
    parser.add_argument("--no-stream", action="store_true")
    parser.add_argument("--cpu-batch-sizes", type=int, nargs="*", default=[1024])
    parser.add_argument("--cpu-steps", type=int, default=30, help="timed steps per CPU figure")
    parser.add_argument("--no-cpu", action="store_true", help="no CPU rows")
    parser.add_argument("--out", default=None, help="where the stream's run goes (default: temp)")
    args = parser.parse_args()

    warnings.filterwarnings("ignore")
    import lightning  # noqa: F401  (its loggers exist once imported)
    import torch

    for name in ("lightning.pytorch", "lightning.fabric", "lightning.pytorch.utilities.rank_zero"):
        logging.getLogger(name).setLevel(logging.ERROR)

    from hispo_pl.data.datasets import load_episodes
    from hispo_pl.data.generation import generate_missing
    from hispo_pl.data.sampler import HERConfig
    from hispo_pl.nn import fast
    from hispo_pl.tasks import parse_stream, parse_task

    started = time.perf_counter()
    torch.set_num_threads(1)
    fast.retain_freed_memory()
    cuda = torch.cuda.is_available()
    task = parse_task(args.task)
    needed = [task, *(parse_stream(args.stream) if cuda and not args.no_stream else [])]
    for t in dict.fromkeys(needed):
        generate_missing(t)
    args.episodes = load_episodes(task).for_task(task)
    her = HERConfig(task.defaults.waysteps, task.defaults.her_temperature)
    data_ready = time.perf_counter() - started
    device_name = torch.cuda.get_device_name(0) if cuda else "none"
    print(
        f"torch {torch.__version__}, CUDA device: {device_name}; task {task.spec}; data ready "
        f"in {data_ready:.0f} s (not counted below)\n"
        "steps/s (median); bare: the step on batches already on the device; capt ms: the update "
        "that captures the graph (CUDA); Trainer: a fit with TaskDataModule; xG: captured with "
        f"--data.group {args.group}; c/f: captured / fast"
    )
    print(
        f"{'device':6s} {'method':8s} {'batch':>5s} | {'ref':>8s} {'fast':>8s} {'captured':>8s} "
        f"{'c/f':>5s} {'capt ms':>7s} | {'ref':>8s} {'fast':>8s} {'captured':>8s} {'xG':>8s} "
        f"{'c/f':>5s}\n{'':21s} | {'bare':^40s} | {'through the Trainer':^41s}",
        flush=True,
    )
    t0 = time.perf_counter()
    if cuda:
        table("cuda", args.batch_sizes, args, lambda b: (task, her, b), args.steps)
    else:
        print(f"cuda   {' '.join(args.methods)} at {args.batch_sizes}: {NO_CUDA}", flush=True)
    if not args.no_cpu:
        table("cpu", args.cpu_batch_sizes, args, lambda b: (task, her, b), args.cpu_steps)
    print(f"[section 1: {time.perf_counter() - t0:.0f} s]\n", flush=True)
    t0 = time.perf_counter()
    workers_section(args)
    print(f"[section 2: {time.perf_counter() - t0:.0f} s]\n", flush=True)
    t0 = time.perf_counter()
    if args.no_stream:
        print("stream: not asked (--no-stream)")
    else:
        stream_section(args)
    print(f"[section 3: {time.perf_counter() - t0:.0f} s]")
    print(f"benchmark wall time {time.perf_counter() - started:.0f} s (data included)")


if __name__ == "__main__":
    sys.exit(main())
