"""Nothing lost under kills, continued from test_reliability.py: the run directory's
integrity, resuming inside a task, and the benchmark under a failed method or a kill. Real
subprocesses and SIGKILL; tiny budgets."""

from __future__ import annotations

import json
import os
import signal
import time

import pytest
import torch
from helpers import ROOT, fit_tiny_stream, tiny_stream_args, write_run_files
from probes import SLOW_STEPS, TINY_HISPO, cli_source, spawn, stream_dir, wait_for

from hispo_pl.cli import main

# --- 4. run directory integrity ---------------------------------------------------------------


def test_resume_with_other_settings_is_refused_naming_the_keys(tiny_run, capsys):
    results, run_dir = tiny_run
    config = (run_dir / "task_01.config.yaml").read_text()
    args = tiny_stream_args(
        "ftn", run_dir.parents[1], ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
    )
    dropout = "model.init_args.backbone.dropout"
    assert main([*args, "--trainer.max_steps", "7", f"--{dropout}", "0.2"]) == 2
    err = capsys.readouterr().err
    assert "trainer.max_steps: 5 -> 7" in err and f"{dropout}: 0.1 -> 0.2" in err
    assert (run_dir / "task_01.config.yaml").read_text() == config  # each task's config kept
    assert (run_dir / "task_02.config.yaml").exists()
    # settings that do not change what is trained may differ
    assert main([*args, "--num_threads", "2", "--trainer.log_every_n_steps", "3"]) == 0
    assert json.loads((run_dir / "results.json").read_text())["R"] == results["R"]


def test_a_second_run_on_the_same_directory_names_the_holder(tiny_run, capsys):
    from hispo_pl.resume import RunDirLock

    results, run_dir = tiny_run
    args = tiny_stream_args(
        "ftn", run_dir.parents[1], ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
    )
    with RunDirLock(run_dir):
        assert main(args) == 2
    err = capsys.readouterr().err
    assert "is in use by another run" in err and f"pid {os.getpid()}" in err
    assert main(args) == 0  # released


@pytest.mark.e2e
def test_kill_after_decisions_before_progress_keeps_one_record_per_task(tiny_umaze, tmp_path):
    config = tmp_path / "hispo.yaml"
    config.write_text(TINY_HISPO)
    args = tiny_stream_args(config, tmp_path)
    prelude = """
import os, signal
from hispo_pl.rundir import RunDir
_save = RunDir.write_progress
def _killed_at_first_task_end(self, progress):
    if len(progress.rows) == 1:  # task 1's decisions are written, its progress is not
        os.kill(os.getpid(), signal.SIGKILL)
    _save(self, progress)
RunDir.write_progress = _killed_at_first_task_end
"""
    proc = spawn(cli_source(args, prelude))
    proc.communicate(timeout=300)
    assert proc.returncode == -signal.SIGKILL
    decisions = stream_dir(tmp_path) / "decisions.jsonl"
    assert {json.loads(line)["task"] for line in decisions.read_text().splitlines()} == {0}
    assert main(args) == 0
    records = [json.loads(line) for line in decisions.read_text().splitlines()]
    keys = [(r["task"], r["subspace"]) for r in records]
    assert sorted(keys) == sorted({(t, s) for t in (0, 1) for s in ("high", "low")})


def test_results_and_progress_are_written_atomically(tiny_run, monkeypatch):
    import hispo_pl.io

    results, run_dir = tiny_run
    before = (run_dir / "results.json").read_text()

    def fail(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(hispo_pl.io.os, "replace", fail)
    args = tiny_stream_args(
        "ftn", run_dir.parents[1], ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
    )
    with pytest.raises(OSError, match="disk full"):
        main(args)
    assert (run_dir / "results.json").read_text() == before
    assert not [p for p in run_dir.iterdir() if p.name.endswith(".tmp")]


# --- 5. resume inside a task ------------------------------------------------------------------


@pytest.mark.e2e
def test_killed_inside_a_task_resumes_there_and_ends_identical(tiny_umaze, tmp_path, capsys):
    """A resume promises the uninterrupted run bit for bit in the same environment: the killed
    child ran on this machine with this process's kernels and one thread (``probes.spawn`` sets
    OMP_NUM_THREADS=1)."""
    stream = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
    extra = ["--trainer.max_steps", "24", "--checkpoint_every", "5", "--data.steps_per_epoch", "7"]
    whole = fit_tiny_stream("ftn", tmp_path / "whole", stream, *extra)[0]

    killed = tmp_path / "killed"
    proc = spawn(cli_source(tiny_stream_args("ftn", killed, stream, *extra), SLOW_STEPS))
    wait_for(stream_dir(killed) / "task_02.partial.ckpt", proc)
    time.sleep(0.3)  # a few steps past the checkpoint: they are lost and retrained
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (stream_dir(killed) / "results.json").exists()
    saved = torch.load(stream_dir(killed) / "task_02.partial.ckpt", weights_only=True)
    before = saved["callbacks"]["TaskCheckpoint"]["seconds"]  # task 2's time in the killed child
    assert before > 0

    capsys.readouterr()
    started = time.perf_counter()
    resumed = fit_tiny_stream("ftn", killed, stream, *extra)[0]
    assert "resuming task 2 from task_02.partial.ckpt" in capsys.readouterr().out
    # its wall time counts the killed child's part as well as this process's
    assert before < resumed["wall_time_s"][1] <= before + time.perf_counter() - started
    assert resumed["phase_time_s"][1]["training"] > before
    for key in ("R", "PER", "BWT", "stored_bytes"):
        assert resumed[key] == whole[key], key
    a = torch.load(stream_dir(tmp_path / "whole") / "task_02.ckpt", weights_only=True)
    b = torch.load(stream_dir(killed) / "task_02.ckpt", weights_only=True)
    for name, tensor in a["state_dict"].items():
        assert torch.equal(b["state_dict"][name], tensor), name
    assert not list(stream_dir(killed).glob("*.partial.ckpt"))


# --- 8. benchmark -----------------------------------------------------------------------------


def test_benchmark_lists_a_failed_method_in_the_table(tmp_path):
    from hispo_pl.benchmark import PlannedRun, Reporter, write_report

    out = tmp_path / "bench"
    R = [[0.5, None], [0.5, 0.25]]
    results = {
        "stream": ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"],
        "R": R,
        "wall_time_s": [1, 1],
    }
    write_run_files(out / "runs" / "ftn" / "seed0", results)
    bad = PlannedRun("broken", 0, out / "runs" / "broken" / "seed0", ("-m", "x"))
    write_run_files(bad.run_dir, launch={"method": "broken", "seed": 0})
    reporter = Reporter(total=2)
    reporter(bad, {"returncode": 2, "results": None, "log_tail": "boom"})
    reporter.close()
    write_report(out, "pointmaze-1")
    table = (out / "table.md").read_text()
    assert "| broken | 0 | failed (exit 2)" in table and "| ftn |" in table


@pytest.mark.e2e
def test_killing_the_benchmark_stops_its_runs(tiny_umaze, tmp_path):
    """``kill`` of the benchmark stops the fits it launched (they are not left running), and
    each says how to resume."""
    out = tmp_path / "bench"
    overrides = [
        "--data.stream", '["pointmaze-umaze-N[3]"]', "--trainer.max_steps", "1000000",
        "--data.batch_size", "64", "--trainer.callbacks.init_args.episodes", "2",
    ]  # fmt: skip
    args = ["benchmark", "--stream", "pointmaze-1", "--methods", "ftn", "--seeds", "0,"]
    proc = spawn(cli_source([*args, "--workers", "1", "--out", str(out), "--", *overrides]))
    lock = out / "runs" / "ftn" / "seed0" / "run.lock"
    wait_for(lock, proc)
    end = time.monotonic() + 60
    while "pid" not in lock.read_text() and time.monotonic() < end:
        time.sleep(0.05)
    fit_pid = int(lock.read_text().split()[1])
    time.sleep(1.0)  # let the fit reach its training steps
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err[-3000:]
    with pytest.raises(ProcessLookupError):
        os.kill(fit_pid, 0)
    log = (out / "runs" / "ftn" / "seed0" / "fit.log").read_text()
    assert "Rerun the same command to resume" in log


def test_benchmark_dry_run_validates_the_overrides(tmp_path, capsys):
    from hispo_pl.benchmark import main as benchmark_main

    common = ["--stream", "pointmaze-1", "--methods", "ftn", "--seeds", "1", "--out", str(tmp_path)]
    common += ["--config-dir", str(ROOT / "configs")]
    assert benchmark_main([*common, "--dry-run", "--", "--trainer.max_stepz", "5"]) == 2
    assert "max_stepz" in capsys.readouterr().err
    dropout = "--model.init_args.backbone.dropout"
    assert benchmark_main([*common, "--dry-run", "--", dropout, "2"]) == 2
    assert "model.init_args.backbone.dropout = 2" in capsys.readouterr().err
    assert benchmark_main([*common, "--dry-run", "--", "--trainer.max_steps", "5"]) == 0
    assert not list(tmp_path.iterdir())


# --- 9. the benchmark's fits import no code from the working folder --------------------------


@pytest.mark.e2e
def test_a_fit_the_benchmark_launches_never_imports_from_the_working_folder(tmp_path, monkeypatch):
    """``python -m`` puts the working folder on the import path; a config naming a module
    there must not run it, unless the user puts the folder there (PYTHONPATH=.)."""
    from hispo_pl.benchmark.launch import execute_run
    from hispo_pl.benchmark.plan import plan_run

    marker = tmp_path / "ran"
    (tmp_path / "evil.py").write_text(f"open({str(marker)!r}, 'w').close()\nclass Thing: pass\n")
    method = tmp_path / "evil.yaml"
    method.write_text("model:\n  class_path: evil.Thing\n")
    monkeypatch.chdir(tmp_path)
    stream = ROOT / "configs" / "streams" / "pointmaze-1.yaml"
    run = plan_run(stream, method, "evil", 0, tmp_path / "out")
    outcome = execute_run(run.argv, str(run.log_path), str(run.results_path))
    log = run.log_path.read_text()
    assert outcome["returncode"] == 2, log
    assert "evil.Thing: no module evil on the import path" in log and "Traceback" not in log
    assert not marker.exists(), "a module of the working folder was imported"
    # asked for, the folder is searched: the same launch imports it (and refuses the class)
    execute_run(run.argv, str(run.log_path), str(run.results_path), {"PYTHONPATH": "."})
    assert marker.exists()
