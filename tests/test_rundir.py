"""The run directory object: every file name and format of a run, spelled once."""

from __future__ import annotations

import doctest
import importlib
import importlib.util
import json
import pkgutil
from pathlib import Path

import numpy as np
import pytest

import hispo_pl
from hispo_pl.errors import RunDirError
from hispo_pl.results import LaunchRecord, LossDecision, Progress, StreamResults
from hispo_pl.rundir import RunDir, task_label


def documented_modules() -> list[str]:
    """Every module of the package (callbacks and configs included) whose docstrings show an
    example, found by walking it, so a new example is run without being listed here."""
    names = []
    for info in pkgutil.walk_packages(hispo_pl.__path__, "hispo_pl."):
        spec = importlib.util.find_spec(info.name)
        origin = spec.origin if spec else None
        if origin and origin.endswith(".py") and ">>> " in Path(origin).read_text():
            names.append(info.name)
    return sorted(names)


def test_examples_are_found_in_every_room():
    names = documented_modules()
    assert {"hispo_pl.rundir", "hispo_pl.callbacks.critic_pruning", "hispo_pl.iql"} <= set(names)


@pytest.mark.parametrize("name", documented_modules())
def test_docstring_examples_run(name):
    failed, attempted = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS)
    assert attempted > 0 and failed == 0


def test_names_count_tasks_from_one(tmp_path):
    run = RunDir(tmp_path)
    assert task_label(0) == 1
    assert run.checkpoint(0).name == "task_01.ckpt"
    assert run.partial_checkpoint(11).name == "task_12.partial.ckpt"
    assert run.task_config(2).name == "task_03.config.yaml"
    assert run.search_file(1, "low") == tmp_path / "search" / "task_02_low.npz"
    names = [run.progress_file, run.results_file, run.decisions_file, run.result_file]
    assert [p.name for p in names] == [
        "progress.json",
        "results.json",
        "decisions.jsonl",
        "result.json",
    ]
    assert (run.lock_file.name, run.run_record_file.name) == ("run.lock", "run.json")


def test_decisions_skip_cut_lines_and_keep_only_what_is_asked(tmp_path):
    run = RunDir(tmp_path)
    assert run.decisions() == []
    first, second = (LossDecision(task=t, subspace="high", decision="first") for t in (0, 1))
    run.append_decisions([first, second])
    with open(run.decisions_file, "a") as f:
        f.write('{"task": 2, "subs')  # a kill mid-line
    assert run.decisions() == [first, second]
    run.keep_decisions(lambda d: d.task < 1)
    assert run.decisions_file.read_text() == json.dumps(first.to_json()) + "\n"


def test_search_files_come_back_keyed_by_the_zero_based_task(tmp_path):
    run = RunDir(tmp_path)
    run.write_search(1, "low", alphas=np.eye(2), losses=np.array([0.5, 0.25]), l_curr=0.3)
    ((key, arrays),) = run.read_searches().items()
    assert key == (1, "low") and float(arrays["l_curr"]) == 0.3
    assert np.array_equal(arrays["losses"], [0.5, 0.25])


def test_progress_results_and_records_round_trip(tmp_path):
    run = RunDir(tmp_path / "new")
    assert run.read_progress() is None and run.read_run_record() == LaunchRecord()
    run.path.mkdir()
    progress = Progress(stream=["a"], fingerprint={"seed": 0})
    run.write_progress(progress)
    assert run.read_progress() == progress and "mem_per_task" not in run.progress_file.read_text()
    progress.finish_task([1.0], 2.0, {"training": 2.0}, None, 1.5)
    run.write_progress(progress)
    assert run.read_progress() == progress and run.stream_task(0) == "a"
    assert list(json.loads(run.progress_file.read_text())) == [
        "stream",
        "rows",
        "wall_time_s",
        "phase_time_s",
        "datasets",
        "fingerprint",
        "mem_per_task",
    ]
    run.write_results(StreamResults(stream=["a"], R=[[1.0]]))
    run.write_run_record(LaunchRecord(method="hispo"))
    assert run.has_results() and run.stream_results().R == [[1.0]]
    assert run.read_run_record() == LaunchRecord(method="hispo")
    run.result_file.write_text(json.dumps({"method": "HBC", "task": "a", "success": 1.0}))
    with pytest.raises(RunDirError, match="result.json has no episodes, seconds, episode_length"):
        run.read_result()


def test_progress_of_an_older_run_gets_none_for_what_it_did_not_record():
    """A progress file from before phase times and datasets: None for each finished task, and
    MEM per task padded with None before the first task that measured it."""
    progress = Progress.from_json({"stream": ["a", "b"], "rows": [[1.0, 0.0]], "wall_time_s": [1]})
    assert progress.phase_time_s == [None] and progress.datasets == [None]
    progress.finish_task([1.0, 1.0], 1.0, {"training": 1.0}, None, 2.0)
    assert progress.mem_per_task == [None, 2.0] and progress.done == 2


def test_committed_results_from_before_the_dataset_record_still_read():
    """results.json files written before runs recorded their datasets read and tabulate."""
    from hispo_pl.benchmark.finished_runs import load_records

    root = Path(__file__).resolve().parents[1] / "docs" / "results" / "pointmaze-1"
    old = RunDir(root / "ftn" / "seed0").stream_results()
    assert old.datasets is None and "datasets" not in old.to_json() and len(old.R) == 4
    records, unreadable = load_records(root)
    assert unreadable == [] and {r.method for r in records} >= {"ftn", "hispo"}
