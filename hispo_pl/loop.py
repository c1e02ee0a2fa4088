"""ContinualLoop: a stream of tasks, each one ``trainer.fit`` of the same LightningModule.

Lightning has no API for several fits in one loop, so the loop is plain Python: one fresh
Trainer per task, one logger for the stream, and task-granular resume: after a task (and the
callbacks' task-end decisions) the loop writes ``task_XX.ckpt`` and the row of the success
matrix R; a rerun of the same command skips finished tasks.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import lightning as L
import numpy as np
import torch

from .config import upgrade_fingerprint
from .console import lightning_notices_once, quiet_lightning_notices, say, task_header, task_summary
from .data.datamodule import TaskDataModule
from .errors import Interrupted, RunDirError
from .io import atomic_save
from .metrics import continual_metrics, module_bytes, results_row_table
from .modules.hispo import SubspacePolicy
from .results import StreamResults
from .rundir import RunDir, task_label
from .stream_report import log_stream_end, log_task_end
from .tasks import Task, parse_task


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

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        self._trainer = trainer

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        step = trainer.global_step
        if self.every > 0 and step % self.every == 0 and 0 < step < trainer.max_steps:
            # the full training state
            atomic_save(self.path, lambda tmp: trainer.save_checkpoint(tmp, weights_only=False))

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
        return {
            "torch": torch.get_rng_state(),
            "numpy": torch.from_numpy(keys.astype(np.int64)),
            "np_rest": [int(pos), int(has_gauss), float(cached)],
            "python": [version, list(internal), gauss],
            "sampler": [g.bit_generator.state for g in generators],
        }

    def load_state_dict(self, state_dict: dict) -> None:
        self._pending = state_dict


def task_phases(fit_seconds: float, callback_seconds: dict[str, float]) -> dict[str, float]:
    """Where a task's ``fit`` went: ``training`` (the steps, with Lightning's own work and
    the callbacks that are not timed) and the timed callback phases (``search``,
    ``evaluation``), in seconds."""
    phases = {"training": fit_seconds - sum(callback_seconds.values())}
    phases.update(sorted(callback_seconds.items()))
    return phases


def fit_interruptibly(trainer: L.Trainer, module: L.LightningModule, datamodule, **kwargs) -> None:
    """``trainer.fit``, where Ctrl-C raises ``KeyboardInterrupt`` again: Lightning turns it into
    ``sys.exit(1)`` after its own shutdown and leaves SIGINT ignored."""
    try:
        trainer.fit(module, datamodule=datamodule, **kwargs)
    except SystemExit:
        if not trainer.interrupted:
            raise
        signal.signal(signal.SIGINT, signal.default_int_handler)
        raise KeyboardInterrupt from None


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
        f = open(self.path, "a+")
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
        f.seek(0)
        f.truncate()
        f.write(
            f"pid {os.getpid()} on {socket.gethostname()}, started "
            f"{time.strftime('%Y-%m-%d %H:%M:%S')}: {' '.join(sys.argv)}\n"
        )
        f.flush()
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


class ContinualLoop:
    """Trains ``module`` on each task of ``stream`` in turn and measures R[i, j].

    Args:
        stream: task specs in order.
        module: the method (its state carries over from task to task).
        make_datamodule: task spec → the task's datamodule (knowing the whole stream).
        make_trainer: task index → a fresh Trainer (callbacks may be shared instances).
        run_dir: where checkpoints, ``progress.json`` and ``results.json`` go.
        reference_bytes: bytes of one single-task model, for MEM.
        scratch_success: success of from-scratch single-task models per task, for FWT.
        seed: when set, every task ``k`` starts with ``seed_everything(seed + k)``, so a task
            trains the same whether the run went through the earlier tasks or resumed after
            them (a resumed run skips their random draws).
        fingerprint: every setting that defines the run (flat ``dotted.key: value``), stored
            in ``progress.json``; a rerun with other values is refused, naming the keys, so
            tasks trained under different settings never mix. None: not checked.
        config_text: the run's configuration, kept as ``task_XX.config.yaml`` for each task
            it trained.
        checkpoint_every: save the task in progress every this many steps
            (``task_XX.partial.ckpt``, see :class:`TaskCheckpoint`); a rerun resumes the task
            from there. 0: only whole tasks are kept.
        pictures: after each task, draw ten of its scored rollouts on its maze for TensorBoard.
    """

    def __init__(
        self,
        stream: Sequence[str | Task],
        module: L.LightningModule,
        make_datamodule: Callable[[str], TaskDataModule],
        make_trainer: Callable[[int], L.Trainer],
        run_dir: RunDir | str | Path,
        reference_bytes: int | None = None,
        scratch_success: Sequence[float] | None = None,
        seed: int | None = None,
        fingerprint: dict | None = None,
        config_text: str | None = None,
        checkpoint_every: int = 0,
        pictures: bool = True,
    ):
        self.stream = [parse_task(t).spec for t in stream]
        self.module = module
        self.make_datamodule = make_datamodule
        self.make_trainer = make_trainer
        self.run_dir = RunDir.of(run_dir)
        self.reference_bytes = reference_bytes
        self.scratch_success = scratch_success
        self.seed = seed
        self.fingerprint = fingerprint
        self.config_text = config_text
        self.checkpoint_every = checkpoint_every
        self.pictures = pictures  # a rollout picture per task in TensorBoard
        self._loggers: list = []  # the trainers' loggers, for the stream-level report
        self._layout_logged = False

    # --- progress on disk -------------------------------------------------------------------

    def _load_progress(self) -> dict:
        fresh = {
            "stream": self.stream,
            "rows": [],
            "wall_time_s": [],
            "phase_time_s": [],
            "datasets": [],
        }
        if self.fingerprint is not None:
            fresh["fingerprint"] = self.fingerprint
        progress = self.run_dir.read_progress()  # a malformed file: RunDirError, named
        if progress is None:
            return fresh
        if progress["stream"] != self.stream:
            raise RunDirError(
                f"{self.run_dir} holds a run of stream {progress['stream']}, not {self.stream}; "
                "choose another run directory (e.g. --trainer.logger.init_args.version)"
            )
        stored = progress.get("fingerprint")
        stored = upgrade_fingerprint(stored) if stored is not None else None
        differing = differing_keys(stored or {}, self.fingerprint or {})
        started = progress["rows"] or self.run_dir.partial_checkpoint(0).exists()
        if differing and not started:  # refused or stopped before its first step: no mixing
            return fresh
        if self.fingerprint is not None and stored is not None and differing:
            diff = "\n  ".join(differing)
            raise RunDirError(
                f"{self.run_dir} holds a run with other settings; resuming would mix tasks "
                f"trained differently. Differing (stored -> now):\n  {diff}\nRerun with the "
                "stored settings to resume, or give this run another directory (e.g. "
                "--trainer.logger.init_args.version)"
            )
        if self.fingerprint is not None and stored is None:
            progress["fingerprint"] = self.fingerprint  # a run from before fingerprints
        # a run from before phase times: its finished tasks have none
        progress.setdefault("phase_time_s", [None] * len(progress["rows"]))
        # ... nor the datasets its finished tasks read
        progress.setdefault("datasets", [None] * len(progress["rows"]))
        return progress

    def _save_progress(self, progress: dict) -> None:
        self.run_dir.write_progress(progress)

    def _keep_finished_decisions(self, done: int) -> None:
        """Drop ``decisions.jsonl`` records of tasks that did not finish (a kill after a task's
        decisions but before its progress was saved), so a resumed task's records appear
        once. Records carry the 0-based ``task``."""

        def finished(record: dict) -> bool:
            task = record.get("task")
            return isinstance(task, int) and task < done

        self.run_dir.keep_decisions(finished)

    # --- the loop ---------------------------------------------------------------------------

    def run(self) -> dict:
        """Train the tasks not finished yet, holding the run directory's lock throughout."""
        self.run_dir.path.mkdir(parents=True, exist_ok=True)
        with RunDirLock(self.run_dir), lightning_notices_once():
            return self._run()

    def _run(self) -> dict:
        self.run_dir.remove_stale_temporaries()  # of writes a kill cut short; the lock is ours
        progress = self._load_progress()
        done = len(progress["rows"])
        last = self.run_dir.checkpoint(done - 1) if done else None
        if last is not None and not last.exists():
            raise MissingCheckpointError(
                f"{RunDir.PROGRESS} lists {done} finished tasks but {last.name} is missing"
            )
        self._keep_finished_decisions(done)
        self._save_progress(progress)  # the fingerprint, before anything trains
        if last is not None:
            self.module.load_checkpoint_file(last)
            print(f"[hispo-pl] resuming {self.run_dir}: tasks 1..{done} already trained")
        for k in range(done, len(self.stream)):
            try:
                self._train_task(k, progress)
            except KeyboardInterrupt:
                kept = f"tasks 1..{k} are finished and kept" if k else "no task had finished"
                partial = self.run_dir.partial_checkpoint(k)
                if self.checkpoint_every > 0 and partial.exists():
                    kept += f", task {task_label(k)} is saved part-way ({partial.name})"
                raise Interrupted(
                    f"interrupted during task {task_label(k)} of {len(self.stream)}; {kept} in "
                    f"{self.run_dir}. Rerun the same command to resume."
                ) from None
        results = self._results(progress)
        self.run_dir.write_results(results)
        if self._loggers:
            decisions = self.run_dir.decisions()
            log_stream_end(self._loggers, results, decisions, self.fingerprint or {})
        return results.to_json()

    def _rollout_picture(self, k: int):
        """Ten of task ``k``'s scored rollouts (RolloutEvaluation's, with their paths) drawn on
        its maze, for TensorBoard; None when the task's rollouts were not recorded."""
        from .render import Overlay, maze_figure

        rollouts = self.module.task_record.rollouts
        if rollouts is None or rollouts.trajectories is None:
            return None
        overlay = Overlay(list(rollouts.trajectories[:10]), rollouts.successes[:10])
        return maze_figure([self.stream[k]], [overlay])

    def _train_task(self, k: int, progress: dict) -> None:
        """Train task ``k`` and record its checkpoint, configuration and row of R."""
        start = time.perf_counter()
        if self.seed is not None:
            workers = os.environ.get("PL_SEED_WORKERS") == "1"  # as the CLI seeded
            L.seed_everything(self.seed + k, workers=workers, verbose=False)
        self.module.task_index = k
        self.module.log_prefix = f"task_{task_label(k):02d}/"
        trainer = self.make_trainer(k)
        partial = self.run_dir.partial_checkpoint(k)
        if self.checkpoint_every > 0:
            trainer.callbacks.append(TaskCheckpoint(partial, self.checkpoint_every))
        resume = partial if partial.exists() and self.checkpoint_every > 0 else None
        if resume is not None:
            print(f"[hispo-pl] resuming task {task_label(k)} from {partial.name}")
        datamodule = self.make_datamodule(self.stream[k])
        datamodule.prepare_data()  # as fit does first: the header can count the dataset's episodes
        say(task_header(k, len(self.stream), datamodule.describe(), trainer.max_steps))
        fit_start = time.perf_counter()
        fit_interruptibly(trainer, self.module, datamodule, ckpt_path=resume, weights_only=True)
        phases = task_phases(time.perf_counter() - fit_start, self.module.task_record.seconds)
        row = self.module.task_record.success_row  # RolloutEvaluation's, at the task's end
        if row is None:
            raise RuntimeError(
                "the stream needs a RolloutEvaluation callback to measure R after each task"
            )
        self._loggers = list(trainer.loggers)
        if self._loggers:
            picture = self._rollout_picture(k) if self.pictures else None
            subspaces = None
            if not self._layout_logged:  # the Custom Scalars layout, once per run
                decided = self.run_dir.decisions()
                subspaces = list(dict.fromkeys(d.subspace for d in decided))
                self._layout_logged = True
            log_task_end(self._loggers, k, row, picture, subspaces)
        atomic_save(
            self.run_dir.checkpoint(k), lambda tmp: trainer.save_checkpoint(tmp, weights_only=False)
        )
        if self.config_text is not None:
            self.run_dir.write_task_config(k, self.config_text)
        progress["rows"].append(list(row))
        elapsed = time.perf_counter() - start
        progress["wall_time_s"].append(elapsed)
        progress["phase_time_s"].append(phases)
        progress["datasets"].append(datamodule.dataset_use.as_json())
        self._save_progress(progress)
        partial.unlink(missing_ok=True)
        decisions = self.run_dir.decisions()
        say(task_summary(k, len(self.stream), elapsed, row, decisions, phases))
        quiet_lightning_notices()  # shown with the first task; the next ones repeat them

    def _results(self, progress: dict) -> StreamResults:
        n = len(self.stream)
        R = np.full((n, n), np.nan)
        for i, row in enumerate(progress["rows"]):
            R[i, : len(row)] = row
        stored = module_bytes(self.module)
        results = StreamResults(
            stream=self.stream,
            R=[[None if math.isnan(v) else v for v in row] for row in R.tolist()],
            wall_time_s=progress["wall_time_s"],
            phase_time_s=progress["phase_time_s"],
            # per task: the Minari id and the episodes it read (None: a task of an older run)
            datasets=progress["datasets"],
            metrics=continual_metrics(R, self.scratch_success, stored, self.reference_bytes),
            stored_bytes=stored,
            table=results_row_table(R),
        )
        if isinstance(self.module, SubspacePolicy):
            names = self.module.subspace_names
            results.anchors = {n: self.module.n_anchors(n) for n in names}
            results.alphas = {n: self.module.task_alphas(n).tolist() for n in names}
        return results
