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
from hispo_pl.results import (
    PROGRESS_KEYS,
    LaunchRecord,
    LossDecision,
    Progress,
    StreamResults,
    TaskFitResult,
)
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
    assert run.read_progress() == progress
    assert json.loads(run.progress_file.read_text())["mem_per_task"] is None  # none measured
    progress.finish_task([1.0], 2.0, {"training": 2.0}, None, 1.5)
    run.write_progress(progress)
    assert run.read_progress() == progress and run.stream_task(0) == "a"
    assert list(json.loads(run.progress_file.read_text())) == ["format", *PROGRESS_KEYS]
    run.write_results(StreamResults(stream=["a"], R=[[1.0]]))
    run.write_run_record(LaunchRecord(method="hispo"))
    assert run.has_results() and run.stream_results().R == [[1.0]]
    assert run.read_run_record() == LaunchRecord(method="hispo")
    run.result_file.write_text(json.dumps({"format": 1, "method": "HBC", "task": "a"}))
    with pytest.raises(RunDirError, match="result.json has no dataset, dataset_episodes, episodes"):
        run.read_result()


def _each_file(run: RunDir) -> list[Path]:
    """A current file of each JSON kind in ``run``, written by :class:`RunDir`."""
    progress = Progress(stream=["a"], fingerprint={"seed": 0})
    progress.finish_task([0.5], 2.25, {"training": 2.0}, {"id": "d", "episodes": 3}, None)
    run.write_progress(progress)
    run.write_results(StreamResults(stream=["a"], R=[[0.5]], wall_time_s=[2.25], table="| 50 |"))
    run.write_run_record(LaunchRecord.from_json({"derived_from": "x/seed0", "method": "ft1"}))
    fit = dict(method="HBC", task="a", episodes=2, seconds=1.5, success=0.5, episode_length=9.0)
    run.write_result(TaskFitResult(**fit, flip_rate=0.0, step=10.0, curve=[]))
    return [run.progress_file, run.results_file, run.run_record_file, run.result_file]


def test_a_current_file_of_each_kind_round_trips_byte_for_byte(tmp_path):
    run, copy = RunDir(tmp_path / "a"), RunDir(tmp_path / "b")
    run.path.mkdir(), copy.path.mkdir()
    written = _each_file(run)
    assert all(json.loads(p.read_text())["format"] == 1 for p in written)
    launch = json.loads(run.run_record_file.read_text())
    assert list(launch) == ["format", "derived_from", "method"]  # the number first, any order
    copy.write_progress(run.read_progress())
    copy.write_results(run.stream_results())
    copy.write_run_record(run.read_run_record())
    copy.write_result(run.read_result())
    for path in written:
        assert (copy.path / path.name).read_bytes() == path.read_bytes(), path.name


@pytest.mark.parametrize("number", [None, 2, "1"])
def test_a_file_of_another_format_is_refused_in_one_line(tmp_path, number):
    run = RunDir(tmp_path)
    readers = {
        run.progress_file: run.read_progress,
        run.results_file: run.stream_results,
        run.run_record_file: run.read_run_record,
        run.result_file: run.read_result,
    }
    for path in _each_file(run):
        record = json.loads(path.read_text())
        if number is None:
            del record["format"]
        else:
            record["format"] = number
        path.write_text(json.dumps(record))
        with pytest.raises(RunDirError) as err:
            readers[path]()
        message = str(err.value)
        assert "\n" not in message and message.startswith(str(path)), message
        assert f"python -m lab migrate {tmp_path}" in message
        found = "has no format number" if number is None else f"is of format {json.dumps(number)}"
        assert found in message


def test_a_results_file_without_a_key_of_its_format_is_refused(tmp_path):
    run = RunDir(tmp_path)
    _each_file(run)
    record = json.loads(run.results_file.read_text())
    del record["datasets"]
    run.results_file.write_text(json.dumps(record))
    with pytest.raises(RunDirError, match="results.json has no datasets; it should hold"):
        run.stream_results()
