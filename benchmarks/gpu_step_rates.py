"""Section 1 of ``benchmarks/gpu_speed.py`` (not a script): the steps/s of one training step of
HBC or HiSPO-K on the ``reference``, ``fast`` and ``captured`` paths, bare and through a
Lightning Trainer, and the table of them on one device.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from contextlib import nullcontext

PATHS = ("reference", "fast", "captured")


def build(method: str, obs_dim: int, action_dim: int, captured: bool = False):
    """HBC, or HiSPO grown to ``HiSPO-K`` anchors per subspace; the captured step or not."""
    from hispo_pl.config import OptimConfig
    from hispo_pl.modules import HBC, HiSPO

    optim = OptimConfig(captured=captured)
    if method == "HBC":
        return HBC(obs_dim, action_dim, optim=optim)
    module = HiSPO(obs_dim, action_dim, optim=optim)
    for _ in range(int(method.split("-")[1]) - 1):
        for name in module.subspace_names:
            module.add_anchor(name)
    return module


def sync(device) -> None:
    import torch

    if torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


def bare_rate(method: str, path: str, device: str, data, args, steps: int):
    """Steps/s of the step alone, on batches drawn on ``device`` beforehand, and the seconds
    of the update that captured the step (CUDA only; else None)."""
    import torch

    from hispo_pl.data.sampler import DeviceHERSampler
    from hispo_pl.nn import fast
    from hispo_pl.nn.program import TrainingProgram, lr_table

    task, her, batch_size = data
    fam = task.env_family
    with fast.reference_path() if path == "reference" else nullcontext():
        torch.manual_seed(0)
        module = build(method, fam.obs_dim, fam.action_dim).to(device).train()
        params = [p for p in module.parameters() if p.requires_grad]
        sampler = DeviceHERSampler(args.episodes, her, batch_size, seed=0, device=device)
        pool = [sampler.sample() for _ in range(8)]
        if path == "captured":
            rates = lr_table(1e-3, "cosine", args.warmup + steps)
            program = TrainingProgram(module.losses, params, rates, torch.device(device))
            step = program.run
        else:
            opt = torch.optim.Adam(params, lr=1e-3, fused=fast.enabled())

            def step(batch):
                loss = module.losses(batch)["loss"]
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()

        capture = None
        for i in range(args.warmup):
            capturing = path == "captured" and program.capture and i == program.warmup
            if capturing:
                sync(device)
                start = time.perf_counter()
            step(pool[i % len(pool)])
            if capturing:
                sync(device)
                capture = time.perf_counter() - start
        sync(device)
        start = time.perf_counter()
        for i in range(steps):
            step(pool[i % len(pool)])
        sync(device)
        return steps / (time.perf_counter() - start), capture


def trainer_rate(method: str, path: str, device: str, data, args, steps: int, group: int = 1):
    """Steps/s (updates) through a Trainer fit of ``warmup + steps`` updates, timed from the
    first Trainer step after the warm-up to the end of training."""
    import lightning as L
    import torch
    from lightning.pytorch.loggers import TensorBoardLogger

    from hispo_pl.data.datamodule import TaskDataModule
    from hispo_pl.nn import fast

    task, _, batch_size = data
    fam = task.env_family
    captured = path == "captured"
    warmup = -(-args.warmup // group) * group  # whole groups, and at least one timed
    steps = max(-(-steps // group), 1) * group

    class Timer(L.Callback):
        start = first = end = last = None

        def on_train_batch_start(self, trainer, *_):
            if self.start is None and trainer.global_step >= warmup:
                sync(device)
                self.start, self.first = time.perf_counter(), trainer.global_step

        def on_train_end(self, trainer, *_):
            sync(device)
            self.end, self.last = time.perf_counter(), trainer.global_step

    with fast.reference_path() if path == "reference" else nullcontext():
        torch.manual_seed(0)
        module = build(method, fam.obs_dim, fam.action_dim, captured)
        timer = Timer()
        trainer = L.Trainer(
            accelerator="gpu" if device.startswith("cuda") else "cpu",
            devices=1,
            max_steps=warmup + steps,
            max_epochs=-1,
            callbacks=[timer],
            logger=TensorBoardLogger(tempfile.mkdtemp(prefix="gpu_speed_")),
            log_every_n_steps=50,
            enable_checkpointing=False,
            enable_progress_bar=False,
            enable_model_summary=False,
        )
        dm = TaskDataModule(
            task.spec,
            batch_size=batch_size,
            sampler="device" if captured else "host",
            group=group,
            holdout=0.0,
        )
        trainer.fit(module, dm)
    return (timer.last - timer.first) / (timer.end - timer.start)


def table(device: str, batch_sizes, args, data_for, steps: int) -> list[str]:
    """The rows of section 1 on ``device``: per method and batch size, each path's steps/s,
    bare and through the Trainer (medians over ``--rounds``), and the captured/fast ratios."""
    lines = []
    for batch_size in batch_sizes:
        data = data_for(batch_size)
        for method in args.methods:
            bare = {p: [] for p in PATHS}
            fit = {p: [] for p in (*PATHS, "group")}
            captures = []
            for r in range(args.rounds):
                order = PATHS if r % 2 == 0 else PATHS[::-1]
                for path in order:
                    rate, capture = bare_rate(method, path, device, data, args, steps)
                    bare[path].append(rate)
                    captures += [capture] if capture is not None else []
                    cleanup()
            for path in PATHS:  # one Trainer fit per path: start-up makes them dear
                fit[path].append(trainer_rate(method, path, device, data, args, steps))
                cleanup()
            if args.group > 1:
                rate = trainer_rate(method, "captured", device, data, args, steps, args.group)
                fit["group"].append(rate)
                cleanup()
            b = {k: statistics.median(v) for k, v in bare.items()}
            t = {k: statistics.median(v) if v else float("nan") for k, v in fit.items()}
            capture = f"{1000 * statistics.median(captures):7.0f}" if captures else f"{'-':>7s}"
            lines.append(
                f"{device:6s} {method:8s} {batch_size:5d} | "
                + " ".join(f"{b[p]:8.1f}" for p in PATHS)
                + f" {b['captured'] / b['fast']:5.2f} {capture} | "
                + " ".join(f"{t[p]:8.1f}" for p in PATHS)
                + f" {t['group']:8.1f} {t['captured'] / t['fast']:5.2f}"
            )
            print(lines[-1], flush=True)
    return lines


def cleanup() -> None:
    import gc

    import torch

    gc.collect()
    if torch.cuda.is_available():
        torch.cuda.empty_cache()
