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

Each JSON file starts with its format number (``"format": 1``, :data:`~hispo_pl.results.
json_fields.FORMAT_KEY`); a reader refuses a file without the number its type writes, and
``python -m lab migrate FOLDER`` (the repository's lab) rewrites older files into it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from .io import atomic_save, atomic_write_text, named_errors, open_append, real_folder
from .results import (
    LAUNCH_FORMAT,
    PROGRESS_FORMAT,
    PROGRESS_KEYS,
    RESULT_FORMAT,
    RESULT_KEYS,
    Decision,
    LaunchRecord,
    Progress,
    StreamResults,
    TaskFitResult,
)
from .run_files import read_results_file, read_run_file, require_lists, run_file_text


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

    def remove_stale_temporaries(self) -> list[Path]:
        """Delete the ``.NAME.*tmp`` files that atomic writes leave when a kill interrupts
        them (call while holding the run's lock); the files removed."""
        stale = sorted(self.path.glob(".*tmp")) if self.path.is_dir() else []
        for path in stale:
            path.unlink(missing_ok=True)
        return stale

    # --- formats ----------------------------------------------------------------------------

    def read_progress(self) -> Progress | None:
        """``progress.json``, or None before the first task started.

        Raises:
            RunDirError: the file is not a JSON object of format
                :data:`~hispo_pl.results.PROGRESS_FORMAT` with the lists ``stream`` and
                ``rows``.
        """
        if not self.progress_file.exists():
            return None
        holds = "a stream's progress"
        progress = read_run_file(self.progress_file, holds, PROGRESS_FORMAT, PROGRESS_KEYS)
        require_lists(self.progress_file, progress, ("stream", "rows"), holds)
        return Progress.from_json(progress)

    def stream_task(self, task: int) -> str | None:
        """The spec of task ``task`` (0-based) of the stream this directory runs, or ``None``
        (not a stream run, or no such task)."""
        progress = self.read_progress()
        stream = progress.stream if progress is not None else []
        return stream[task] if 0 <= task < len(stream) else None

    def write_progress(self, progress: Progress) -> None:
        atomic_write_text(self.progress_file, run_file_text(self.PROGRESS, progress.to_json()))

    def has_results(self) -> bool:
        return self.results_file.exists()

    def stream_results(self) -> StreamResults:
        """``results.json``, checked to be tabulable (:func:`~hispo_pl.run_files.results_problem`).

        Raises:
            RunDirError: the file is not JSON, not an object, not of the current format, or
                its R does not fit its stream.
        """
        return read_results_file(self.results_file)

    def write_results(self, results: StreamResults) -> None:
        atomic_write_text(self.results_file, run_file_text(self.RESULTS, results.to_json()))

    def write_task_config(self, task: int, text: str) -> None:
        atomic_write_text(self.task_config(task), text)

    def decisions(self) -> list[Decision]:
        """Every record of ``decisions.jsonl`` as its kind of
        :class:`~hispo_pl.results.Decision`, in order (none when absent); a line that is no
        decision record (cut by a kill, or of no known kind) is skipped."""
        if not self.decisions_file.exists():
            return []
        lines = self.decisions_file.read_text().splitlines()
        return [d for d in map(_decision, lines) if d is not None]

    def append_decisions(self, records: Iterable[Decision]) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        with named_errors(self.decisions_file), open_append(self.decisions_file) as f:
            for record in records:
                f.write(json.dumps(record.to_json()) + "\n")

    def keep_decisions(self, keep: Callable[[Decision], bool]) -> None:
        """Rewrite ``decisions.jsonl`` with the records ``keep`` accepts, each line as it was
        (lines that are no decision record dropped); the file is left alone when nothing
        changes."""
        if not self.decisions_file.exists():
            return
        lines = self.decisions_file.read_text().splitlines(keepends=True)
        kept = []
        for line in lines:
            record = _decision(line)
            if record is not None and keep(record):
                kept.append(line if line.endswith("\n") else line + "\n")
        if kept != lines:
            atomic_write_text(self.decisions_file, "".join(kept))

    def write_search(self, task: int, subspace: str, **arrays) -> None:
        """The search's candidates and losses of one subspace at the end of ``task``."""
        path = self.search_file(task, subspace)
        real_folder(path.parent, self.path)  # a link at search/ is replaced, not written into

        def save(tmp: Path) -> None:
            with open(tmp, "xb") as f:  # a file object: np.savez adds .npz to a name
                np.savez(f, **arrays)

        atomic_save(path, save)

    def read_searches(self) -> dict[tuple[int, str], dict[str, np.ndarray]]:
        """Every saved search, keyed by (0-based task, subspace)."""
        out = {}
        for path in sorted((self.path / self.SEARCH).glob("task_*_*.npz")):
            _, label, subspace = path.stem.split("_", 2)
            with np.load(path) as data:
                out[(_task_index(label), subspace)] = {k: data[k] for k in data.files}
        return out

    def read_result(self) -> TaskFitResult:
        """A single-task fit's ``result.json``.

        Raises:
            RunDirError: the file is not a JSON object of format
                :data:`~hispo_pl.results.RESULT_FORMAT` with every key of a result."""
        holds = "a single-task fit's evaluation"
        record = read_run_file(self.result_file, holds, RESULT_FORMAT, RESULT_KEYS)
        return TaskFitResult.from_json(record)

    def write_result(self, result: TaskFitResult) -> None:
        atomic_write_text(self.result_file, run_file_text(self.RESULT, result.to_json()))

    def read_run_record(self) -> LaunchRecord:
        """The benchmark's ``run.json`` (empty for a run it did not launch).

        Raises:
            RunDirError: the file is not a JSON object of format
                :data:`~hispo_pl.results.LAUNCH_FORMAT`."""
        if not self.run_record_file.exists():
            return LaunchRecord()
        holds = "the benchmark's record of the run"
        return LaunchRecord.from_json(read_run_file(self.run_record_file, holds, LAUNCH_FORMAT))

    def write_run_record(self, record: LaunchRecord) -> None:
        atomic_write_text(self.run_record_file, run_file_text(self.RUN_RECORD, record.to_json()))


def _decision(line: str) -> Decision | None:
    """One ``decisions.jsonl`` line as its kind of decision, or None for a line that is no
    decision record (not a JSON object, or of no known kind)."""
    try:
        record = json.loads(line)
        return Decision.from_json(record) if isinstance(record, dict) else None
    except ValueError:
        return None
