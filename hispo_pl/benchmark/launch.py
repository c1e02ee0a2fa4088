"""Launching the runs: local worker processes or Ray remote tasks, each a ``hispo-pl fit``
subprocess; a progress bar and a line per finished run."""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from ..io import named_errors, open_append
from ..progress import ProgressPrinter
from ..rundir import RunDir
from .plan import PlannedRun

TAIL_LINES = 25


def _tail(path: Path, lines: int = TAIL_LINES) -> str:
    if not Path(path).exists():
        return ""
    return "\n".join(Path(path).read_text(errors="replace").splitlines()[-lines:])


def execute_run(
    argv: Sequence[str],
    log_path: str,
    results_path: str,
    env: dict[str, str] | None = None,
    on_start: Callable[[subprocess.Popen], None] | None = None,
) -> dict:
    """Run ``python <argv>`` with this interpreter, stdout and stderr appended to
    ``log_path``; return ``returncode``, ``results`` (the ``results.json`` dict, None on
    failure), ``log_tail`` and ``seconds``. The Ray launcher runs this on its workers."""
    log = Path(log_path)
    log.parent.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, *argv]
    start = time.perf_counter()
    with named_errors(log), open_append(log) as f:
        f.write(f"=== {time.strftime('%Y-%m-%d %H:%M:%S')} {shlex.join(command)}\n")
        f.flush()
        proc = subprocess.Popen(
            command, stdout=f, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})}
        )
        if on_start is not None:
            on_start(proc)
        returncode = proc.wait()
    results = None
    if returncode == 0 and Path(results_path).exists():
        results = json.loads(Path(results_path).read_text())
    return {
        "returncode": returncode,
        "results": results,
        "log_tail": "" if results is not None else _tail(log),
        "seconds": time.perf_counter() - start,
    }


def run_env(num_threads: int) -> dict[str, str]:
    """Environment for each run: unbuffered output (the log tail is current) and OpenMP
    threads matching ``--num-threads``; the Minari store path travels to Ray workers."""
    env = {"PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": str(num_threads)}
    if "MINARI_DATASETS_PATH" in os.environ:
        env["MINARI_DATASETS_PATH"] = os.environ["MINARI_DATASETS_PATH"]
    return env


class Reporter:
    """Progress over runs (skipped ones count as done: a bar on a terminal, a line at each
    tenth in a log, :class:`~hispo_pl.progress.ProgressPrinter`) and a printed line per finished or
    failed run; a failure shows its log path and the tail of the log."""

    def __init__(self, total: int, done: int = 0) -> None:
        self.bar = ProgressPrinter("benchmark", total, "runs")
        self.bar.update(done)
        self._write = self.bar.write
        self.failed: list[PlannedRun] = []

    def __call__(self, run: PlannedRun, outcome: dict) -> None:
        results = outcome["results"]
        if results is not None:
            minutes = sum(results.get("wall_time_s", [])) / 60
            self._write(
                f"[benchmark] {run.method} seed {run.seed}: PER {100 * results['PER']:.1f}  "
                f"{minutes:.1f} min"
            )
        else:
            self.failed.append(run)
            why = f"exit {outcome['returncode']}" + (
                f", no {run.results_path.name}" if outcome["returncode"] == 0 else ""
            )
            record_status(run, f"failed ({why}); log: {run.log_path}")
            tail = "\n".join("    " + line for line in outcome["log_tail"].splitlines())
            self._write(
                f"[benchmark] FAILED {run.method} seed {run.seed} ({why}); log: {run.log_path}\n"
                f"{tail}"
            )
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()


def record_status(run: PlannedRun, status: str) -> None:
    """Note a run's outcome in its ``run.json`` (the tables list failed runs with it)."""
    run_dir = RunDir(run.run_dir)
    with contextlib.suppress(OSError, ValueError):  # a convenience; the log says the rest
        run_dir.write_run_record(run_dir.read_run_record().replace(status=status))


def run_local(
    runs: Sequence[PlannedRun],
    workers: int,
    report: Callable[[PlannedRun, dict], None],
    env: dict[str, str] | None = None,
) -> None:
    """Each run as a subprocess, ``workers`` at a time; on Ctrl-C the live runs are
    terminated (a rerun resumes them)."""
    live: set[subprocess.Popen] = set()
    lock = threading.Lock()

    def start(proc: subprocess.Popen) -> None:
        with lock:
            live.add(proc)

    def job(run: PlannedRun) -> dict:
        return execute_run(run.argv, str(run.log_path), str(run.results_path), env, start)

    pool = ThreadPoolExecutor(max_workers=max(1, workers))
    try:
        futures = {pool.submit(job, run): run for run in runs}
        for future in as_completed(futures):
            run = futures[future]
            try:
                outcome = future.result()
            except Exception as e:  # the launch itself failed (e.g. the log is unwritable)
                outcome = {"returncode": -1, "results": None, "log_tail": repr(e)}
            report(run, outcome)
    except KeyboardInterrupt:
        with lock:
            for proc in live:
                proc.terminate()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def run_ray(
    runs: Sequence[PlannedRun],
    num_threads: int,
    report: Callable[[PlannedRun, dict], None],
    address: str | None = None,
    local_cpus: int | None = None,
    env: dict[str, str] | None = None,
) -> None:
    """Each run as a Ray remote task of ``num_threads`` CPUs (Ray schedules them) running the
    same ``fit`` subprocess on a worker. ``address``: ``local`` starts a private instance of
    ``local_cpus`` CPUs, ``auto`` / ``ray://host:10001`` joins a cluster, None lets Ray decide
    (``RAY_ADDRESS``, else local). Workers need the repository, the package and the data at
    the same paths as here (a shared filesystem). A run's ``results.json`` comes back with
    the task and is written here too if the worker's file is not visible.
    """
    try:
        import ray
    except ImportError:
        raise SystemExit(
            "the ray launcher needs Ray: pip install 'hispo-pl[ray]' (or 'ray>=2.9')"
        ) from None
    started = not ray.is_initialized()
    if started:
        options: dict = {"log_to_driver": False}
        if address == "local":
            options.update(include_dashboard=False, num_cpus=local_cpus)
        ray.init(address=address, **options)
    task = ray.remote(num_cpus=num_threads)(execute_run)
    pending = {
        task.remote(list(run.argv), str(run.log_path), str(run.results_path), env): run
        for run in runs
    }
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            run = pending.pop(done[0])
            try:
                outcome = ray.get(done[0])
            except Exception as e:  # the task or its worker died
                outcome = {"returncode": -1, "results": None, "log_tail": f"{e}"}
            if outcome["results"] is not None and not run.results_path.exists():
                run.run_dir.mkdir(parents=True, exist_ok=True)
                run.write_results(outcome["results"])
            report(run, outcome)
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()
