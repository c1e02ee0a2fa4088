"""Nothing lost, nothing silently wrong: hispo-pl under kills, bad input and untrusted
files. Each test probes one way a run could lose work or accept a wrong file; the kill tests
use real subprocesses and SIGKILL. Budgets are tiny: a few steps, a few episodes."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import TINY_STREAM, error_lines, tiny_stream_args, write_run_files
from probes import SLOW_STEPS, TINY_HISPO, cli_source, spawn, stream_dir, wait_for

from hispo_pl.cli import main
from hispo_pl.config import BackboneConfig
from hispo_pl.errors import TrainingDivergedError
from hispo_pl.results import PROGRESS_KEYS, StreamResults
from hispo_pl.run_files import run_file_text
from hispo_pl.rundir import RunDir

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
    proc = spawn(cli_source(["data", "generate", "pointmaze-umaze", "--episodes", "2"], prelude))
    wait_for(marker, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()

    assert not dataset_exists("hispo/pointmaze-umaze-expert-v0")
    assert main(["data", "list"]) == 0
    assert '"id"' not in capsys.readouterr().out  # nothing listed as if it were whole
    assert main(["data", "generate", "pointmaze-umaze", "--episodes", "2"]) == 0
    assert json.loads(capsys.readouterr().out)["episodes"] == 2
    assert load_episodes("pointmaze-umaze-N[2]").n_episodes == 2
    assert not list((tmp_path / ".staging").glob("*")), "staging left behind"


def test_overwrite_killed_while_collecting_keeps_the_old_dataset(tmp_path, monkeypatch, capsys):
    from hispo_pl.data.datasets import dataset_problem, load_episodes

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert main(["data", "generate", "pointmaze-umaze", "--episodes", "2"]) == 0
    capsys.readouterr()
    marker = tmp_path / "collected"
    # the new episodes are collected, and the process is killed while Minari writes them
    prelude = f"""
import pathlib, time, minari
def _hang(**kwargs):
    pathlib.Path({str(marker)!r}).touch()
    time.sleep(600)
minari.create_dataset_from_buffers = _hang
"""
    argv = ["data", "generate", "pointmaze-umaze", "--episodes", "3", "--overwrite"]
    proc = spawn(cli_source(argv, prelude))
    wait_for(marker, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert dataset_problem("hispo/pointmaze-umaze-expert-v0") is None
    assert load_episodes("pointmaze-umaze-N[2]").n_episodes == 2
    assert main(["data", "generate", *argv[2:]]) == 0  # the rerun finishes the new one
    assert json.loads(capsys.readouterr().out)["episodes"] == 3
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


@pytest.mark.parametrize(
    "hparams",
    [
        {"_class_path": "planted_module.X", "lr": 1.0},
        {"_class_path": "hispo_pl.modules.HiSPO", "backbone": {"class_path": "planted_module.X"}},
    ],
    ids=["model", "nested"],
)
def test_fit_ckpt_path_never_imports_what_the_checkpoint_names(
    tmp_path, monkeypatch, capsys, hparams
):
    planted = tmp_path / "planted_module.py"
    ran = tmp_path / "ran"
    planted.write_text(f"open({str(ran)!r}, 'w').close()\nclass X: pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    ckpt = tmp_path / "crafted.ckpt"
    torch.save({"state_dict": {}, "hyper_parameters": hparams}, ckpt)
    config = str(Path(__file__).parents[2] / "configs" / "hbc" / "pointmaze-umaze.yaml")
    assert main(["fit", "--config", config, "--ckpt_path", str(ckpt)]) == 2
    assert not ran.exists(), "the checkpoint made hispo-pl import a module"
    err = capsys.readouterr().err.strip()
    assert "not a readable hispo-pl checkpoint" in err and "planted_module.X" in err
    assert len(err.splitlines()) == 1, err


def test_a_real_checkpoint_names_an_imported_method(tiny_run):
    from hispo_pl.modules import NetworkPerTask
    from hispo_pl.modules.checkpoints import read_checkpoint
    from hispo_pl.modules.hbc import checkpoint_model_hparams, imported_method

    path = tiny_run[1] / "task_02.ckpt"
    hparams = checkpoint_model_hparams(read_checkpoint(path), path)
    assert imported_method(hparams["class_path"]) is NetworkPerTask
    assert "_instantiator" not in hparams["dict_kwargs"] and "backbone" in hparams["dict_kwargs"]
    assert imported_method("os.path") is None and imported_method("torch.nn.Linear") is None


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
    run_dir = stream_dir(tmp_path)
    assert not list(run_dir.glob("*.ckpt")) and not (run_dir / "results.json").exists()


def test_non_finite_data_is_refused_when_it_loads(tmp_path, monkeypatch, capsys):
    import h5py

    from hispo_pl.data.datasets import DatasetValuesError, dataset_path, load_episodes
    from hispo_pl.data.generation import generate_dataset

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "data"))
    dataset_id = generate_dataset("pointmaze-umaze", episodes=3, progress=False)
    with h5py.File(dataset_path(dataset_id) / "data" / "main_data.hdf5", "r+") as f:
        f["episode_1/observations/observation"][7, 2] = np.nan
    with pytest.raises(DatasetValuesError, match=r"episode 1 holds 1 NaN .* in observation"):
        load_episodes("pointmaze-umaze-N[3]")
    assert main(tiny_stream_args("hispo", tmp_path / "runs", ["pointmaze-umaze-N[3]"])) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("hispo-pl: error: the data of hispo/pointmaze-umaze-expert-v0")
    assert "first at step 7" in err and "Traceback" not in err and "learning rate" not in err
    assert not list((tmp_path / "runs").rglob("*.ckpt"))


def test_a_non_finite_search_loss_stops_the_task(tiny_umaze, tmp_path, monkeypatch, capsys):
    from hispo_pl.callbacks import loss_search

    real = loss_search.race_subspace

    def nan_race(*args, **kwargs):
        outcome = real(*args, **kwargs)
        return loss_search.RaceOutcome(outcome.survivors, outcome.losses * np.nan, None)

    monkeypatch.setattr(loss_search, "race_subspace", nan_race)
    assert main(tiny_stream_args("hispo", tmp_path, ["pointmaze-umaze-N[3]"])) == 2
    err = capsys.readouterr().err.strip()
    assert "the search at the end of task 1 scored L_curr = nan" in err
    assert len(error_lines(err)) == 1 and "Traceback" not in err
    run_dir = stream_dir(tmp_path)
    assert not list(run_dir.glob("*.ckpt")) and not (run_dir / "results.json").exists()
    decisions = run_dir / "decisions.jsonl"
    assert not decisions.exists() or "NaN" not in decisions.read_text()


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
        assert main(["evaluate", "--ckpt", ckpt, "--task", "pointmaze-umaze", *extra]) == 2
        err = capsys.readouterr().err
        assert ("tasks 1..2" in err) if "--as-task" in extra else ("--episodes must be" in err)
    assert main(["data", "generate", "pointmaze-umaze", "--episodes", "0"]) == 2


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
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err


@pytest.mark.e2e
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_or_kill_says_how_to_resume(tiny_umaze, tmp_path, sig):
    args = tiny_stream_args("ftn", tmp_path, ["pointmaze-umaze-N[3]"], "--trainer.max_steps", "400")
    proc = spawn(cli_source([*args, "--checkpoint_every", "5"], SLOW_STEPS))
    wait_for(stream_dir(tmp_path) / "task_01.partial.ckpt", proc)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    assert "Exception ignored" not in err, err  # a stop a finaliser dropped
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


@pytest.mark.e2e
def test_kill_outside_a_training_step_stops_the_stream(tiny_umaze, tmp_path):
    """Lightning only notes a SIGTERM during its training steps; one that arrives while the
    task-end callbacks roll out must stop the stream all the same."""
    marker = tmp_path / "rolling_out"
    args = tiny_stream_args("ftn", tmp_path, ["pointmaze-umaze-N[3]"], "--trainer.max_steps", "2")
    proc = spawn(cli_source(args, SLOW_ROLLOUTS.format(marker=marker)))
    wait_for(marker, proc)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 128 + signal.SIGTERM, err[-3000:]
    assert "Rerun the same command to resume" in err and "Traceback" not in err


SWALLOWED = """
import pathlib, time
from hispo_pl.evaluation import RolloutEvaluator
_run = RolloutEvaluator.run
class _Finalised:
    def __del__(self):
        pathlib.Path("{marker}").touch()
        time.sleep(5)  # the stop arrives here: Python ignores the interrupt it raises
def _run_with_a_finaliser(self, *args, **kwargs):
    _Finalised()  # collected at once: its __del__ runs inside the task-end rollouts
    return _run(self, *args, **kwargs)
RolloutEvaluator.run = _run_with_a_finaliser
"""


@pytest.mark.e2e
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_swallowed_by_a_finaliser_still_stops_the_stream(tiny_umaze, tmp_path, sig):
    """A Ctrl-C's or a SIGTERM's KeyboardInterrupt raised inside ``__del__`` is dropped by
    Python, which would print "Exception ignored"; the stop request stays, is not printed as
    ignored, and stops the run (Lightning notes a SIGTERM only during its training steps, and
    the next task would forget it). test_reliability_signals.py sends it at random moments."""
    marker = tmp_path / "finalising"
    args = tiny_stream_args("ftn", tmp_path, TINY_STREAM, "--trainer.max_steps", "2")
    proc = spawn(cli_source(args, SWALLOWED.format(marker=marker)))
    wait_for(marker, proc)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    assert "Exception ignored" not in err and "Traceback" not in err
    assert proc.returncode == 128 + sig, err[-3000:]
    assert "interrupted during task 1 of 2" in err and "Rerun the same command to resume" in err
    assert not (stream_dir(tmp_path) / "results.json").exists()


# --- 5. the benchmark never mixes streams ---------------------------------------------------

PM1_TASKS = [
    "pointmaze-umaze-N[500]",
    "pointmaze-large-N[500]",
    "pointmaze-umaze-PO[500]",
    "pointmaze-medium-IO[500]",
]


def _finished_run(out: Path, method: str, seed: int, tasks: list[str], R=None, meta=True) -> Path:
    """A finished benchmark run on disk, as the benchmark leaves it."""
    run = out / "runs" / method / f"seed{seed}"
    run.mkdir(parents=True)
    n = len(tasks)
    R = R if R is not None else [[0.9 if j <= i else None for j in range(n)] for i in range(n)]
    launch = {"method": method, "seed": seed, "stream": "pointmaze-1"} if meta else None
    write_run_files(run, {"stream": tasks, "R": R, "MEM": 1.0}, launch)
    return run


@pytest.mark.parametrize("meta", [True, False], ids=["run.json", "results.json"])
def test_a_second_stream_into_one_out_is_refused_before_anything_is_written(tmp_path, capsys, meta):
    out = tmp_path / "out"
    run = _finished_run(out, "scn", 0, PM1_TASKS, meta=meta)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    configs = str(Path(__file__).parents[2] / "configs")
    argv = ["benchmark", "--stream", "pointmaze-2", "--methods", "scn", "--seeds", "1"]
    assert main([*argv, "--out", str(out), "--config-dir", configs]) == 2
    err = capsys.readouterr().err
    assert "holds runs of another stream: scn/seed0" in err and "its own --out" in err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert (run / "results.json").exists()


def test_an_export_over_another_streams_runs_is_refused_before_anything_is_written(
    tmp_path, capsys
):
    dest, configs = tmp_path / "dest", str(Path(__file__).parents[2] / "configs")
    first = tmp_path / "pm1"
    _finished_run(first, "scn", 0, PM1_TASKS)
    (first / "benchmark.json").write_text(json.dumps({"stream": "pointmaze-1"}))
    assert main(["benchmark", "--report-only", "--out", str(first), "--export", str(dest)]) == 0
    second = tmp_path / "pm2"
    run = _finished_run(second, "scn", 0, PM1_TASKS[:3])
    write_run_files(run, launch={"method": "scn", "seed": 0, "stream": "pm2"})
    (second / "benchmark.json").write_text(json.dumps({"stream": "pm2"}))
    capsys.readouterr()
    before = {p: p.read_bytes() for p in dest.rglob("*") if p.is_file()}
    assert main(["benchmark", "--report-only", "--out", str(second), "--export", str(dest)]) == 2
    err = capsys.readouterr().err.strip()
    assert "holds runs of another stream: scn/seed0 (pointmaze-1), benchmark.json" in err
    assert "its own --export" in err and len(err.splitlines()) == 1
    # a benchmark that would train first is refused before it starts
    argv = ["benchmark", "--stream", "pointmaze-2", "--methods", "scn", "--seeds", "1"]
    new = tmp_path / "new"
    assert main([*argv, "--out", str(new), "--export", str(dest), "--config-dir", configs]) == 2
    assert "scn/seed0 (pointmaze-1)" in capsys.readouterr().err and not new.exists()
    assert {p: p.read_bytes() for p in dest.rglob("*") if p.is_file()} == before


def test_results_that_do_not_fit_their_stream_are_listed_not_tabulated(tmp_path, capsys):
    _finished_run(tmp_path, "scn", 0, PM1_TASKS)
    _finished_run(tmp_path, "ftn", 0, PM1_TASKS, R=[[1.0]])  # 1x1 R: PER 100 if tabulated
    assert main(["benchmark", "--out", str(tmp_path), "--report-only"]) == 0
    table = (tmp_path / "table.md").read_text()
    assert "| scn |" in table.replace("**", "") and "| ftn |" not in table.replace("**", "")
    assert "Runs that could not be read" in table and "R has 1 rows for a stream of 4" in table
    assert "left out of the tables: ftn/seed0" in capsys.readouterr().out


def test_a_report_over_two_streams_is_refused(tmp_path, capsys):
    _finished_run(tmp_path, "scn", 0, PM1_TASKS)
    _finished_run(tmp_path, "ftn", 0, PM1_TASKS[:3])
    assert main(["benchmark", "--out", str(tmp_path), "--report-only"]) == 2
    err = capsys.readouterr().err
    assert "holds runs of different streams" in err and "Traceback" not in err


# --- 8. malformed run files: named, never a traceback ----------------------------------------


@pytest.mark.parametrize(
    "text, said",
    [
        ('{"format": 1}', "has no stream, rows"),
        ("[]", "JSON list, not an object"),
        ('{"format": 1, "stream": ["pointmaze-umaze-N[3]"]}', "has no rows"),
        (
            json.dumps(
                {"format": 1, **dict.fromkeys(PROGRESS_KEYS), "stream": ["pointmaze-umaze-N[3]"]}
            ),
            "has no list rows",
        ),
        ("{", "not readable JSON"),
    ],
    ids=["empty-object", "list", "no-rows", "null-rows", "cut"],
)
def test_a_malformed_progress_file_is_named_on_resume(tiny_umaze, tmp_path, capsys, text, said):
    run_dir = stream_dir(tmp_path)
    run_dir.mkdir(parents=True)
    (run_dir / "progress.json").write_text(text)
    assert main(tiny_stream_args("ftn", tmp_path, ["pointmaze-umaze-N[3]"])) == 2
    err = capsys.readouterr().err.strip()
    assert str(run_dir / "progress.json") in err and said in err, err
    assert "Traceback" not in err and (run_dir / "progress.json").read_text() == text


@pytest.mark.parametrize("text", ["garbage", "{}", "[1, 2]", '{"R": "x", "stream": []}'])
def test_malformed_results_are_listed_as_unreadable(tmp_path, capsys, text):
    _finished_run(tmp_path, "scn", 0, PM1_TASKS)
    bad = _finished_run(tmp_path, "ftn", 0, PM1_TASKS)
    (bad / "results.json").write_text(text)
    (bad.parent.parent / "scn" / "seed0" / "decisions.jsonl").write_text('[1]\n"x"\n{"task": 0}\n')
    assert main(["benchmark", "--out", str(tmp_path), "--report-only"]) == 0
    captured = capsys.readouterr()
    assert "left out of the tables: ftn/seed0" in captured.out and "Traceback" not in captured.err
    assert "Runs that could not be read" in (tmp_path / "table.md").read_text()


@pytest.mark.parametrize("value", ["-1e9", "NaN", "Infinity", "1.5", "true"])
def test_results_whose_R_is_no_success_rate_are_listed_as_unreadable(tmp_path, capsys, value):
    _finished_run(tmp_path, "scn", 0, PM1_TASKS)
    bad = _finished_run(tmp_path, "ftn", 0, PM1_TASKS)
    text = (bad / "results.json").read_text()
    (bad / "results.json").write_text(text.replace("0.9", value, 1))
    assert main(["benchmark", "--out", str(tmp_path), "--report-only"]) == 0
    assert "left out of the tables: ftn/seed0" in capsys.readouterr().out
    table = (tmp_path / "table.md").read_text()
    said = "R holds values that are not numbers" if value == "true" else "not a success rate"
    assert "| ftn |" not in table.replace("**", "") and said in table


# --- 6. too few episodes to hold one out -----------------------------------------------------


def test_one_episode_with_a_holdout_is_refused_with_the_numbers(tiny_umaze, tmp_path, capsys):
    for holdout in ("0.1", "0.6"):
        args = tiny_stream_args(
            "ftn", tmp_path, ["pointmaze-umaze-N[1]"], "--data.holdout", holdout
        )
        assert main(args) == 2
        err = capsys.readouterr().err.strip()
        assert (
            f"pointmaze-umaze-N[1] has 1 episode: --data.holdout {holdout} needs at least 2" in err
        )
        assert "Traceback" not in err and len(err.splitlines()) == 1
    # the refused runs trained nothing, so the corrected command starts in the same directory
    args = tiny_stream_args("ftn", tmp_path, ["pointmaze-umaze-N[1]"], "--data.holdout", "0")
    assert main(args) == 0  # decisions on the training data, as asked


# --- 10. smaller: configs that explode, run files others can read, leftovers ---------------


def test_a_config_whose_aliases_explode_is_refused_quickly(tmp_path, capsys):
    import time

    lines = ['a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for prev, name in zip("abcdefgh", "bcdefghi", strict=True):
        lines.append(f"{name}: &{name} [{', '.join([f'*{prev}'] * 9)}]")
    (tmp_path / "laughs.yaml").write_text("\n".join(lines) + "\n")
    start = time.monotonic()
    assert main(["fit", "--config", str(tmp_path / "laughs.yaml")]) == 2
    assert time.monotonic() - start < 10
    err = capsys.readouterr().err
    assert "its aliases expand to 490,329,064 YAML nodes" in err and "Traceback" not in err


def test_run_files_get_the_mode_of_any_new_file(tmp_path):
    from hispo_pl.io import atomic_write_text

    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "results.json", "{}")
        os.umask(0o002)
        atomic_write_text(tmp_path / "progress.json", "{}")
    finally:
        os.umask(old)
    assert (tmp_path / "results.json").stat().st_mode & 0o777 == 0o644
    assert (tmp_path / "progress.json").stat().st_mode & 0o777 == 0o664


def test_leftovers_of_interrupted_writes_are_removed_on_the_next_run(tiny_umaze, tmp_path):
    run_dir = stream_dir(tmp_path)
    run_dir.mkdir(parents=True)
    leftovers = [run_dir / ".progress.json.x1y2.tmp", run_dir / ".task_01.partial.ckpt.tmp"]
    for path in leftovers:
        path.write_bytes(b"cut short")
    assert main(tiny_stream_args("ftn", tmp_path, ["pointmaze-umaze-N[3]"])) == 0
    assert not any(p.exists() for p in leftovers)
    assert not list(run_dir.glob(".*tmp")) and (run_dir / "task_01.ckpt").exists()


@pytest.mark.parametrize(
    "content, said",
    [
        (None, "no such file"),
        ("garbage", "not readable JSON"),
        (
            run_file_text(
                RunDir.RESULTS,
                StreamResults(stream=["a", "b"], R=[[1.0, None], [0.5, 1.0]]).to_json(),
            ),
            "its stream has 2 tasks, this one 1",
        ),
    ],
    ids=["missing", "garbage", "other-stream"],
)
def test_scratch_results_are_checked_before_training(tiny_umaze, tmp_path, capsys, content, said):
    scratch = tmp_path / "scratch" / "results.json"
    if content is not None:
        scratch.parent.mkdir()
        scratch.write_text(content)
    args = tiny_stream_args(
        "ftn", tmp_path, ["pointmaze-umaze-N[3]"], "--scratch_results", str(scratch)
    )
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "--scratch_results" in err and said in err and "Traceback" not in err
    assert not list(stream_dir(tmp_path).glob("*.ckpt"))


# --- 7. the machine's errors: one paragraph naming the path, earlier work intact -------------


@pytest.fixture
def small_disk(tmp_path):
    """A 300 KB tmpfs (root only): too small for a task's checkpoint."""
    import subprocess

    disk = tmp_path / "disk"
    disk.mkdir()
    if os.getuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=300k", "tmpfs", str(disk)])
    if done.returncode != 0:
        pytest.skip("tmpfs cannot be mounted here")
    yield disk
    subprocess.run(["umount", "-l", str(disk)], check=False)


def test_a_full_disk_names_the_file_and_leaves_no_truncated_checkpoint(
    tiny_umaze, small_disk, capsys
):
    assert main(tiny_stream_args("ftn", small_disk / "runs")) == 2
    err = capsys.readouterr().err.strip()
    run_dir = stream_dir(small_disk / "runs")
    assert f"cannot use {run_dir / 'task_01.ckpt'}: no space is left" in err, err
    assert "rerun the same command to resume" in err and len(error_lines(err)) == 1
    assert not list(run_dir.glob("*.ckpt")) and not list(run_dir.glob(".*tmp"))
    assert json.loads((run_dir / "progress.json").read_text())["rows"] == []


def test_a_read_only_run_directory_is_one_paragraph(tiny_umaze, small_disk, capsys):
    import subprocess

    subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)
    assert main(tiny_stream_args("ftn", small_disk / "runs")) == 2
    err = capsys.readouterr().err.strip()
    assert "read-only file system" in err and str(small_disk) in err and "Traceback" not in err
    assert main(["render", "pointmaze-umaze", "--out", str(small_disk / "m.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"hispo-pl render: error: cannot use {small_disk / 'm.png'}")
    assert "resume" not in err


@pytest.mark.parametrize(
    "argv, said",
    [
        (["render", "pointmaze-umaze", "--out", "{tmp}/m.xyz"], "--out {tmp}/m.xyz: name an image"),
        (["render", "pointmaze-umaze", "--out", "{tmp}/file/m.png"], "a file is in the way"),
        (["render", "pointmaze-umaze", "--out", "{tmp}/" + "n" * 300 + ".png"], "too long"),
        (["config", "copy", "{tmp}/file"], "{tmp}/file is a file; config copy fills a folder"),
    ],
    ids=["render-extension", "render-file-in-the-way", "name-too-long", "config-copy"],
)
def test_paths_that_cannot_be_written_are_one_paragraph(tmp_path, capsys, argv, said):
    (tmp_path / "file").write_text("in the way")
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert said.replace("{tmp}", str(tmp_path)) in err and "Traceback" not in err
    assert (tmp_path / "file").read_text() == "in the way"


GRID_FILES = {
    "parts-list": "streams: [pointmaze-1]\nmethods: [scn]\nparts: [pointmaze-1]\n",
    "sweeps-list": "streams: [pointmaze-1]\nmethods: [l2]\nsweeps: [l2]\n",
    "extra-number": "streams: [pointmaze-1]\nmethods: [scn]\nextra: 5\n",
    "unknown-method": "streams: [pointmaze-1]\nmethods: [scnn]\n",
    "unknown-stream": "streams: [pointmaze-9]\nmethods: [scn]\n",
}


@pytest.mark.parametrize(
    "argv, said",
    [
        (["--grid", "paper", "--num-threads", "0"], "--num-threads: must be an integer"),
        (["--grid", "paper", "--workers", "0"], "argument --workers: must be an integer >= 1"),
        (["--grid", "{tmp}/parts-list.yaml"], "`parts` must be a mapping of part names"),
        (["--grid", "{tmp}/sweeps-list.yaml"], "`sweeps` must be a mapping of methods"),
        (["--grid", "{tmp}/extra-number.yaml"], "`extra` must be a list of fit arguments"),
        (["--grid", "{tmp}/unknown-method.yaml"], "unknown method(s) scnn; known"),
        (["--grid", "{tmp}/unknown-stream.yaml"], "stream pointmaze-9: no stream config"),
    ],
    ids=["threads0", "workers0", *GRID_FILES],
)
def test_benchmark_grid_user_errors_are_one_line(tmp_path, capsys, argv, said):
    for name, text in GRID_FILES.items():
        (tmp_path / f"{name}.yaml").write_text(text)
    work, root = tmp_path / "work", tmp_path / "root"
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    argv = ["benchmark", *args, "--out", str(work), "--export", str(root), "--dry-run"]
    assert main(argv) == 2  # a dry run: a check that lets a case through trains nothing
    err = capsys.readouterr().err.strip()
    assert said in err and len(err.splitlines()) == 1, err
    assert not work.exists() and not root.exists()


@pytest.mark.parametrize(
    "ckpt", ["{tmp}/missing.ckpt", "", "{tmp}"], ids=["missing", "empty", "dir"]
)
def test_fit_ckpt_path_that_is_no_file_is_one_line(tmp_path, capsys, ckpt):
    config = str(Path(__file__).parents[2] / "configs" / "hbc" / "pointmaze-umaze.yaml")
    path = ckpt.replace("{tmp}", str(tmp_path))
    args = ["fit", "--config", config, "--trainer.logger.init_args.save_dir", str(tmp_path)]
    assert main([*args, "--ckpt_path", path]) == 2
    err = capsys.readouterr().err.strip()
    assert f"--ckpt_path {path!r}: no such checkpoint file" in err and len(err.splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_a_corrupt_benchmark_json_is_one_line_and_nothing_is_written(tmp_path, capsys):
    _finished_run(tmp_path / "out", "scn", 0, PM1_TASKS)
    (tmp_path / "out" / "benchmark.json").write_text("{")
    for export in ([], ["--export", str(tmp_path / "dest")]):
        assert main(["benchmark", "--report-only", "--out", str(tmp_path / "out"), *export]) == 2
        err = capsys.readouterr().err.strip()
        assert "benchmark.json is not readable JSON" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out" / "table.md").exists() and not (tmp_path / "dest").exists()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs /proc, where no folder is made")
@pytest.mark.parametrize(
    "argv",
    [
        ["config", "copy", "/proc/nonexistent/configs"],
        ["render", "pointmaze-umaze", "--out", "/proc/nonexistent/m.png"],
        ["benchmark", "--report-only", "--out", "{tmp}/out", "--export", "/proc/nonexistent/d"],
    ],
    ids=["config-copy", "render", "export"],
)
def test_a_folder_that_cannot_be_made_is_one_line(tmp_path, capsys, argv):
    _finished_run(tmp_path / "out", "scn", 0, PM1_TASKS)
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert "cannot make the folder /proc/nonexistent" in err and len(err.splitlines()) == 1, err


# --- 9. two jobs on one missing dataset -------------------------------------------------------


def test_two_processes_that_need_one_dataset_build_it_once(tmp_path, monkeypatch):
    from hispo_pl.data.datasets import load_episodes

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    argv = ["data", "generate", "pointmaze-umaze", "--episodes", "4"]
    procs = [spawn(cli_source(argv)) for _ in range(2)]
    outcomes = [proc.communicate(timeout=300) for proc in procs]
    for proc, (out, err) in zip(procs, outcomes, strict=True):
        assert proc.returncode == 0, err[-2000:]
        assert json.loads(out[out.index("{") :])["episodes"] == 4
    assert load_episodes("pointmaze-umaze-N[4]").n_episodes == 4
    assert not list((tmp_path / ".staging").glob("*")), "staging left behind"


def test_hyperparameters_that_do_not_fit_the_weights_are_refused_before_allocating(
    tiny_run, tmp_path, capsys
):
    checkpoint = torch.load(tiny_run[1] / "task_02.ckpt", weights_only=True)
    checkpoint["hyper_parameters"]["backbone"]["low_hidden"] = 10**9  # 10^18 weights if built
    torch.save(checkpoint, tmp_path / "crafted.ckpt")
    path = str(tmp_path / "crafted.ckpt")
    assert main(["evaluate", "--ckpt", path, "--task", "pointmaze-umaze"]) == 2
    err = capsys.readouterr().err.strip()
    assert "its hyperparameters make" in err and "its weights hold" in err
    assert len(err.splitlines()) == 1


# --- 11. writes stay in the folder asked: links replaced, linked sources refused ------------


def _link_to_victim(link: Path, victim: Path, text: str = "victim\n") -> Path:
    """A symbolic link at ``link`` to ``victim``, a file outside the folder being written."""
    victim.write_text(text)
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(victim)
    return victim


def test_export_refuses_a_run_file_that_is_a_link_and_writes_nothing(tmp_path, capsys):
    run = _finished_run(tmp_path / "out", "scn", 0, PM1_TASKS)
    secret = _link_to_victim(run / "config.yaml", tmp_path / "secret", "SECRET\n")
    dest = tmp_path / "dest"
    argv = ["benchmark", "--report-only", "--out", str(tmp_path / "out"), "--export", str(dest)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert f"{run / 'config.yaml'} is a symbolic link" in err and len(err.splitlines()) == 1
    assert not dest.exists() and secret.read_text() == "SECRET\n"


def test_export_and_report_replace_links_at_the_destination(tmp_path, capsys):
    _finished_run(tmp_path / "out", "scn", 0, PM1_TASKS)
    dest, outside = tmp_path / "dest", tmp_path / "outside"
    victims = [
        _link_to_victim(dest / "scn" / "seed0" / "results.json", tmp_path / "v1"),
        _link_to_victim(dest / "table.md", tmp_path / "v2"),
        _link_to_victim(dest / "perf_vs_memory.png", tmp_path / "v3"),
    ]
    outside.mkdir()
    (dest / "ftn").symlink_to(outside, target_is_directory=True)
    _finished_run(tmp_path / "out", "ftn", 0, PM1_TASKS)
    argv = ["benchmark", "--report-only", "--out", str(tmp_path / "out"), "--export", str(dest)]
    assert main(argv) == 0
    assert all(v.read_text() == "victim\n" for v in victims) and not list(outside.iterdir())
    for path in (dest / "scn/seed0/results.json", dest / "table.md", dest / "ftn/seed0/run.json"):
        assert path.is_file() and not path.is_symlink(), path
    assert not (dest / "ftn").is_symlink() and "| scn |" in (dest / "table.md").read_text()


def test_the_grids_export_replaces_a_linked_config_and_refuses_a_linked_source(tmp_path):
    from hispo_pl.benchmark.grid_plan import Cell
    from hispo_pl.benchmark.grid_run import export_cell
    from hispo_pl.errors import LinkedFileError

    run = _finished_run(tmp_path / "work", "ftn", 0, PM1_TASKS)
    (run / "config.yaml").write_text("model: {}\n")
    cell, root = Cell("pointmaze-1", "ftn", "ftn", 0), tmp_path / "root"
    victim = _link_to_victim(cell.result_dir(root) / "config.yaml", tmp_path / "victim")
    _link_to_victim(root / "pointmaze-1" / "benchmark.json", tmp_path / "victim2")
    target = export_cell(run, cell, root)
    assert victim.read_text() == "victim\n" and (tmp_path / "victim2").read_text() == "victim\n"
    assert (target / "config.yaml").read_text() == "model: {}\n"
    assert not (target / "config.yaml").is_symlink()
    (run / "decisions.jsonl").symlink_to(tmp_path / "victim")
    with pytest.raises(LinkedFileError, match="decisions.jsonl is a symbolic link"):
        export_cell(run, cell, root)


def test_run_files_appended_or_locked_replace_a_link(tmp_path):
    from hispo_pl.benchmark.launch import execute_run
    from hispo_pl.results import LossDecision
    from hispo_pl.resume import RunDirLock
    from hispo_pl.rundir import RunDir

    run = RunDir(tmp_path / "run")
    names = ["decisions.jsonl", "run.lock", "fit.log", "search/task_01_low.npz"]
    victims = [_link_to_victim(run.path / n, tmp_path / f"victim{i}") for i, n in enumerate(names)]
    run.append_decisions([LossDecision(task=0, subspace="low", decision="first")])
    with RunDirLock(run):
        pass
    execute_run(["-c", "print('hello')"], str(run.fit_log), str(run.results_file))
    run.write_search(0, "low", losses=np.zeros(2))
    assert all(v.read_text() == "victim\n" for v in victims)
    assert "hello" in run.fit_log.read_text() and [d.task for d in run.decisions()] == [0]
    assert not any((run.path / n).is_symlink() for n in names)
    assert run.read_searches()[(0, "low")]["losses"].tolist() == [0.0, 0.0]


def test_render_out_replaces_a_link(tmp_path):
    victim = _link_to_victim(tmp_path / "m.png", tmp_path / "victim")
    assert main(["render", "pointmaze-umaze", "--out", str(tmp_path / "m.png")]) == 0
    assert victim.read_text() == "victim\n" and not (tmp_path / "m.png").is_symlink()
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"


# --- 12. --preset: explicit flags win, and a run without one is configured as before --------

# what `fit --preset paper --eps_high 0.05 --eps_low 0.05` on PointMaze-1 with HiSPO trained
# before explicit flags could win over the preset (the keys a preset, a knob or a method
# config set; Lightning's own trainer defaults left out): runs started so must resume
PAPER_HISPO_FINGERPRINT = {
    "seed_everything": 0,
    "trainer.callbacks[AnchorExtension].class_path": "hispo_pl.callbacks.AnchorExtension",
    "trainer.callbacks[DirichletEvaluation].class_path": "hispo_pl.callbacks.DirichletEvaluation",
    "trainer.callbacks[DirichletEvaluation].init_args.n_candidates": 1024,
    "trainer.callbacks[DirichletEvaluation].init_args.n_batches": 16,
    "trainer.callbacks[DirichletEvaluation].init_args.survivors": 32,
    "trainer.callbacks[DirichletEvaluation].init_args.probe_samples": 256,
    "trainer.callbacks[DirichletEvaluation].init_args.loss": "mse",
    "trainer.callbacks[DirichletEvaluation].init_args.precision": "auto",
    "trainer.callbacks[DirichletEvaluation].init_args.seed": 0,
    "trainer.callbacks[DirichletEvaluation].init_args.every_n_steps": 0,
    "trainer.callbacks[DirichletEvaluation].init_args.refine_current": False,
    "trainer.callbacks[DirichletEvaluation].init_args.convergence_window": 0.2,
    "trainer.callbacks[SubspacePruning].class_path": "hispo_pl.callbacks.SubspacePruning",
    "trainer.callbacks[SubspacePruning].init_args.eps_high": 0.05,
    "trainer.callbacks[SubspacePruning].init_args.eps_low": 0.05,
    "trainer.callbacks[SubspacePruning].init_args.eps": None,
    "trainer.callbacks[RolloutEvaluation].class_path": "hispo_pl.callbacks.RolloutEvaluation",
    "trainer.callbacks[RolloutEvaluation].init_args.eval_every": 0,
    "trainer.callbacks[RolloutEvaluation].init_args.episodes": 100,
    "trainer.callbacks[RolloutEvaluation].init_args.seed": 0,
    "trainer.callbacks[RolloutEvaluation].init_args.progress": False,
    "trainer.max_steps": 6000,
    "model.init_args.obs_dim": None,
    "model.init_args.action_dim": None,
    "model.init_args.goal_dim": 2,
    "model.init_args.backbone.kind": "hbc",
    "model.init_args.backbone.high_hidden": 64,
    "model.init_args.backbone.low_hidden": 256,
    "model.init_args.backbone.dropout": 0.1,
    "model.init_args.backbone.high_log_std": None,
    "model.init_args.backbone.low_log_std": None,
    "model.init_args.backbone.low_obs": True,
    "model.init_args.backbone.low_velocity": False,
    "model.init_args.backbone.high_obs": True,
    "model.init_args.backbone.binary_actions": 0,
    "model.init_args.optim.lr": 0.0003,
    "model.init_args.optim.schedule": "cosine",
    "model.init_args.anchor_init": "random",
    "model.init_args.cosine_weight": 0.0,
    "model.init_args.alpha_noise": 0.1,
    "model.init_args.alpha_groups": 1,
    "model.init_args.new_anchor_score": 0.0,
    "model.class_path": "hispo_pl.modules.HiSPO",
    "data.task": None,
    "data.dataset": None,
    "data.datasets": None,
    "data.batch_size": 1024,
    "data.waysteps": None,
    "data.her_temperature": None,
    "data.her_strategy": "exponential",
    "data.goal_horizon": "episode",
    "data.steps_per_epoch": 1000,
    "data.seed": 0,
    "data.stream": "pointmaze-1",
    "data.replay": False,
    "data.holdout": 0.0,
    "data.transitions": False,
    "data.low_inputs": "observation",
    "data.high_inputs": "observation",
    "preset": "paper",
    "eps_high": None,
    "eps_low": None,
    "eps": None,
    "search_candidates": None,
    "search_batches": None,
    "eval_episodes": None,
    "eval_every": None,
    "optimizer": None,
    "lr_scheduler": None,
}


def _hispo_fingerprint(tmp_path: Path, *extra: str) -> dict:
    """The fingerprint a HiSPO stream run on PointMaze-1 with ``extra`` flags checks on
    resume, parsed as ``fit`` parses it (nothing trained)."""
    from helpers import ROOT

    from hispo_pl.fit import run_lightning_cli
    from hispo_pl.run_checks import plain_config, run_fingerprint

    configs = [ROOT / "configs/streams/pointmaze-1.yaml", ROOT / "configs/methods/hispo.yaml"]
    args = [a for c in configs for a in ("--config", str(c))]
    args += ["--trainer.logger.init_args.save_dir", str(tmp_path), *extra]
    config = run_lightning_cli(args, run=False).config.as_dict()
    return run_fingerprint(plain_config({k: v for k, v in config.items() if k != "config"}))


def test_the_paper_preset_without_a_conflicting_flag_trains_as_before(tmp_path, capsys):
    knobs = ("--eps_high", "0.05", "--eps_low", "0.05")
    found = _hispo_fingerprint(tmp_path, "--preset", "paper", *knobs)
    assert {k: found.get(k) for k in PAPER_HISPO_FINGERPRINT} == PAPER_HISPO_FINGERPRINT
    assert "--preset paper" not in capsys.readouterr().out  # nothing kept, nothing said


def test_the_paper_protocol_grid_gives_no_flag_the_preset_sets(tmp_path):
    from hispo_pl.benchmark.grid import load_grid
    from hispo_pl.benchmark.grid_plan import Cell, cell_run
    from hispo_pl.config_files import config_root
    from hispo_pl.presets import apply_preset, given_keys

    grid = load_grid("paper-protocol", config_root())
    for stream in grid.streams:
        for method in grid.methods:
            run = cell_run(
                Cell(stream, method, method, 0, ("--eps_high", "0.05")),
                grid,
                config_root(),
                tmp_path,
            )
            config = {
                "model": {"class_path": "hispo_pl.modules.HiSPO", "init_args": {}},
                "data": {"stream": stream},
                "trainer": {"callbacks": []},
            }
            apply_preset(config, "paper")
            again = json.loads(json.dumps(config))
            assert apply_preset(again, "paper", given_keys(run.argv)) == {} and again == config


def test_explicit_flags_win_over_the_preset_and_the_run_says_which(tiny_umaze, tmp_path, capsys):
    flags = ["--data.holdout", "0.2", "--model.init_args.optim.lr", "0.01"]
    args = tiny_stream_args("ftn", tmp_path, ["pointmaze-umaze-N[3]"], "--preset", "paper", *flags)
    assert main(args) == 0
    said = [ln for ln in capsys.readouterr().out.splitlines() if "--preset paper" in ln]
    assert len(said) == 1, said
    for kept in ("data.batch_size 64 (the preset: 1024)", "data.holdout 0.2 (the preset: 0.0)"):
        assert kept in said[0]
    assert "model.init_args.optim.lr 0.01 (the preset: 0.0003)" in said[0]
    import yaml

    config = yaml.safe_load((stream_dir(tmp_path) / "task_01.config.yaml").read_text())
    assert config["data"]["batch_size"] == 64 and config["data"]["holdout"] == 0.2
    assert config["model"]["init_args"]["optim"]["lr"] == 0.01
    assert config["model"]["init_args"]["optim"]["schedule"] == "cosine"  # the preset's still


def test_the_grid_report_replaces_a_linked_folder(tmp_path):
    from hispo_pl.benchmark.grid import grid_from_dict
    from hispo_pl.benchmark.grid_report import write_grid_report

    grid = grid_from_dict({"streams": ["pointmaze-1"], "methods": ["scn"], "seeds": 1}, "g")
    outside = tmp_path / "outside"
    outside.mkdir()
    (tmp_path / "root").mkdir()
    (tmp_path / "root" / "grid-g").symlink_to(outside, target_is_directory=True)
    written = write_grid_report(grid, tmp_path / "root", figures=False)
    assert written and not list(outside.iterdir())
    assert not (tmp_path / "root" / "grid-g").is_symlink()
