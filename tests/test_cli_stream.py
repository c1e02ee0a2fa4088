"""A stream end to end through ``hispo-pl fit`` with a stream config and the HiSPO method."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from helpers import tiny_stream_args
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from hispo_pl.cli import main
from hispo_pl.config import BackboneConfig
from hispo_pl.metrics import module_bytes
from hispo_pl.modules.hbc import HBC

ROOT = Path(__file__).resolve().parents[1]
STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]

pytestmark = pytest.mark.usefixtures("one_thread")


def _stream_args(save_dir: Path) -> list[str]:
    extra = ("--trainer.log_every_n_steps", "1")
    return tiny_stream_args("hispo", save_dir, STREAM, *extra)


def test_stream_fit_prints_metrics_logs_and_resumes(tiny_umaze, tmp_path, capsys):
    assert main(_stream_args(tmp_path)) == 0
    out = capsys.readouterr().out
    assert "stream pointmaze-umaze-N[3] -> pointmaze-umaze-PO[3]" in out
    assert "PER" in out and "BWT" in out and "anchors per subspace" in out

    run_dir = tmp_path / "pointmaze-1" / "seed0"  # the stream's version defaults to seed<seed>
    results = json.loads((run_dir / "results.json").read_text())
    assert results["stream"] == STREAM
    assert len(results["R"]) == 2 and all(len(row) == 2 for row in results["R"])
    assert results["BWT"] == 0.0  # HiSPO: the first task's success is kept exactly
    assert results["R"][1][0] == results["R"][0][0]
    assert results["MEM"] > 0  # a reference model size is passed by the CLI
    # ... that of the single-task HBC with the method config's architecture
    goal_space = dict(low_obs=False, low_velocity=True)
    reference = HBC(4, 2, backbone=BackboneConfig(high_log_std=0.0, low_log_std=0.0, **goal_space))
    assert results["MEM"] == pytest.approx(results["stored_bytes"] / module_bytes(reference))
    assert f"anchors per subspace: {results['anchors']}" in out
    assert (run_dir / "task_01.ckpt").exists() and (run_dir / "task_02.ckpt").exists()

    events = list(run_dir.rglob("events.out.tfevents.*"))
    assert events, "no TensorBoard event file written"
    acc = EventAccumulator(str(run_dir))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    assert {"eval/T01/on_T01/success", "eval/T02/on_T01/success", "anchors/high/count"} <= tags
    assert {"anchors/low/count", "task_01/train/loss", "task_02/train/loss"} <= tags
    after_first = acc.Scalars("eval/T01/on_T01/success")
    assert [s.step for s in after_first] == [0]
    assert after_first[0].value == pytest.approx(results["R"][0][0])
    counts = acc.Scalars("anchors/high/count")
    assert [s.step for s in counts] == [1, 2]
    assert counts[-1].value == results["anchors"]["high"]

    # the same command again: every task is finished, nothing trains, same results
    assert main(_stream_args(tmp_path)) == 0
    out = capsys.readouterr().out
    assert "tasks 1..2 already trained" in out
    again = json.loads((run_dir / "results.json").read_text())
    for key in ("R", "PER", "BWT", "anchors", "alphas", "wall_time_s"):
        assert again[key] == results[key], key


def test_decision_lines_name_each_subspaces_decision_and_ratio():
    from hispo_pl.cli import decision_lines

    records = [
        {"task": 0, "subspace": "high", "decision": "first", "l_curr": 0.2, "eps": 0.1},
        {
            "task": 1,
            "subspace": "high",
            "decision": "keep",
            "l_prev": 0.9,
            "l_curr": 0.05,
            "eps": 0.1,
        },
        {
            "task": 1,
            "subspace": "low",
            "decision": "prune",
            "l_prev": 0.21,
            "l_curr": 0.2,
            "eps": 0.1,
        },
        {"task": 2, "subspace": "low", "decision": "zero-shot", "eps": {"low": 1.0}},
    ]
    assert decision_lines(records) == [
        "task 2: high keep (18.00 vs 1.10), low prune (1.05 vs 1.10)"
    ]
