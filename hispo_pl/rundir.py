"""A run's directory: every file a run writes or reads back, by name and format, in one place.

The loop, the callbacks, the CLI, the benchmark, the study scripts and the notebook all go
through :class:`RunDir`, so a file name is spelled once. Tasks are 0-based everywhere in code
and data; :func:`task_label` is the one place that turns an index into the 1-based label
users see in file names, TensorBoard tags and messages. No torch here: reports, scripts and
the notebook import it freely.

========================  =====================================================================
``task_XX.ckpt``          the module after task XX and its decisions (the loop)
``task_XX.partial.ckpt``  task XX part-way through, for a resume inside it
``task_XX.config.yaml``   the configuration task XX was trained with
``progress.json``         stream, rows of R and wall times of the finished tasks, fingerprint
``results.json``          the stream's results: R, PER, BWT, FWT, MEM, anchors, alphas, table
``decisions.jsonl``       one JSON record per task-end decision (keep / prune / transfer)
``search/task_XX_S.npz``  the Dirichlet search of subspace S at the end of task XX
``figures/``              the notebook's pictures of the run
``result.json``           a single-task fit's final evaluation
``config.yaml``           LightningCLI's copy of the whole configuration
``run.json``              the benchmark's record of a run it launched
``fit.log``               the output of a run the benchmark launched
``run.lock``              held while a run uses the directory
========================  =====================================================================
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from .io import atomic_write_text


def task_label(index: int) -> int:
    """The label users see for the 0-based task ``index``: tasks count from 1, like the paper.

    Example:
        >>> task_label(0), f"task_{task_label(2):02d}.ckpt"
        (1, 'task_03.ckpt')
    """
    return index + 1


def _task_index(label: str) -> int:
    return int(label) - 1


class RunDir:
    """The files of one run directory (it need not exist yet).

    Example:
        >>> run = RunDir("runs/pointmaze-1/seed0")
        >>> run.checkpoint(0).name, run.search_file(1, "low").as_posix()
        ('task_01.ckpt', 'runs/pointmaze-1/seed0/search/task_02_low.npz')
    """

    PROGRESS = "progress.json"
    RESULTS = "results.json"
    DECISIONS = "decisions.jsonl"
    SEARCH = "search"
    FIGURES = "figures"
    RESULT = "result.json"
    CONFIG = "config.yaml"
    RUN_RECORD = "run.json"
    FIT_LOG = "fit.log"
    LOCK = "run.lock"
    EXPORTED = (RESULTS, DECISIONS, CONFIG, RUN_RECORD)
    """The small files of a finished run that ``docs/results`` keeps (never checkpoints)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    @classmethod
    def of(cls, value: RunDir | str | os.PathLike) -> RunDir:
        return value if isinstance(value, RunDir) else cls(value)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    def __str__(self) -> str:
        return str(self.path)

    def __fspath__(self) -> str:
        return str(self.path)

    # --- names ------------------------------------------------------------------------------

    def _task_file(self, task: int, suffix: str) -> Path:
        return self.path / f"task_{task_label(task):02d}{suffix}"

    def checkpoint(self, task: int) -> Path:
        """The module after task ``task`` (0-based) and its task-end decisions."""
        return self._task_file(task, ".ckpt")

    def partial_checkpoint(self, task: int) -> Path:
        """Task ``task`` part-way through (a rerun resumes it from there)."""
        return self._task_file(task, ".partial.ckpt")

    def task_config(self, task: int) -> Path:
        """The configuration task ``task`` was trained with."""
        return self._task_file(task, ".config.yaml")

    def search_file(self, task: int, subspace: str) -> Path:
        return self.path / self.SEARCH / f"task_{task_label(task):02d}_{subspace}.npz"

    @property
    def figures_dir(self) -> Path:
        return self.path / self.FIGURES

    @property
    def progress_file(self) -> Path:
        return self.path / self.PROGRESS

    @property
    def results_file(self) -> Path:
        return self.path / self.RESULTS

    @property
    def decisions_file(self) -> Path:
        return self.path / self.DECISIONS

    @property
    def result_file(self) -> Path:
        return self.path / self.RESULT

    @property
    def config_file(self) -> Path:
        return self.path / self.CONFIG

    @property
    def run_record_file(self) -> Path:
        return self.path / self.RUN_RECORD

    @property
    def fit_log(self) -> Path:
        return self.path / self.FIT_LOG

    @property
    def lock_file(self) -> Path:
        return self.path / self.LOCK

    # --- formats ----------------------------------------------------------------------------

    def read_progress(self) -> dict | None:
        """``progress.json``, or None before the first task started.

        Raises:
            ValueError: the file is not readable JSON.
        """
        if not self.progress_file.exists():
            return None
        return json.loads(self.progress_file.read_text())

    def stream_task(self, task: int) -> str | None:
        """The spec of task ``task`` (0-based) of the stream this directory runs, or ``None``
        (not a stream run, or no such task)."""
        stream = (self.read_progress() or {}).get("stream") or []
        return stream[task] if 0 <= task < len(stream) else None

    def write_progress(self, progress: dict) -> None:
        atomic_write_text(self.progress_file, json.dumps(progress, indent=1))

    def has_results(self) -> bool:
        return self.results_file.exists()

    def read_results(self) -> dict:
        return json.loads(self.results_file.read_text())

    def write_results(self, results: dict) -> None:
        atomic_write_text(self.results_file, json.dumps(results, indent=1))

    def write_task_config(self, task: int, text: str) -> None:
        atomic_write_text(self.task_config(task), text)

    def read_decisions(self) -> list[dict]:
        """Every record of ``decisions.jsonl`` in order (none when absent); a line cut by a
        kill is skipped."""
        if not self.decisions_file.exists():
            return []
        records = []
        for line in self.decisions_file.read_text().splitlines():
            try:
                records.append(json.loads(line))
            except ValueError:
                continue
        return records

    def append_decisions(self, records: Iterable[dict]) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        with open(self.decisions_file, "a") as f:
            for record in records:
                f.write(json.dumps(record) + "\n")

    def keep_decisions(self, keep: Callable[[dict], bool]) -> None:
        """Rewrite ``decisions.jsonl`` with the records ``keep`` accepts (cut lines dropped);
        the file is left alone when nothing changes."""
        if not self.decisions_file.exists():
            return
        lines = self.decisions_file.read_text().splitlines(keepends=True)
        kept = []
        for line in lines:
            try:
                record = json.loads(line)
            except ValueError:
                continue
            if keep(record):
                kept.append(line if line.endswith("\n") else line + "\n")
        if kept != lines:
            atomic_write_text(self.decisions_file, "".join(kept))

    def write_search(self, task: int, subspace: str, **arrays) -> None:
        """The search's candidates and losses of one subspace at the end of ``task``."""
        path = self.search_file(task, subspace)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **arrays)

    def read_searches(self) -> dict[tuple[int, str], dict[str, np.ndarray]]:
        """Every saved search, keyed by (0-based task, subspace)."""
        out = {}
        for path in sorted((self.path / self.SEARCH).glob("task_*_*.npz")):
            _, label, subspace = path.stem.split("_", 2)
            with np.load(path) as data:
                out[(_task_index(label), subspace)] = {k: data[k] for k in data.files}
        return out

    def read_result(self) -> dict:
        return json.loads(self.result_file.read_text())

    def write_result(self, result: dict) -> None:
        atomic_write_text(self.result_file, json.dumps(result, indent=2) + "\n")

    def read_run_record(self) -> dict:
        """The benchmark's ``run.json`` (empty for a run it did not launch)."""
        if not self.run_record_file.exists():
            return {}
        return json.loads(self.run_record_file.read_text())

    def write_run_record(self, record: dict) -> None:
        atomic_write_text(self.run_record_file, json.dumps(record, indent=1))
