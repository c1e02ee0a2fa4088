"""The typed run files: every committed record reads as its kind and writes back the same
bytes; the kinds tell decisions apart; the metric table drives what is computed and shown."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hispo_pl.metrics import METRICS, continual_metrics
from hispo_pl.results import (
    CriticDecision,
    Decision,
    LaunchRecord,
    LossDecision,
    StreamResults,
    ZeroShotDecision,
    decisions_table,
    fwt_reference,
)
from hispo_pl.run_files import run_file_text
from hispo_pl.rundir import RunDir

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"
# runs of different ages (written before phase times and datasets were recorded, migrated:
# null there; with both); CSP's critic records
OLD = RESULTS / "earlier-defaults" / "pointmaze-1" / "hispo" / "seed0"
NEW = RESULTS / "pointmaze-1-paper" / "hispo" / "seed0"
CRITIC = RESULTS / "antmaze-2" / "csp" / "seed0"


def _committed(name: str) -> list[Path]:
    return sorted(RESULTS.rglob(name))


@pytest.mark.parametrize("run", [OLD, NEW, CRITIC], ids=["old", "new", "critic"])
def test_a_committed_run_round_trips_byte_for_byte(run, tmp_path):
    results = json.loads((run / "results.json").read_text())
    copy = RunDir(tmp_path)
    copy.write_results(RunDir(run).stream_results())
    assert copy.results_file.read_bytes() == (run / "results.json").read_bytes()
    copy.append_decisions(RunDir(run).decisions())
    assert copy.decisions_file.read_bytes() == (run / "decisions.jsonl").read_bytes()
    assert set(results) >= {"PER", "BWT", "MEM", "table"}


def test_the_committed_runs_are_of_different_ages():
    old, new = (RunDir(run).stream_results() for run in (OLD, NEW))
    assert old.phase_time_s is None and old.datasets is None and old.mem_per_task is None
    assert None not in new.phase_time_s and None not in new.datasets


def test_every_committed_file_reads_and_writes_back_unchanged(tmp_path):
    for path in _committed("decisions.jsonl"):
        for line in path.read_text().splitlines():
            assert json.dumps(Decision.from_json(json.loads(line)).to_json()) == line, path
    for path in _committed("results.json"):
        text = run_file_text(path.name, RunDir(path.parent).stream_results().to_json())
        assert text == path.read_text(), path
    for path in _committed("result.json"):
        result = RunDir(path.parent).read_result()
        assert 0.0 <= result.success <= 1.0, path
        assert run_file_text(path.name, result.to_json()) == path.read_text(), path
    for path in _committed("run.json"):
        copy = RunDir(tmp_path / path.parent.relative_to(RESULTS))
        copy.path.mkdir(parents=True)
        copy.write_run_record(RunDir(path.parent).read_run_record())
        assert copy.run_record_file.read_bytes() == path.read_bytes(), path


def test_a_launch_record_keeps_its_keys_order_and_nulls():
    record = LaunchRecord.launched(
        method="sc1", seed=0, stream=None, steps_per_task=None, argv=["fit"], command="python"
    )
    assert record.to_json()["stream"] is None and record.holds("steps_per_task")
    source = LaunchRecord.from_json({"derived_from": "scn/seed0"}).merged(record)
    assert list(source.to_json())[:2] == ["derived_from", "method"]
    copied = record.merged({"commit": None, "mine": 1}).replace(derived_from="l2-lambda1/seed0")
    assert list(copied.to_json())[-3:] == ["commit", "mine", "derived_from"]
    assert copied.extra == {"mine": 1} and copied.commit is None and copied.holds("commit")
    assert LaunchRecord.from_json(copied.to_json()) == copied
    assert list(copied.without("argv", "command").to_json())[4:6] == ["commit", "mine"]
    with pytest.raises(TypeError, match="a launch records method"):
        LaunchRecord.launched(method="sc1")


def test_each_record_reads_as_its_kind():
    kinds = {
        type(d) for path in _committed("decisions.jsonl") for d in RunDir(path.parent).decisions()
    }
    assert kinds == {LossDecision, CriticDecision, ZeroShotDecision}
    critic = RunDir(CRITIC).decisions()
    assert {d.kind for d in critic} == {"critic"} and all(d.tolerance == d.eps for d in critic)
    loss = RunDir(NEW).decisions()
    assert {d.kind for d in loss} <= {"first", "keep", "prune"} and loss[0].kind == "first"
    record = {"task": 2, "subspace": "low", "decision": "train", "pac_rate": {"low": 0.5}}
    zero_shot = Decision.from_json({**record, "eps": {"low": 1.0}, "delta": 0.1, "anchors": 2})
    assert isinstance(zero_shot, ZeroShotDecision) and zero_shot.kind == "zero-shot"
    assert zero_shot.tolerance is None and zero_shot.comparison() is None


def test_a_zero_shot_record_writes_its_savings_only_when_skipped():
    d = ZeroShotDecision(task=1, subspace="low", decision="zero-shot", delta=0.1, anchors=1)
    assert "steps_skipped" not in d.to_json() and "time_saved_s" not in d.to_json()
    d.steps_skipped, d.time_saved_s = 3000, None  # skipped before any task was timed
    assert list(d.to_json())[-2:] == ["steps_skipped", "time_saved_s"]
    assert d.to_json()["time_saved_s"] is None


def test_unknown_keys_are_kept_and_a_non_record_is_refused(tmp_path):
    record = {"task": 0, "subspace": "low", "decision": "first", "eps": 0.1, "anchors": 1}
    d = Decision.from_json({**record, "newer": 3})
    assert d.extra == {"newer": 3} and d.to_json()["newer"] == 3
    with pytest.raises(ValueError, match="not a decision record"):
        Decision.from_json({"task": 0, "decision": "first"})
    run = RunDir(tmp_path)
    run.decisions_file.write_text(json.dumps({"task": 0}) + "\n" + json.dumps(record) + "\n")
    assert [d.subspace for d in run.decisions()] == ["low"]  # the stray line is skipped
    results = StreamResults.from_json({"stream": ["a"], "R": [[1.0]], "wall_time_s": [], "x": 1})
    assert results.to_json()["x"] == 1 and list(results.to_json())[-1] == "x"


def test_decisions_table_renders_only_its_kind_with_the_run_columns():
    loss = LossDecision(task=0, subspace="low", decision="first", eps=0.1, anchors=1, l_curr=0.2)
    critic = CriticDecision(task=1, subspace="policy", decision="keep", eps=0.1, anchors=2)
    runs = [(("hispo", "0"), [loss, critic])]
    lines = decisions_table(LossDecision, runs, [("method", "---"), ("seed", "---:")])
    assert lines[0].startswith("| method | seed | task | subspace | L_prev |")
    assert lines[1].startswith("|---|---:|---:|---|") and len(lines) == 3
    assert lines[2] == "| hispo | 0 | 1 | low |  | 0.2000 |  | 0.1 |  |  | first | 1 |"
    assert decisions_table(ZeroShotDecision, [((), [loss, critic])]) == []


R = np.array([[0.8, np.nan], [0.6, 0.9]])


def test_the_metric_table_computes_every_metric_in_its_order():
    assert [m.name for m in METRICS] == ["PER", "BWT", "FWT", "MEM"]
    found = continual_metrics(R, [0.7, 0.8], stored_bytes=300, reference_bytes=100)
    assert list(found) == ["PER", "BWT", "FWT", "MEM"]
    assert found == pytest.approx({"PER": 0.75, "BWT": -0.1, "FWT": 0.1, "MEM": 3.0})
    assert list(continual_metrics(R)) == ["PER", "BWT"]  # no reference, no model sizes
    mem = next(m for m in METRICS if m.name == "MEM")
    assert mem.of_model and mem.format(3.0) == "3.00" and not mem.percent
    per = METRICS[0]
    assert per.format(0.75) == "75.0" and per.percent and not per.of_model


def test_stream_results_order_the_model_metrics_after_the_stored_bytes():
    results = StreamResults(
        stream=["a", "b"],
        R=[[0.8, None], [0.6, 0.9]],
        wall_time_s=[1.0, 2.0],
        metrics=continual_metrics(R, [0.7, 0.8], 300, 100),
        stored_bytes=300,
    )
    keys = list(results.to_json())
    times = ["wall_time_s", "phase_time_s", "datasets"]
    model = ["stored_bytes", "MEM", "mem_per_task"]
    assert keys == ["stream", "R", *times, "PER", "BWT", "FWT", *model, "table"]
    assert results.to_json()["datasets"] is None  # not recorded: null, the key is there
    np.testing.assert_array_equal(np.isnan(results.matrix), [[False, True], [False, False]])
    assert fwt_reference(results, 2) == [0.8, 0.9] and fwt_reference(results, 3) is None
