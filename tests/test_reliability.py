"""Nothing lost, nothing silently wrong (issue 17): hispo-pl under kills, bad input and
untrusted files. Each test is one probe of the issue; the kill tests use real subprocesses
and SIGKILL. Budgets are tiny: a few steps, a few episodes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from helpers import ROOT, fit_tiny_stream, tiny_stream_args

from hispo_pl.cli import main
from hispo_pl.config import BackboneConfig
from hispo_pl.errors import TrainingDivergedError

pytestmark = pytest.mark.usefixtures("one_thread")

TINY_HISPO = """
model:
  class_path: hispo_pl.modules.HiSPO
  init_args: {backbone: {high_hidden: 8, low_hidden: 16, high_log_std: 0.0}}
trainer:
  callbacks:
    - class_path: hispo_pl.callbacks.AnchorExtension
    - class_path: hispo_pl.callbacks.DirichletEvaluation
      init_args: {n_candidates: 8, n_batches: 1, survivors: null}
    - class_path: hispo_pl.callbacks.SubspacePruning
    - class_path: hispo_pl.callbacks.RolloutEvaluation
      init_args: {episodes: 2}
"""


def _run_dir(save_dir: Path) -> Path:
    return save_dir / "pointmaze-1" / "seed0"


def _cli(args: list[str], prelude: str = "") -> str:
    """Python source that runs ``hispo-pl`` with ``args`` after ``prelude`` (patches)."""
    return f"{prelude}\nimport sys\nfrom hispo_pl.cli import main\nsys.exit(main({args!r}))\n"


def _spawn(source: str) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(
        [sys.executable, "-c", source],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120) -> None:
    end = time.monotonic() + timeout
    while not path.exists():
        if proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"finished before {path.name} appeared:\n{out[-2000:]}\n{err[-3000:]}")
        if time.monotonic() > end:
            proc.kill()
            pytest.fail(f"{path} did not appear")
        time.sleep(0.02)


SLOW_STEPS = """
import time
from hispo_pl.modules.hbc import GoalConditionedBC
_step = GoalConditionedBC.training_step
def _slow(self, *args):
    time.sleep(0.05)
    return _step(self, *args)
GoalConditionedBC.training_step = _slow
"""


@pytest.fixture(scope="module")
def tiny_run(tiny_umaze, tmp_path_factory):
    """A finished two-task FTN stream (tiny budgets): results and run dir."""
    return fit_tiny_stream("ftn", tmp_path_factory.mktemp("tiny_run"))


# --- 1. data generate: a dataset cut short counts as missing --------------------------------


def test_data_generate_killed_while_minari_writes_is_rebuilt(tmp_path, monkeypatch, capsys):
    from hispo_pl.data.datasets import dataset_exists, load_episodes

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    marker = tmp_path / "written"
    # Minari writes the file, then (standing for a kill half-way through) the file is cut
    # short and the process is killed before it returns
    prelude = f"""
import os, pathlib, time, minari
_create = minari.create_dataset_from_buffers
def _create_then_hang(dataset_id, **kwargs):
    _create(dataset_id=dataset_id, **kwargs)
    from minari.storage import get_dataset_path
    data = pathlib.Path(get_dataset_path(dataset_id)) / "data" / "main_data.hdf5"
    with open(data, "r+b") as f:
        f.truncate(os.path.getsize(data) // 3)
    pathlib.Path({str(marker)!r}).touch()
    time.sleep(600)
minari.create_dataset_from_buffers = _create_then_hang
"""
    proc = _spawn(_cli(["data", "generate", "pointmaze-umaze", "--episodes", "2"], prelude))
    _wait_for(marker, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()

    assert not dataset_exists("hispo/pointmaze-umaze-expert-v0")
    assert main(["data", "list"]) == 0
    assert '"id"' not in capsys.readouterr().out  # nothing listed as if it were whole
    assert main(["data", "generate", "pointmaze-umaze", "--episodes", "2"]) == 0
    assert json.loads(capsys.readouterr().out)["episodes"] == 2
    assert load_episodes("pointmaze-umaze-N[2]", generate_if_missing=False).n_episodes == 2
    assert not list((tmp_path / ".staging").glob("*")), "staging left behind"


def test_truncated_dataset_counts_as_missing_and_is_rebuilt(tmp_path, monkeypatch, capsys):
    from hispo_pl.data.datasets import dataset_path, dataset_problem
    from hispo_pl.data.generation import generate_dataset

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    dataset_id = generate_dataset("pointmaze-umaze", episodes=2, progress=False)
    data = dataset_path(dataset_id) / "data" / "main_data.hdf5"
    data.write_bytes(data.read_bytes()[:3000])
    assert dataset_problem(dataset_id).startswith("incomplete")
    assert main(["data", "list"]) == 0
    captured = capsys.readouterr()
    assert '"episodes"' not in captured.out and "counts as missing" in captured.err
    assert main(["data", "generate", "pointmaze-umaze", "--episodes", "2"]) == 0
    assert dataset_problem(dataset_id) is None
    (tmp_path / "hispo" / "pointmaze-umaze-expert-v0" / "data" / "main_data.hdf5").unlink()
    assert dataset_problem(dataset_id) == "incomplete: no episode data"


# --- 2. untrusted checkpoints -----------------------------------------------------------------


def test_checkpoint_class_string_is_never_imported(tmp_path, monkeypatch, capsys):
    planted = tmp_path / "planted_module.py"
    ran = tmp_path / "ran"
    planted.write_text(f"open({str(ran)!r}, 'w').close()\nclass X: pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    ckpt = tmp_path / "crafted.ckpt"
    torch.save({"hispo_pl_class": "planted_module.X", "state_dict": {}}, ckpt)
    assert main(["evaluate", "--ckpt", str(ckpt), "--task", "pointmaze-umaze"]) == 2
    assert not ran.exists(), "the checkpoint made hispo-pl import a module"
    err = capsys.readouterr().err
    assert "not a readable hispo-pl checkpoint" in err and "planted_module.X" in err


def test_corrupt_truncated_and_unsafe_checkpoints_get_one_line(tiny_run, tmp_path, capsys):
    good = (tiny_run[1] / "task_02.ckpt").read_bytes()
    (tmp_path / "truncated.ckpt").write_bytes(good[: len(good) // 2])
    (tmp_path / "garbage.ckpt").write_bytes(b"not a checkpoint at all")

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {tmp_path / 'pwned'}",))

    torch.save({"state_dict": {}, "x": Payload()}, tmp_path / "unsafe.ckpt")
    for name in ("truncated", "garbage", "unsafe"):
        path = tmp_path / f"{name}.ckpt"
        assert main(["evaluate", "--ckpt", str(path), "--task", "pointmaze-umaze"]) == 2, name
        err = capsys.readouterr().err.strip()
        assert err.startswith("hispo-pl evaluate: error: not a readable hispo-pl checkpoint")
        assert len(err.splitlines()) == 1, err
        assert "weights_only" not in err and "Traceback" not in err
    assert not (tmp_path / "pwned").exists()


# --- 3. non-finite training -------------------------------------------------------------------


def test_nan_training_stops_with_step_and_lr_and_saves_nothing(tiny_umaze, tmp_path, capsys):
    args = tiny_stream_args(
        "ftn", tmp_path, ["pointmaze-umaze-N[3]"], "--model.init_args.optim.lr", "1e12"
    )
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "training diverged" in err and "at step" in err and "learning rate" in err
    assert "--model.init_args.optim.lr" in err and "Traceback" not in err
    run_dir = _run_dir(tmp_path)
    assert not list(run_dir.glob("*.ckpt")) and not (run_dir / "results.json").exists()


def test_a_non_finite_state_is_never_saved(tmp_path):
    import lightning as L

    from hispo_pl.modules.hbc import HBC

    module = HBC(obs_dim=4, action_dim=2, backbone=BackboneConfig(high_hidden=8, low_hidden=8))
    with torch.no_grad():
        next(module.parameters())[0] = float("nan")
    trainer = L.Trainer(logger=False, enable_checkpointing=False, enable_progress_bar=False)
    trainer.strategy.connect(module)
    with pytest.raises(TrainingDivergedError, match="NaN or infinite"):
        trainer.save_checkpoint(tmp_path / "nan.ckpt")
    assert not (tmp_path / "nan.ckpt").exists()


# --- 6. every value checked before anything trains -------------------------------------------


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["--data.batch_size", "0"], "data.batch_size = 0"),
        (["--trainer.max_steps", "0"], "trainer.max_steps = 0"),
        (["--model.init_args.backbone.dropout", "1.0"], "model.init_args.backbone.dropout = 1.0"),
        (["--trainer.callbacks.init_args.episodes", "0"], "init_args.episodes = 0"),
        (["--ckpt_path", "some.ckpt"], "a stream resumes by itself"),
        (["--checkpoint_every", "-1"], "checkpoint_every = -1"),
        (["--data.holdout", "1.5"], "data.holdout = 1.5"),
    ],
    ids=["batch0", "steps0", "dropout1", "episodes0", "ckpt_path", "checkpoint_every", "holdout"],
)
def test_invalid_values_are_refused_before_training(tmp_path, monkeypatch, capsys, extra, named):
    (tmp_path / "some.ckpt").write_bytes(b"")
    monkeypatch.chdir(tmp_path)
    assert main(tiny_stream_args("ftn", tmp_path / "runs", ["pointmaze-umaze-N[3]"], *extra)) == 2
    err = capsys.readouterr().err
    assert named in err and "Traceback" not in err
    assert not list((tmp_path / "runs").rglob("*.ckpt")) and not list(tmp_path.rglob("*.json"))


def test_negative_eps_is_refused_before_the_first_task(tmp_path, capsys):
    config = tmp_path / "hispo.yaml"
    config.write_text(
        TINY_HISPO.replace("SubspacePruning", "SubspacePruning\n      init_args: {eps_low: -0.5}")
    )
    assert main(tiny_stream_args(config, tmp_path)) == 2
    assert "eps_low = -0.5: must be >= 0" in capsys.readouterr().err
    assert not list(tmp_path.rglob("*.ckpt"))


def test_as_task_and_episodes_out_of_range(tiny_run, capsys):
    ckpt = str(tiny_run[1] / "task_02.ckpt")
    for extra in (["--as-task", "3"], ["--as-task", "0"], ["--episodes", "0"]):
        with pytest.raises(SystemExit) as done:
            main(["evaluate", "--ckpt", ckpt, "--task", "pointmaze-umaze", *extra])
        assert done.value.code == 2
        err = capsys.readouterr().err
        assert ("tasks 1..2" in err) if "--as-task" in extra else ("--episodes must be" in err)
    with pytest.raises(SystemExit) as done:
        main(["data", "generate", "pointmaze-umaze", "--episodes", "0"])
    assert done.value.code == 2


# --- 7. user errors: one paragraph, exit 2; Ctrl-C says how to resume ------------------------


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (tiny_stream_args("ftn", Path("unused"), ["pointmaze-umaz-N[3]"]), "task spec grammar"),
        ([*tiny_stream_args("ftn", Path("unused")), "--data.stream", "pointmaze-9"], "unknown"),
        (["evaluate", "--ckpt", __file__, "--task", "pointmaze-umaz"], "--task: unknown maze"),
    ],
    ids=["task-spec", "stream", "evaluate-task"],
)
def test_user_errors_are_one_paragraph_and_exit_2(argv, said, capsys):
    try:
        code = main(argv)
    except SystemExit as done:  # argparse's own usage errors
        code = done.value.code if hasattr(done, "value") else done.code
    assert code == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_or_kill_says_how_to_resume(tiny_umaze, tmp_path, sig):
    args = tiny_stream_args("ftn", tmp_path, ["pointmaze-umaze-N[3]"], "--trainer.max_steps", "400")
    proc = _spawn(_cli([*args, "--checkpoint_every", "5"], SLOW_STEPS))
    _wait_for(_run_dir(tmp_path) / "task_01.partial.ckpt", proc)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + sig, err[-3000:]
    assert "interrupted during task 1 of 1" in err and "Rerun the same command to resume" in err
    assert "Traceback" not in err


SLOW_ROLLOUTS = """
import time, pathlib
from hispo_pl.evaluation import RolloutEvaluator
def _slow(self, *args, **kwargs):
    pathlib.Path("{marker}").touch()
    time.sleep(60)
RolloutEvaluator.run = _slow
"""


def test_kill_outside_a_training_step_stops_the_stream(tiny_umaze, tmp_path):
    """Lightning only notes a SIGTERM during its training steps; one that arrives while the
    task-end callbacks roll out must stop the stream all the same."""
    marker = tmp_path / "rolling_out"
    args = tiny_stream_args("ftn", tmp_path, ["pointmaze-umaze-N[3]"], "--trainer.max_steps", "2")
    proc = _spawn(_cli(args, SLOW_ROLLOUTS.format(marker=marker)))
    _wait_for(marker, proc)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signal.SIGTERM, err[-3000:]
    assert "Rerun the same command to resume" in err and "Traceback" not in err


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
    from hispo_pl.loop import RunDirLock

    results, run_dir = tiny_run
    args = tiny_stream_args(
        "ftn", run_dir.parents[1], ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
    )
    with RunDirLock(run_dir):
        assert main(args) == 2
    err = capsys.readouterr().err
    assert "is in use by another run" in err and f"pid {os.getpid()}" in err
    assert main(args) == 0  # released


def test_kill_after_decisions_before_progress_keeps_one_record_per_task(tiny_umaze, tmp_path):
    config = tmp_path / "hispo.yaml"
    config.write_text(TINY_HISPO)
    args = tiny_stream_args(config, tmp_path)
    prelude = """
import os, signal
from hispo_pl.loop import ContinualLoop
_save = ContinualLoop._save_progress
def _killed_at_first_task_end(self, progress):
    if len(progress["rows"]) == 1:  # task 1's decisions are written, its progress is not
        os.kill(os.getpid(), signal.SIGKILL)
    _save(self, progress)
ContinualLoop._save_progress = _killed_at_first_task_end
"""
    proc = _spawn(_cli(args, prelude))
    proc.communicate(timeout=300)
    assert proc.returncode == -signal.SIGKILL
    decisions = _run_dir(tmp_path) / "decisions.jsonl"
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


def test_killed_inside_a_task_resumes_there_and_ends_identical(tiny_umaze, tmp_path, capsys):
    stream = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
    extra = ["--trainer.max_steps", "24", "--checkpoint_every", "5", "--data.steps_per_epoch", "7"]
    whole = fit_tiny_stream("ftn", tmp_path / "whole", stream, *extra)[0]

    killed = tmp_path / "killed"
    proc = _spawn(_cli(tiny_stream_args("ftn", killed, stream, *extra), SLOW_STEPS))
    _wait_for(_run_dir(killed) / "task_02.partial.ckpt", proc)
    time.sleep(0.3)  # a few steps past the checkpoint: they are lost and retrained
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (_run_dir(killed) / "results.json").exists()

    capsys.readouterr()
    resumed = fit_tiny_stream("ftn", killed, stream, *extra)[0]
    assert "resuming task 2 from task_02.partial.ckpt" in capsys.readouterr().out
    for key in ("R", "PER", "BWT", "stored_bytes"):
        assert resumed[key] == whole[key], key
    a = torch.load(_run_dir(tmp_path / "whole") / "task_02.ckpt", weights_only=True)
    b = torch.load(_run_dir(killed) / "task_02.ckpt", weights_only=True)
    for name, tensor in a["state_dict"].items():
        assert torch.equal(b["state_dict"][name], tensor), name
    assert not list(_run_dir(killed).glob("*.partial.ckpt"))


# --- 8. benchmark -----------------------------------------------------------------------------


def test_benchmark_lists_a_failed_method_in_the_table(tmp_path):
    from hispo_pl.benchmark import PlannedRun, Reporter, write_report

    out = tmp_path / "bench"
    good = out / "runs" / "ftn" / "seed0"
    good.mkdir(parents=True)
    R = [[0.5, None], [0.5, 0.25]]
    (good / "results.json").write_text(json.dumps({"R": R, "wall_time_s": [1, 1]}))
    bad = PlannedRun("broken", 0, out / "runs" / "broken" / "seed0", ("-m", "x"))
    bad.run_dir.mkdir(parents=True)
    (bad.run_dir / "run.json").write_text(json.dumps({"method": "broken", "seed": 0}))
    reporter = Reporter(total=2)
    reporter(bad, {"returncode": 2, "results": None, "log_tail": "boom"})
    reporter.close()
    write_report(out, "pointmaze-1")
    table = (out / "table.md").read_text()
    assert "| broken | 0 | failed (exit 2)" in table and "| ftn |" in table


def test_killing_the_benchmark_stops_its_runs(tiny_umaze, tmp_path):
    """``kill`` of the benchmark stops the fits it launched (they are not left running), and
    each says how to resume."""
    out = tmp_path / "bench"
    overrides = [
        "--data.stream", '["pointmaze-umaze-N[3]"]', "--trainer.max_steps", "1000000",
        "--data.batch_size", "64", "--trainer.callbacks.init_args.episodes", "2",
    ]  # fmt: skip
    args = ["benchmark", "--stream", "pointmaze-1", "--methods", "ftn", "--seeds", "0,"]
    proc = _spawn(_cli([*args, "--workers", "1", "--out", str(out), "--", *overrides]))
    lock = out / "runs" / "ftn" / "seed0" / "run.lock"
    _wait_for(lock, proc)
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
