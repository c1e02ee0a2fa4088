"""Sweep trees: a run at another pruning tolerance shares the tasks before its first differing
decision with a finished run, and a run at another penalty λ (L2, EWC) shares task 1, so it is
branched from that run's files and resumed instead of trained from the start. The tests that
license it: a branched run equals a real run of that ε or λ (results, decisions, progress,
checkpoints, configuration), both where it trains on after the branch and where it agrees on
every task and is copied whole."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
import yaml
from helpers import (
    BENCH_TINY_OVERRIDES,
    fit_tiny_stream,
    grid_config_dir,
    nested_equal,
    without_times,
)

from hispo_pl.benchmark import branch
from hispo_pl.benchmark.configs import saved_setting
from hispo_pl.cli import main as cli_main
from hispo_pl.errors import RunDirError
from hispo_pl.results import LaunchRecord, LossDecision
from hispo_pl.rundir import RunDir

ROOT = Path(__file__).resolve().parents[2]
STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]", "pointmaze-umaze-IA[3]"]
BUDGET = ("--trainer.max_steps", "20")
ROOT_EPS = 0.1


def _eps_args(eps: float) -> tuple[str, ...]:
    return ("--eps_high", f"{eps:g}", "--eps_low", f"{eps:g}", *BUDGET)


def _both(eps: float) -> dict[str, float]:
    return {"eps_high": eps, "eps_low": eps}


@pytest.fixture(scope="module")
def root_run(tiny_umaze, tmp_path_factory) -> Path:
    """HiSPO at ε = 0.1 on three tiny tasks: two task-end decisions per subspace."""
    root = tmp_path_factory.mktemp("tree")
    return fit_tiny_stream("hispo", root / "root", STREAM, *_eps_args(ROOT_EPS))[1]


def _tolerance_sharing(run: Path, tasks: int) -> float:
    """A tolerance of the paper's kind whose run shares exactly ``tasks`` tasks with ``run``."""
    decisions = RunDir(run).decisions()
    for eps in (0.0, 0.01, 0.05, 0.25, 0.5, 1.0, 2.0, 20.0):
        if eps != ROOT_EPS and branch.shared_tasks(decisions, _both(eps), 3) == tasks:
            return eps
    raise AssertionError(f"no tolerance shares {tasks} tasks with {run}: {decisions}")


@pytest.mark.e2e
@pytest.mark.parametrize("shared", [2, 3], ids=["trains-on", "copied-whole"])
def test_a_branched_run_equals_a_real_run_of_its_tolerance(root_run, tmp_path, shared):
    eps = _tolerance_sharing(root_run, shared)
    real = RunDir(fit_tiny_stream("hispo", tmp_path / "real", STREAM, *_eps_args(eps))[1])
    target = RunDir(tmp_path / "branched" / "pointmaze-1" / "seed0")
    branch.branch_run(root_run, target.path, shared, _both(eps), LaunchRecord(method="hispo"))
    assert target.read_run_record().branched_tasks == shared
    fit_tiny_stream("hispo", tmp_path / "branched", STREAM, *_eps_args(eps))  # in target
    branched_results = target.stream_results().to_json()
    assert without_times(branched_results) == without_times(real.stream_results().to_json())
    assert [d.to_json() for d in target.decisions()] == [d.to_json() for d in real.decisions()]
    branched, trained = target.read_progress().to_json(), real.read_progress().to_json()
    assert without_times(branched) == without_times(trained)
    for task in range(len(STREAM)):
        a = torch.load(target.checkpoint(task), weights_only=True)
        assert nested_equal(a, torch.load(real.checkpoint(task), weights_only=True)), task
    # the copied tasks cost nothing; a task trained after the branch did
    training = [p["training"] for p in target.read_progress().phase_time_s]
    assert training[:shared] == [0.0] * shared and all(t > 0 for t in training[shared:])
    # the configuration is in the run's files even where no task trained (copied whole), as
    # a real run writes it: the grid reads the swept value back from it
    configs = [yaml.safe_load(r.config_file.read_text()) for r in (target, real)]
    for config in configs:
        config["trainer"].pop("logger")  # where each was written
    assert configs[0] == configs[1]
    assert saved_setting(target.config_file, "eps_low") == eps
    if shared < len(STREAM):  # the first differing decision is the branch's own
        root = [d.decision for d in RunDir(root_run).decisions() if d.task == shared]
        assert root != [d.decision for d in target.decisions() if d.task == shared]


def _lambda_args(lam: float) -> tuple[str, ...]:
    return ("--model.init_args.penalty_lambda", f"{lam:g}", *BUDGET)


@pytest.mark.e2e
@pytest.mark.parametrize("method", ["l2", "ewc"])
def test_a_branched_run_equals_a_real_run_of_its_lambda(tiny_umaze, tmp_path, method):
    source = fit_tiny_stream(method, tmp_path / "source", STREAM, *_lambda_args(0.01))[1]
    real = RunDir(fit_tiny_stream(method, tmp_path / "real", STREAM, *_lambda_args(10))[1])
    settings = {branch.PENALTY_KEY: 10.0}
    target = RunDir(tmp_path / "branched" / "pointmaze-1" / "seed0")
    with pytest.raises(RunDirError, match="would not train alike"):
        branch.branch_run(source, tmp_path / "two", 2, settings, LaunchRecord())
    branch.branch_run(source, target.path, 1, settings, LaunchRecord(method=method))
    fit_tiny_stream(method, tmp_path / "branched", STREAM, *_lambda_args(10))  # in target
    assert without_times(target.stream_results().to_json()) == without_times(
        real.stream_results().to_json()
    )
    branched, trained = target.read_progress().to_json(), real.read_progress().to_json()
    assert without_times(branched) == without_times(trained)
    for task in range(len(STREAM)):
        a = torch.load(target.checkpoint(task), weights_only=True)
        assert nested_equal(a, torch.load(real.checkpoint(task), weights_only=True)), task
    for task in range(len(STREAM)):
        configs = [yaml.safe_load(r.task_config(task).read_text()) for r in (target, real)]
        for config in configs:
            config["trainer"].pop("logger")
        assert configs[0] == configs[1], task
    assert saved_setting(target.config_file, branch.PENALTY_KEY) == 10
    training = [p["training"] for p in target.read_progress().phase_time_s]
    assert training[0] == 0.0 and all(t > 0 for t in training[1:])
    # the source's task 2 did train otherwise: λ is read from task 2 on
    trained_at = [torch.load(RunDir(r).checkpoint(1), weights_only=True) for r in (source, real)]
    assert not nested_equal(trained_at[0]["state_dict"], trained_at[1]["state_dict"])


def test_shared_tasks_end_at_the_first_decision_the_tolerance_changes():
    d = [
        LossDecision(task=0, subspace="low", decision="first", eps=0.1),
        LossDecision(task=1, subspace="low", decision="keep", eps=0.1, l_prev=1.2, l_curr=1.0),
        LossDecision(task=2, subspace="high", decision="prune", eps=0.1, l_prev=1.05, l_curr=1.0),
    ]
    assert branch.shared_tasks(d, _both(0.1), 4) == 4
    assert branch.shared_tasks(d, _both(0.01), 4) == 2  # task 2's high anchor is kept at 0.01
    assert branch.shared_tasks(d, _both(0.25), 4) == 1  # task 1's low anchor is pruned at 0.25
    assert branch.shared_tasks(d, {"eps_high": 0.1}, 4) == 4  # low's tolerance as recorded
    found = branch.best_source({"a": (d, 3), "b": (d[:2], 2)}, _both(0.01))
    assert found == ("a", 2)
    assert branch.best_source({"a": (d, 3)}, _both(0.25)) == ("a", 1)
    assert branch.branch_settings(["--eps_high", "0.05", "--eps_low", "0.05", "--x", "1"]) == (
        _both(0.05)
    )
    assert branch.tolerances(_both(0.05)) == {"high": 0.05, "low": 0.05}


def test_a_penalty_lambda_shares_task_one_whatever_the_decisions():
    lam = {branch.PENALTY_KEY: 10.0}
    assert branch.branch_settings(["--model.init_args.penalty_lambda", "10", "--x", "1"]) == lam
    assert branch.tolerances(lam) == {}
    assert branch.shared_tasks([], lam, 4) == 1
    assert branch.shared_tasks([], lam, 0) == 0  # a source with no finished task shares none
    assert branch.best_source({"a": ([], 4), "b": ([], 0)}, lam) == ("a", 1)


def test_a_branch_refuses_tasks_that_would_decide_otherwise_or_a_used_directory(root_run, tmp_path):
    eps = _tolerance_sharing(root_run, 2)
    with pytest.raises(RunDirError, match="would not train alike"):
        branch.branch_run(root_run, tmp_path / "a", 3, _both(eps), LaunchRecord())
    with pytest.raises(RunDirError, match="fewer than 4 finished tasks"):
        branch.branch_run(root_run, tmp_path / "b", 4, _both(ROOT_EPS), LaunchRecord())
    branch.branch_run(root_run, tmp_path / "c", 2, _both(eps), LaunchRecord())
    with pytest.raises(RunDirError, match="already holds a run"):
        branch.branch_run(root_run, tmp_path / "c", 2, _both(eps), LaunchRecord())


# --- the grid's tolerance tree, end to end ----------------------------------------------------


def _tree_grid_configs(tmp_path: Path, name: str, method: str, key, sweep: str, values) -> Path:
    """A one-stream, one-seed grid whose ``method`` sweeps ``key`` over ``values`` as a tree."""
    grid = {
        "streams": ["pointmaze-1"],
        "methods": [method],
        "seeds": [0],
        "steps_per_task": 20,
        "extra": [*BENCH_TINY_OVERRIDES[:1], json.dumps(STREAM), *BENCH_TINY_OVERRIDES[2:]],
        "sweeps": {method: {"key": key, "name": sweep, "values": values, "branch": True}},
    }
    return grid_config_dir(tmp_path, name, grid)


@pytest.mark.e2e
def test_the_grid_trains_a_tolerance_sweep_as_a_tree(tiny_umaze, tmp_path, capsys):
    pytest.importorskip("rliable")
    values = [0.1, 0.0, 20.0]  # 20: prunes every anchor, so it parts at the first decision
    configs = _tree_grid_configs(tmp_path, "tree", "hispo", ["eps_high", "eps_low"], "eps", values)
    work, root = tmp_path / "work", tmp_path / "results"
    args = ["benchmark", "--grid", "tree", "--config-dir", str(configs), "--out", str(work)]
    args += ["--export", str(root), "--workers", "1"]
    assert cli_main([*args, "--dry-run"]) == 0
    printed = capsys.readouterr().out
    assert "pointmaze-1/hispo-eps0/seed0 waits for the tree's first value hispo-eps0.1" in printed
    assert cli_main(args) == 0
    printed = capsys.readouterr().out
    sweeps = root / "pointmaze-1" / "sweeps"
    first = RunDir(sweeps / "hispo-eps0.1" / "seed0")
    assert not first.read_run_record().holds("branched_tasks")
    decisions = first.decisions()
    for value in values[1:]:
        run = RunDir(sweeps / f"hispo-eps{value:g}" / "seed0")
        record = run.read_run_record()
        shared = branch.shared_tasks(decisions, _both(value), len(STREAM))
        assert record.branched_from == "pointmaze-1/hispo-eps0.1/seed0"
        assert record.branched_tasks == shared >= 1
        assert f"hispo-eps{value:g}/seed0: its first {shared} task(s) branched" in printed
        assert [d.eps for d in run.decisions() if d.l_prev is not None] == [value] * len(
            [d for d in run.decisions() if d.l_prev is not None]
        )
        assert saved_setting(run.config_file, "eps_low") == value
        assert run.stream_results().R[:shared] == first.stream_results().R[:shared]
    assert branch.shared_tasks(decisions, _both(20.0), len(STREAM)) == 1
    # the sweeps report counts what the tree trained, of the tasks its runs hold
    copied = sum(branch.shared_tasks(decisions, _both(v), len(STREAM)) for v in values[1:])
    sweeps = (root / "grid-tree" / "sweeps.md").read_text()
    held = len(values) * len(STREAM)
    assert f"| {held - copied} of {held} |" in sweeps
    # the chosen value's seed 0 is its sweep run; nothing is left to run
    assert cli_main([*args, "--dry-run"]) == 0
    assert "pointmaze-1: 4 done, 0 to run" in capsys.readouterr().out


@pytest.mark.e2e
def test_the_grid_trains_a_lambda_sweep_as_a_tree(tiny_umaze, tmp_path, capsys):
    pytest.importorskip("rliable")
    configs = _tree_grid_configs(
        tmp_path, "lambda-tree", "l2", branch.PENALTY_KEY, "lambda", [0.01, 10]
    )
    work, root = tmp_path / "work", tmp_path / "results"
    args = ["benchmark", "--grid", "lambda-tree", "--config-dir", str(configs), "--out"]
    args += [str(work), "--export", str(root), "--workers", "1"]
    assert cli_main(args) == 0
    printed = capsys.readouterr().out
    assert "l2-lambda10/seed0: its first 1 task(s) branched" in printed
    # the branch resumes as its own first launch, not as a run launched otherwise before
    assert "l2-lambda10/seed0: resuming an interrupted run\n" in printed
    sweeps = root / "pointmaze-1" / "sweeps"
    first, other = (RunDir(sweeps / f"l2-lambda{v}" / "seed0") for v in ("0.01", "10"))
    record = other.read_run_record()
    assert (record.branched_from, record.branched_tasks) == ("pointmaze-1/l2-lambda0.01/seed0", 1)
    assert saved_setting(other.config_file, branch.PENALTY_KEY) == 10
    assert other.stream_results().R[:1] == first.stream_results().R[:1]
    held = 2 * len(STREAM)
    assert f"| {held - 1} of {held} |" in (root / "grid-lambda-tree" / "sweeps.md").read_text()


def test_a_branch_refuses_a_folder_another_process_holds(root_run, tmp_path):
    from hispo_pl.resume import RunDirLock

    target = tmp_path / "held"
    target.mkdir()
    with RunDirLock(target), pytest.raises(RunDirError, match="in use by another run"):
        branch.branch_run(root_run, target, 1, _both(ROOT_EPS), LaunchRecord())
    assert not RunDir(target).progress_file.exists()
