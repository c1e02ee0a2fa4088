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
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import lightning as L
import numpy as np
import torch

from .data.datamodule import TaskDataModule
from .data.tasks import Task, parse_task
from .metrics import continual_metrics, memory_ratio, module_bytes, results_row_table
from .modules.hispo import SubspacePolicy

PROGRESS_FILE = "progress.json"
RESULTS_FILE = "results.json"


def checkpoint_path(run_dir: Path, task_index: int) -> Path:
    """``task_01.ckpt`` for the first task: names count tasks from 1, like the paper."""
    return Path(run_dir) / f"task_{task_index + 1:02d}.ckpt"


def load_module_state(module: L.LightningModule, path: Path) -> None:
    """Load a task checkpoint into ``module`` in place (structure restored first); plain
    tensors and values only, so ``weights_only=True`` holds."""
    checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    module.on_load_checkpoint(checkpoint)
    module.load_state_dict(checkpoint["state_dict"])


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
    """

    def __init__(
        self,
        stream: Sequence[str | Task],
        module: L.LightningModule,
        make_datamodule: Callable[[str], TaskDataModule],
        make_trainer: Callable[[int], L.Trainer],
        run_dir: str | Path,
        reference_bytes: int | None = None,
        scratch_success: Sequence[float] | None = None,
        seed: int | None = None,
    ):
        self.stream = [parse_task(t).spec for t in stream]
        self.module = module
        self.make_datamodule = make_datamodule
        self.make_trainer = make_trainer
        self.run_dir = Path(run_dir)
        self.reference_bytes = reference_bytes
        self.scratch_success = scratch_success
        self.seed = seed

    # --- progress on disk -------------------------------------------------------------------

    def _load_progress(self) -> dict:
        path = self.run_dir / PROGRESS_FILE
        if not path.exists():
            return {"stream": self.stream, "rows": [], "wall_time_s": []}
        progress = json.loads(path.read_text())
        if progress["stream"] != self.stream:
            raise ValueError(
                f"{self.run_dir} holds a run of stream {progress['stream']}, not {self.stream}; "
                "choose another run directory (e.g. --trainer.logger.init_args.version)"
            )
        return progress

    def _save_progress(self, progress: dict) -> None:
        tmp = self.run_dir / (PROGRESS_FILE + ".tmp")
        tmp.write_text(json.dumps(progress, indent=1))
        tmp.replace(self.run_dir / PROGRESS_FILE)

    # --- the loop ---------------------------------------------------------------------------

    def run(self) -> dict:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        progress = self._load_progress()
        done = len(progress["rows"])
        if done and not checkpoint_path(self.run_dir, done - 1).exists():
            missing = checkpoint_path(self.run_dir, done - 1).name
            raise FileNotFoundError(
                f"{PROGRESS_FILE} lists {done} finished tasks but {missing} is missing"
            )
        if done:
            load_module_state(self.module, checkpoint_path(self.run_dir, done - 1))
            print(f"[hispo-pl] resuming {self.run_dir}: tasks 1..{done} already trained")
        for k in range(done, len(self.stream)):
            start = time.perf_counter()
            if self.seed is not None:
                workers = os.environ.get("PL_SEED_WORKERS") == "1"  # as the CLI seeded
                L.seed_everything(self.seed + k, workers=workers, verbose=False)
            self.module.task_index = k
            self.module.log_prefix = f"task_{k + 1:02d}/"
            trainer = self.make_trainer(k)
            trainer.fit(self.module, datamodule=self.make_datamodule(self.stream[k]))
            row = self._row_from(trainer, k)
            trainer.save_checkpoint(checkpoint_path(self.run_dir, k))
            progress["rows"].append(row)
            progress["wall_time_s"].append(time.perf_counter() - start)
            self._save_progress(progress)
        results = self._results(progress)
        (self.run_dir / RESULTS_FILE).write_text(json.dumps(results, indent=1))
        return results

    def _row_from(self, trainer: L.Trainer, k: int) -> list[float]:
        from .callbacks import RolloutEvaluation

        for cb in trainer.callbacks:
            if isinstance(cb, RolloutEvaluation) and cb.stream_row is not None:
                return list(cb.stream_row)
        raise RuntimeError(
            "the stream needs a RolloutEvaluation callback to measure R after each task"
        )

    def _results(self, progress: dict) -> dict:
        n = len(self.stream)
        R = np.full((n, n), np.nan)
        for i, row in enumerate(progress["rows"]):
            R[i, : len(row)] = row
        out: dict = {
            "stream": self.stream,
            "R": [[None if math.isnan(v) else v for v in row] for row in R.tolist()],
            "wall_time_s": progress["wall_time_s"],
        }
        out.update(continual_metrics(R, self.scratch_success))
        stored = module_bytes(self.module)
        out["stored_bytes"] = stored
        if self.reference_bytes:
            out["MEM"] = memory_ratio(stored, self.reference_bytes)
        if isinstance(self.module, SubspacePolicy):
            out["anchors"] = {n: self.module.n_anchors(n) for n in self.module.subspace_names}
            out["alphas"] = {
                n: self.module.task_alphas(n).tolist() for n in self.module.subspace_names
            }
        out["table"] = results_row_table(R)
        return out
