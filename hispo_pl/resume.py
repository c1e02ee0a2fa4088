"""What lets a stream stop and go on: the run directory's lock, the fingerprint check that
refuses to mix tasks trained under other settings, and the task-in-progress checkpoint that
resumes a task mid-way with the random state it had."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
import time
from pathlib import Path

import lightning as L
import numpy as np
import torch

from .errors import RunDirError
from .io import atomic_save, named_errors, open_append
from .results import Progress
from .rundir import RunDir


def _sampler_generators(trainer: L.Trainer) -> list[np.random.Generator]:
    """The numpy generators that draw the training batches: the HER sampler(s) behind the
    task datamodule's loader (one per task for a replaying sampler)."""
    loader = trainer.train_dataloader
    sampler = getattr(getattr(loader, "dataset", None), "sampler", None)
    samplers = getattr(sampler, "samplers", [sampler])
    return [s.rng for s in samplers if isinstance(getattr(s, "rng", None), np.random.Generator)]


class TaskCheckpoint(L.Callback):
    """Saves the task in progress every ``every`` steps to ``path`` (atomically), so a run
    killed inside a long task resumes from there rather than from the task's start.

    With Lightning's own state (weights, optimiser, schedule, loop counters, callbacks) the
    file holds the random state a resumed task needs to go on exactly as an uninterrupted one:
    torch's, numpy's and Python's global generators and the batch sampler's generator, all
    as plain values (``weights_only=True`` loads it).
    """

    def __init__(self, path: Path, every: int):
        self.path, self.every = Path(path), every
        self._trainer: L.Trainer | None = None
        self._pending: dict | None = None
        self._started = time.perf_counter()
        self._saving = False  # True while the partial checkpoint is written
        self.seconds_before = 0.0
        """The task's seconds in the processes before this one, up to the partial checkpoint
        it resumed (0 for a task that starts here): a resumed task's wall time counts them."""

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        self._trainer = trainer

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        step = trainer.global_step
        if self.every > 0 and step % self.every == 0 and 0 < step < trainer.max_steps:
            # the full training state, and the seconds so far (only here: a finished task's
            # checkpoint stays a function of the run's settings alone)
            self._saving = True
            try:
                atomic_save(self.path, lambda tmp: trainer.save_checkpoint(tmp, weights_only=False))
            finally:
                self._saving = False

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self._pending is None:
            return
        import random

        state, self._pending = self._pending, None
        torch.set_rng_state(state["torch"])
        keys = state["numpy"].numpy().astype(np.uint32)
        np.random.set_state(("MT19937", keys, *state["np_rest"]))
        random.setstate((state["python"][0], tuple(state["python"][1]), state["python"][2]))
        generators = _sampler_generators(trainer)
        if len(generators) != len(state["sampler"]):
            raise RuntimeError("the resumed task's batch sampler differs from the saved one")
        for generator, saved in zip(generators, state["sampler"], strict=True):
            generator.bit_generator.state = saved

    def state_dict(self) -> dict:
        import random

        kind, keys, pos, has_gauss, cached = np.random.get_state()
        version, internal, gauss = random.getstate()
        generators = _sampler_generators(self._trainer) if self._trainer is not None else []
        state = {
            "torch": torch.get_rng_state(),
            "numpy": torch.from_numpy(keys.astype(np.int64)),
            "np_rest": [int(pos), int(has_gauss), float(cached)],
            "python": [version, list(internal), gauss],
            "sampler": [g.bit_generator.state for g in generators],
        }
        if self._saving:
            state["seconds"] = self.seconds_before + time.perf_counter() - self._started
        return state

    def load_state_dict(self, state_dict: dict) -> None:
        self._pending = state_dict
        self.seconds_before = float(state_dict.get("seconds", 0.0))  # 0: a file that has none


def differing_keys(stored: dict, current: dict) -> list[str]:
    """``key: stored -> current`` for every stored key whose value differs now (or is gone).
    Keys only ``current`` has are settings a newer hispo-pl added; they do not count, so an
    upgrade does not lock a run out of its own directory."""
    missing = object()
    out = []
    for key in sorted(stored):
        a, b = stored.get(key, missing), current.get(key, missing)
        if a != b:
            show = lambda v: "(unset)" if v is missing else json.dumps(v)  # noqa: E731
            out.append(f"{key}: {show(a)} -> {show(b)}")
    return out


class RunDirLock:
    """An exclusive lock on a run directory for as long as a run uses it (``fcntl.flock`` on
    ``run.lock``, released by the system even after ``kill -9``). The file names the holder
    (pid, host, start time, command), so a second run can say who it is waiting for.

    Raises:
        RunDirError: on enter, when another process holds the lock.
    """

    def __init__(self, run_dir: RunDir | str | Path):
        self.path = RunDir.of(run_dir).lock_file
        self._file = None

    def __enter__(self) -> RunDirLock:
        try:
            import fcntl
        except ImportError:  # not POSIX: no lock
            return self
        f = open_append(self.path, "a+")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.seek(0)
            holder = f.read().strip() or "another process"
            f.close()
            raise RunDirError(
                f"{self.path.parent} is in use by another run ({holder}); wait for it to end, "
                "or give this run another directory (e.g. --trainer.logger.init_args.version)"
            ) from None
        try:
            with named_errors(self.path):  # a full disk says which file
                f.seek(0)
                f.truncate()
                f.write(
                    f"pid {os.getpid()} on {socket.gethostname()}, started "
                    f"{time.strftime('%Y-%m-%d %H:%M:%S')}: {' '.join(sys.argv)}\n"
                )
                f.flush()
        except BaseException:
            with contextlib.suppress(OSError):  # what it could not write, it cannot flush
                f.close()  # releases the lock
            raise
        self._file = f
        return self

    def __exit__(self, *exc) -> None:
        if self._file is not None:
            self._file.seek(0)
            self._file.truncate()
            self._file.close()  # closing releases the lock
            self._file = None


class MissingCheckpointError(RunDirError, FileNotFoundError):
    """``progress.json`` lists a finished task whose checkpoint is gone."""


def resume_progress(run_dir: RunDir, stream: list[str], fingerprint: dict | None) -> Progress:
    """The progress a run of ``stream`` goes on from in ``run_dir``: the stored one, or a fresh
    one when there is none or the stored run never trained a step.

    Raises:
        RunDirError: the directory holds another stream, or a started run whose settings
            differ from ``fingerprint`` (the differing keys named).
    """
    fresh = Progress(stream=stream, fingerprint=fingerprint)
    progress = run_dir.read_progress()  # a malformed file: RunDirError, named
    if progress is None:
        return fresh
    if progress.stream != stream:
        raise RunDirError(
            f"{run_dir} holds a run of stream {progress.stream}, not {stream}; "
            "choose another run directory (e.g. --trainer.logger.init_args.version)"
        )
    stored = progress.fingerprint
    differing = differing_keys(stored or {}, fingerprint or {})
    started = progress.rows or run_dir.partial_checkpoint(0).exists()
    if differing and not started:  # refused or stopped before its first step: no mixing
        return fresh
    if fingerprint is not None and stored is not None and differing:
        diff = "\n  ".join(differing)
        raise RunDirError(
            f"{run_dir} holds a run with other settings; resuming would mix tasks "
            f"trained differently. Differing (stored -> now):\n  {diff}\nRerun with the "
            "stored settings to resume, or give this run another directory (e.g. "
            "--trainer.logger.init_args.version)"
        )
    return progress
