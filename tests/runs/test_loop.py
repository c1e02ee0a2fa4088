"""The ContinualLoop on a tiny three-task stream: results, checkpoints, zero forgetting for
HiSPO, and task-granular resume that reproduces an uninterrupted run exactly."""

from __future__ import annotations

import json
import re
import shutil

import lightning as L
import pytest
import torch
from helpers import quiet_trainer

from hispo_pl.callbacks import (
    AnchorExtension,
    DirichletEvaluation,
    RolloutEvaluation,
    SubspacePruning,
)
from hispo_pl.config import BackboneConfig
from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.loop import ContinualLoop, task_phases
from hispo_pl.metrics import module_bytes
from hispo_pl.modules.hispo import SUBSPACES, HiSPO
from hispo_pl.results import RESULTS_FORMAT, StreamResults
from hispo_pl.rundir import RunDir
from hispo_pl.tasks import Task

STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-IA[3]", "pointmaze-umaze-PO[3]"]
SIZES = {"obs_dim": 4, "action_dim": 2, "backbone": BackboneConfig(high_hidden=8, low_hidden=16)}
SEED = 0
COMPARED = ("stream", "R", "PER", "BWT", "stored_bytes", "anchors", "alphas", "table")


class Interrupted(Exception):
    """Stands for a run killed between two tasks."""


def _loop(run_dir, stream=STREAM, stop_at: int | None = None, seed: int | None = SEED):
    """A loop built like ``cli_stream.run_stream_from_cli``: shared callbacks, a fresh Trainer and
    datamodule per task; ``make_trainer`` raises at task ``stop_at``."""
    L.seed_everything(SEED, verbose=False)
    module = HiSPO(**SIZES)
    callbacks = [
        AnchorExtension(),
        DirichletEvaluation(n_candidates=16, n_batches=2),
        SubspacePruning(eps_high=0.0, eps_low=0.0),  # keeps any anchor that lowers the loss
        RolloutEvaluation(episodes=2),
    ]
    started: list[int] = []

    def make_datamodule(task: Task) -> TaskDataModule:
        return TaskDataModule(task=task, batch_size=64, steps_per_epoch=5, stream=stream)

    def make_trainer(k: int) -> L.Trainer:
        if k == stop_at:
            raise Interrupted
        started.append(k)
        return quiet_trainer(
            max_steps=5,
            default_root_dir=run_dir,
            callbacks=list(callbacks),
        )

    loop = ContinualLoop(stream, module, make_datamodule, make_trainer, run_dir, seed=seed)
    loop.started = started
    return loop


@pytest.fixture(scope="module")
def uninterrupted(tiny_umaze, tmp_path_factory):
    run_dir = tmp_path_factory.mktemp("run_a")
    loop = _loop(run_dir)
    results = loop.run()
    assert loop.started == [0, 1, 2]
    assert isinstance(results, StreamResults) and results == RunDir(run_dir).stream_results()
    return {"dir": run_dir, "results": results.to_json(), "module": loop.module}


def test_results_and_checkpoints_are_written(uninterrupted):
    run_dir, results = uninterrupted["dir"], uninterrupted["results"]
    on_disk = json.loads((run_dir / RunDir.RESULTS).read_text())
    assert on_disk.pop("format") == RESULTS_FORMAT and on_disk == results
    for key in ("stream", "R", "PER", "BWT", "stored_bytes", "anchors", "alphas", "wall_time_s"):
        assert key in results, key
    assert "FWT" not in results and "MEM" not in results  # no baselines given
    assert results["stream"] == STREAM
    for k in range(3):
        assert RunDir(run_dir).checkpoint(k).name == f"task_{k + 1:02d}.ckpt"
        assert RunDir(run_dir).checkpoint(k).exists()
    assert not RunDir(run_dir).checkpoint(3).exists()
    progress = json.loads((run_dir / RunDir.PROGRESS).read_text())
    assert progress["stream"] == STREAM
    assert progress["rows"] == results["R"]
    assert len(progress["wall_time_s"]) == 3 and all(t > 0 for t in progress["wall_time_s"])
    assert results["wall_time_s"] == progress["wall_time_s"]
    # where each task's time went: the steps, the search and the rollouts, within its wall time
    assert results["phase_time_s"] == progress["phase_time_s"]
    for phases, wall in zip(results["phase_time_s"], results["wall_time_s"], strict=True):
        assert set(phases) == {"training", "search", "evaluation"}
        assert all(t > 0 for t in phases.values()) and sum(phases.values()) <= wall


def test_structure_in_results_matches_the_module(uninterrupted):
    results, module = uninterrupted["results"], uninterrupted["module"]
    # with eps = 0 some new anchor is kept, so the results depend on what training learned
    assert max(results["anchors"].values()) > 1
    assert results["stored_bytes"] == module_bytes(module)
    for name in SUBSPACES:
        k = module.n_anchors(name)
        assert results["anchors"][name] == k and 1 <= k <= 3
        alphas = results["alphas"][name]
        assert alphas == module.task_alphas(name).tolist()
        assert len(alphas) == 3 and all(len(row) == k for row in alphas)
        assert alphas[0][0] == 1.0 and all(v == 0 for v in alphas[0][1:])
        assert all(sum(row) == pytest.approx(1.0) for row in alphas)


def test_R_is_full_and_HiSPO_does_not_forget(uninterrupted):
    results = uninterrupted["results"]
    R = results["R"]
    assert len(R) == 3 and all(len(row) == 3 for row in R)
    assert all(v is not None and 0.0 <= v <= 1.0 for row in R for v in row)
    # frozen anchors and stored weights: a task's success never changes once it is learned
    for j in range(3):
        for i in range(j, 3):
            assert R[i][j] == R[j][j], (i, j)
    assert results["BWT"] == 0.0
    assert results["PER"] == pytest.approx(sum(R[-1]) / 3)
    assert "after T01" in results["table"] and "T03" in results["table"]


def test_rerun_of_a_finished_run_trains_nothing(uninterrupted, capsys):
    loop = _loop(uninterrupted["dir"])
    results = loop.run().to_json()
    assert loop.started == []
    assert "tasks 1..3 already trained" in capsys.readouterr().out
    for key in COMPARED + ("wall_time_s",):
        assert results[key] == uninterrupted["results"][key], key
    for name in SUBSPACES:
        assert loop.module.n_anchors(name) == uninterrupted["module"].n_anchors(name)


def test_resume_after_an_interruption_reproduces_the_uninterrupted_run(uninterrupted, tmp_path):
    """A resume promises the uninterrupted run bit for bit in the same environment: here both
    run in this process, with one thread and the same kernels."""
    interrupted = _loop(tmp_path, stop_at=2)
    with pytest.raises(Interrupted):
        interrupted.run()
    assert interrupted.started == [0, 1]
    assert RunDir(tmp_path).checkpoint(1).exists() and not RunDir(tmp_path).checkpoint(2).exists()
    assert not (tmp_path / RunDir.RESULTS).exists()
    assert len(json.loads((tmp_path / RunDir.PROGRESS).read_text())["rows"]) == 2

    resumed = _loop(tmp_path)  # a fresh process: new module, same seed setup
    results = resumed.run().to_json()
    assert resumed.started == [2]
    expected = uninterrupted["results"]
    for key in COMPARED:
        assert results[key] == expected[key], key
    on_disk = json.loads((tmp_path / RunDir.RESULTS).read_text())
    assert on_disk["R"] == expected["R"] and on_disk["alphas"] == expected["alphas"]
    for k in range(3):  # the same weights, bit for bit, after every task
        a = torch.load(RunDir(uninterrupted["dir"]).checkpoint(k), weights_only=True)["state_dict"]
        b = torch.load(RunDir(tmp_path).checkpoint(k), weights_only=True)["state_dict"]
        assert a.keys() == b.keys()
        for name, tensor in a.items():
            assert torch.equal(b[name], tensor), (k, name)


def test_another_stream_in_the_same_directory_is_refused(uninterrupted, tmp_path):
    shutil.copy(uninterrupted["dir"] / RunDir.PROGRESS, tmp_path / RunDir.PROGRESS)
    other = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
    loop = _loop(tmp_path, stream=other)
    with pytest.raises(ValueError, match=re.escape(str(tmp_path))) as err:
        loop.run()
    assert "pointmaze-umaze-PO[3]" in str(err.value)
    assert loop.started == []


def test_progress_without_its_checkpoint_is_an_error(uninterrupted, tmp_path):
    shutil.copy(uninterrupted["dir"] / RunDir.PROGRESS, tmp_path / RunDir.PROGRESS)
    loop = _loop(tmp_path)
    with pytest.raises(FileNotFoundError, match="task_03.ckpt is missing"):
        loop.run()
    assert loop.started == []


def test_a_stream_needs_a_rollout_evaluation(tiny_umaze, tmp_path):
    L.seed_everything(SEED, verbose=False)

    def make_trainer(k):
        return quiet_trainer(
            max_steps=2,
            default_root_dir=tmp_path,
        )

    def make_datamodule(task):
        return TaskDataModule(task=task, batch_size=16, steps_per_epoch=2, stream=STREAM)

    loop = ContinualLoop(STREAM, HiSPO(**SIZES), make_datamodule, make_trainer, tmp_path)
    with pytest.raises(RuntimeError, match="RolloutEvaluation"):
        loop.run()


def test_task_phases_split_a_fit_between_training_and_the_timed_callbacks():
    phases = task_phases(100.0, {"search": 12.5, "evaluation": 30.0})
    assert phases == {"training": 57.5, "evaluation": 30.0, "search": 12.5}
    assert list(phases) == ["training", "evaluation", "search"]
    assert task_phases(8.0, {}) == {"training": 8.0}
