"""ContinualLoop: a stream of tasks, each one ``trainer.fit`` of the same LightningModule.

Lightning has no API for several fits in one loop, so the loop is plain Python: one fresh
Trainer per task, one logger for the stream, and task-granular resume: after a task (and the
callbacks' task-end decisions) the loop writes ``task_XX.ckpt`` and the row of the success
matrix R; a rerun of the same command skips finished tasks. What makes a stop and a resume
safe (the run directory's lock, the fingerprint check, the task-in-progress checkpoint) is in
:mod:`.resume`.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import signal
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import lightning as L
import numpy as np

from .callbacks.protocols import WeightedSubspaces
from .console import lightning_notices_once, quiet_lightning_notices, say, task_header, task_summary
from .data.datamodule import TaskDataModule
from .errors import Interrupted, ResumableWork
from .io import atomic_save, files_in_log_dir
from .metrics import continual_metrics, memory_ratio, module_bytes, results_row_table
from .results import Progress, StreamResults
from .resume import MissingCheckpointError, RunDirLock, TaskCheckpoint, resume_progress
from .rundir import RunDir, task_label
from .stopping import interrupt_behind
from .stream_report import log_stream_end, log_task_end
from .tasks import Task, parse_task


def task_phases(fit_seconds: float, callback_seconds: dict[str, float]) -> dict[str, float]:
    """Where a task's ``fit`` went: ``training`` (the steps, with Lightning's own work and
    the callbacks that are not timed) and the timed callback phases (``search``,
    ``evaluation``), in seconds."""
    phases = {"training": fit_seconds - sum(callback_seconds.values())}
    phases.update(sorted(callback_seconds.items()))
    return phases


DISK_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO)  # a disk's, not a path's


@contextlib.contextmanager
def _event_writer_errors_said_once():
    """TensorBoard's writer thread prints the error of the disk that stopped it, which the
    Trainer raises again in this thread: it is said once, here, in one paragraph."""
    hook = threading.excepthook

    def quiet(args) -> None:
        disk = getattr(args.exc_value, "errno", None) in DISK_ERRORS
        if not (disk and type(args.thread).__name__ == "_AsyncWriterThread"):
            hook(args)

    threading.excepthook = quiet
    try:
        yield
    finally:
        threading.excepthook = hook


def fit_interruptibly(trainer: L.Trainer, module: L.LightningModule, datamodule, **kwargs) -> None:
    """``trainer.fit``, where Ctrl-C raises ``KeyboardInterrupt`` again: Lightning turns it into
    ``sys.exit(1)`` after its own shutdown and leaves SIGINT ignored (the handler before it is
    put back). The files Lightning writes by name stay in the logger's folder
    (:func:`~hispo_pl.io.files_in_log_dir`), an error of the file system without a path
    (TensorBoard's writer gives none) names that folder, and a stop that an import wrapped in
    another error is the stop again (:func:`~hispo_pl.stopping.interrupt_behind`)."""
    files_in_log_dir(trainer)
    ctrl_c = signal.getsignal(signal.SIGINT)  # Python's, or the command's (hispo_pl.stopping)
    try:
        with _event_writer_errors_said_once():
            trainer.fit(module, datamodule=datamodule, **kwargs)
    except SystemExit:
        if not trainer.interrupted:
            raise
        signal.signal(signal.SIGINT, ctrl_c)
        raise KeyboardInterrupt from None
    except Exception as err:
        if interrupt_behind(err):  # a stop that an import wrapped in its own error
            raise KeyboardInterrupt from None
        if not isinstance(err, OSError):
            raise
        # the writer of TensorBoard's event files says no path
        if err.filename is not None or err.errno not in DISK_ERRORS or trainer.log_dir is None:
            raise
        raise OSError(err.errno, err.strerror, trainer.log_dir) from err


class ContinualLoop:
    """Trains ``module`` on each task of ``stream`` in turn and measures R[i, j].

    Args:
        stream: the tasks (or their specs) in order.
        module: the method (its state carries over from task to task).
        make_datamodule: task → the task's datamodule (knowing the whole stream).
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
        make_datamodule: Callable[[Task], TaskDataModule],
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
        self.stream: list[Task] = [parse_task(t) for t in stream]  # parsed once, here
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

    @property
    def specs(self) -> list[str]:
        """The stream as task specs, the form its files hold."""
        return [task.spec for task in self.stream]

    # --- progress on disk -------------------------------------------------------------------

    def _keep_finished_decisions(self, done: int) -> None:
        """Drop ``decisions.jsonl`` records of tasks that did not finish (a kill after a task's
        decisions but before its progress was saved), so a resumed task's records appear
        once. Records carry the 0-based ``task``."""
        self.run_dir.keep_decisions(lambda d: isinstance(d.task, int) and d.task < done)

    # --- the loop ---------------------------------------------------------------------------

    def run(self) -> StreamResults:
        """Train the tasks not finished yet, holding the run directory's lock throughout. A
        stop or an error of the machine at any point leaves what a rerun resumes, and says so
        (a stop outside a task too: while the lock is taken or the results are written).
        Returns the stream's results, as written to ``results.json``."""
        self.run_dir.path.mkdir(parents=True, exist_ok=True)
        try:
            with ResumableWork(), RunDirLock(self.run_dir), lightning_notices_once():
                return self._run()
        except KeyboardInterrupt as err:
            if isinstance(err, Interrupted):
                raise
            raise Interrupted(
                f"interrupted; the tasks finished so far are kept in {self.run_dir}. Rerun the "
                "same command to resume."
            ) from None

    def _run(self) -> StreamResults:
        self.run_dir.remove_stale_temporaries()  # of writes a kill cut short; the lock is ours
        progress = resume_progress(self.run_dir, self.specs, self.fingerprint)
        done = progress.done
        last = self.run_dir.checkpoint(done - 1) if done else None
        if last is not None and not last.exists():
            raise MissingCheckpointError(
                f"{RunDir.PROGRESS} lists {done} finished tasks but {last.name} is missing"
            )
        self._keep_finished_decisions(done)
        self.run_dir.write_progress(progress)  # the fingerprint, before anything trains
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
        return results

    def _rollout_picture(self, k: int):
        """Ten of task ``k``'s scored rollouts (RolloutEvaluation's, with their paths) drawn on
        its maze, for TensorBoard; None when the task's rollouts were not recorded."""
        from .render import Overlay, maze_figure

        rollouts = self.module.task_record.rollouts
        if rollouts is None or rollouts.trajectories is None:
            return None
        overlay = Overlay(list(rollouts.trajectories[:10]), rollouts.successes[:10])
        return maze_figure([self.stream[k]], [overlay])

    def _train_task(self, k: int, progress: Progress) -> None:
        """Train task ``k`` and record its checkpoint, configuration and row of R."""
        start = time.perf_counter()
        if self.seed is not None:
            workers = os.environ.get("PL_SEED_WORKERS") == "1"  # as the CLI seeded
            L.seed_everything(self.seed + k, workers=workers, verbose=False)
        self.module.task_index = k
        self.module.log_prefix = f"task_{task_label(k):02d}/"
        trainer = self.make_trainer(k)
        partial = self.run_dir.partial_checkpoint(k)
        checkpoint = TaskCheckpoint(partial, self.checkpoint_every)
        if self.checkpoint_every > 0:
            trainer.callbacks.append(checkpoint)
        resume = partial if partial.exists() and self.checkpoint_every > 0 else None
        if resume is not None:
            print(f"[hispo-pl] resuming task {task_label(k)} from {partial.name}")
        datamodule = self.make_datamodule(self.stream[k])
        datamodule.prepare_data()  # as fit does first: the header can count the dataset's episodes
        say(task_header(k, len(self.stream), datamodule.describe(), trainer.max_steps))
        fit_start = time.perf_counter()
        fit_interruptibly(trainer, self.module, datamodule, ckpt_path=resume, weights_only=True)
        phases = task_phases(time.perf_counter() - fit_start, self.module.task_record.seconds)
        phases["training"] += checkpoint.seconds_before  # the steps an earlier process trained
        row = self.module.task_record.success_row  # RolloutEvaluation's, at the task's end
        memory_now = self._memory()  # after the task's decisions
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
            rows = [*progress.rows, list(row)]  # R so far, this task's row last
            log_task_end(self._loggers, rows, picture, subspaces, memory_now)
        atomic_save(
            self.run_dir.checkpoint(k), lambda tmp: trainer.save_checkpoint(tmp, weights_only=False)
        )
        if self.config_text is not None:
            self.run_dir.write_task_config(k, self.config_text)
        elapsed = time.perf_counter() - start + checkpoint.seconds_before
        progress.finish_task(row, elapsed, phases, datamodule.dataset_use.as_json(), memory_now)
        self.run_dir.write_progress(progress)
        partial.unlink(missing_ok=True)
        decisions = self.run_dir.decisions()
        say(task_summary(k, len(self.stream), elapsed, row, decisions, phases))
        quiet_lightning_notices()  # shown with the first task; the next ones repeat them

    def _memory(self) -> float | None:
        """MEM of the module as it stands (after a task's decisions); None without a
        single-task model to measure it against."""
        if not self.reference_bytes:
            return None
        return memory_ratio(module_bytes(self.module), self.reference_bytes)

    def _results(self, progress: Progress) -> StreamResults:
        n = len(self.stream)
        R = np.full((n, n), np.nan)
        for i, row in enumerate(progress.rows):
            R[i, : len(row)] = row
        stored = module_bytes(self.module)
        results = StreamResults(
            stream=self.specs,
            R=[[None if math.isnan(v) else v for v in row] for row in R.tolist()],
            wall_time_s=progress.wall_time_s,
            phase_time_s=progress.phase_time_s,
            # per task: the Minari id and the episodes it read (None: a task of an older run)
            datasets=progress.datasets,
            metrics=continual_metrics(R, self.scratch_success, stored, self.reference_bytes),
            stored_bytes=stored,
            table=results_row_table(R),
            mem_per_task=progress.mem_per_task,
        )
        if isinstance(self.module, WeightedSubspaces):
            names = self.module.subspace_names
            results.anchors = {n: self.module.n_anchors(n) for n in names}
            results.alphas = {n: self.module.task_alphas(n).tolist() for n in names}
        return results
