"""A stream end to end through ``hispo-pl fit`` with a stream config and the HiSPO method."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from helpers import own_minari_dataset, tiny_stream_args
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from hispo_pl.cli import main
from hispo_pl.config import BackboneConfig
from hispo_pl.data.datasets import load_episodes
from hispo_pl.metrics import module_bytes
from hispo_pl.modules.hbc import HBC

ROOT = Path(__file__).resolve().parents[2]
STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]


def _stream_args(save_dir: Path) -> list[str]:
    extra = ("--trainer.log_every_n_steps", "1")
    return tiny_stream_args("hispo", save_dir, STREAM, *extra)


def test_stream_fit_prints_metrics_logs_and_resumes(tiny_umaze, tmp_path, capsys):
    assert main(_stream_args(tmp_path)) == 0
    out, err = capsys.readouterr()
    assert "stream pointmaze-umaze-N[3] -> pointmaze-umaze-PO[3]" in out
    assert "PER" in out and "BWT" in out and "anchors per subspace" in out
    # per task: a header, progress as lines on stderr (not a terminal), a summary
    assert "task 1/2: pointmaze-umaze-N[3], 5 steps" in out
    assert "task 2/2 step 5/5 (100 %), loss " in err
    assert "task 2/2 done in " in out and "(earlier tasks: mean " in out
    assert out.count("Trainable params") <= 1  # the model summary once per stream

    run_dir = tmp_path / "pointmaze-1" / "seed0"  # the stream's version defaults to seed<seed>
    results = json.loads((run_dir / "results.json").read_text())
    assert results["stream"] == STREAM
    assert len(results["R"]) == 2 and all(len(row) == 2 for row in results["R"])
    assert results["BWT"] == 0.0  # HiSPO: the first task's success is kept exactly
    assert results["R"][1][0] == results["R"][0][0]
    assert results["MEM"] > 0  # a reference model size is passed by the CLI
    # ... that of the single-task HBC with the method config's architecture
    inputs = dict(low_obs=False, low_velocity=True, high_obs=True)  # PointMaze's inputs
    stream_width = dict(high_hidden=192)  # configs/streams/pointmaze-1.yaml
    reference = HBC(4, 2, backbone=BackboneConfig(**inputs, **stream_width))
    assert results["MEM"] == pytest.approx(results["stored_bytes"] / module_bytes(reference))
    assert f"anchors per subspace: {results['anchors']}" in out
    assert f"tensorboard --logdir {run_dir}" in out
    assert "#custom_scalars&_smoothingWeight=0" in out  # the forgetting curves as measured
    assert (run_dir / "task_01.ckpt").exists() and (run_dir / "task_02.ckpt").exists()

    events = list(run_dir.rglob("events.out.tfevents.*"))
    assert events, "no TensorBoard event file written"
    acc = EventAccumulator(str(run_dir))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    assert {"stream/success/T01", "stream/success/T02", "anchors/high/count"} <= tags
    assert {"anchors/low/count", "task_01/train/loss", "task_02/train/loss"} <= tags
    first_task = acc.Scalars("stream/success/T01")  # one step convention: tasks trained
    assert [s.step for s in first_task] == [1, 2]
    assert first_task[0].value == pytest.approx(100 * results["R"][0][0])  # in %
    counts = acc.Scalars("anchors/high/count")
    assert [s.step for s in counts] == [0, 1, 2]  # step 0: the one anchor it starts with
    assert counts[0].value == 1 and counts[-1].value == results["anchors"]["high"]
    _assert_stream_report(run_dir, results)

    # the same command again: every task is finished, nothing trains, same results
    assert main(_stream_args(tmp_path)) == 0
    out = capsys.readouterr().out
    assert "tasks 1..2 already trained" in out
    again = json.loads((run_dir / "results.json").read_text())
    for key in ("R", "PER", "BWT", "anchors", "alphas", "wall_time_s"):
        assert again[key] == results[key], key


def test_decision_lines_name_each_subspaces_decision_and_ratio():
    from hispo_pl.console import decision_legend, decision_lines
    from hispo_pl.results import CriticDecision, LossDecision, ZeroShotDecision

    records = [
        LossDecision(task=0, subspace="high", decision="first", l_curr=0.2, eps=0.1, anchors=1),
        LossDecision(
            task=1, subspace="high", decision="keep", l_prev=0.9, l_curr=0.05, eps=0.1, anchors=2
        ),
        LossDecision(
            task=1, subspace="low", decision="prune", l_prev=0.21, l_curr=0.2, eps=0.1, anchors=1
        ),
        ZeroShotDecision(
            task=2,
            subspace="low",
            decision="zero-shot",
            pac_rate={"low": 1.0},
            eps={"low": 1.0},
            delta=0.1,
            anchors=1,
            alpha=[1.0],
        ),
    ]
    critic = CriticDecision(
        task=1, subspace="policy", decision="keep", eps=0.1, anchors=2, w_curr=0.52, w_prev=0.4
    )
    assert decision_lines([critic]) == ["task 2: policy keep (W 0.520 vs 0.440)"]
    assert decision_legend([critic]) == "W_curr vs W_prev + eps |W_prev|"
    assert decision_legend(records) == "L_prev / L_curr vs 1 + eps"
    assert decision_lines(records) == [
        "task 2: high keep (18.00 vs 1.10), low prune (1.05 vs 1.10)"
    ]


def _assert_stream_report(run_dir: Path, results: dict) -> None:
    """What a user sees of a finished stream in TensorBoard: stream metrics (also in the
    HParams tab, with no placeholder), forgetting curves at step = tasks trained, the success
    matrix and anchor weights as images, a rollout picture per task, decisions as text."""
    acc = EventAccumulator(str(run_dir), size_guidance={"images": 0, "tensors": 0})
    acc.Reload()
    tags = acc.Tags()
    for metric, scale in (("PER", 100), ("BWT", 100)):  # success in %, as printed
        (point,) = acc.Scalars(f"stream/{metric}")
        assert point.step == 2 and point.value == pytest.approx(scale * results[metric])
    # memory after each task, the last one the stream's MEM
    memory = [(p.step, p.value) for p in acc.Scalars("stream/MEM")]
    assert memory == [(k + 1, pytest.approx(m)) for k, m in enumerate(results["mem_per_task"])]
    assert results["mem_per_task"][-1] == pytest.approx(results["MEM"])
    assert results["mem_per_task"][0] == pytest.approx(1.0, rel=1e-3)  # one anchor each: one model
    assert "hp_metric" not in tags["scalars"]
    curve = acc.Scalars("stream/success/T01")
    R = results["R"]
    assert [(p.step, p.value) for p in curve] == [(1, 100 * R[0][0]), (2, 100 * R[1][0])]
    # the anchor weights are pictures, not one-point scalar charts
    assert not [t for t in tags["scalars"] if t.startswith("alpha/")]
    assert {
        "stream/success_matrix",
        "alpha/high",
        "alpha/low",
        "rollouts/T01",
        "rollouts/T02",
        "pruning/rule",  # the deciding values, drawn whole (no smoothing, no outlier scaling)
        "anchors/per_subspace",
    } <= set(tags["images"])
    forgetting = acc.Images("stream/forgetting")  # after each task, unsmoothed
    assert [image.step for image in forgetting] == [1, 2]
    (rule,) = acc.Images("pruning/rule")  # the second task's decisions (the first has none)
    assert rule.step == 2
    assert {
        "stream/decisions/text_summary",
        "stream/success_matrix/text_summary",
        "stream/anchors/text_summary",
    } <= set(tags["tensors"])
    _assert_custom_scalars(acc, tags["scalars"])
    _assert_hparams(acc, results)


def _assert_custom_scalars(acc: EventAccumulator, scalars: list[str]) -> None:
    """One chart per task holds its forgetting curve, one each subspace's L_prev / L_curr and
    the line 1 + eps, one the anchor counts; each chart's tags are logged ones."""
    from tensorboard.plugins.custom_scalar import layout_pb2

    (event,) = acc.Tensors("custom_scalars__config__")
    layout = layout_pb2.Layout.FromString(event.tensor_proto.string_val[0])
    charts = {  # each tag a margin series banded by itself: every value stays on the axis
        chart.title: [s.value for s in chart.margin.series if s.value in scalars]
        for category in layout.category
        for chart in category.chart
    }
    for category in layout.category:
        for chart in category.chart:
            assert all(s.value == s.lower == s.upper for s in chart.margin.series)
    for task in ("T01", "T02"):
        (forgetting,) = (tags for title, tags in charts.items() if title.startswith(f"{task}:"))
        assert forgetting == [f"stream/success/{task}"]
    anchors = next(tags for title, tags in charts.items() if title.startswith("anchors"))
    assert sorted(anchors) == ["anchors/high/count", "anchors/low/count"]
    for subspace in ("high", "low"):
        rule = next(tags for title, tags in charts.items() if title.startswith(f"{subspace}:"))
        assert sorted(rule) == [
            f"search/{subspace}/1_plus_eps",
            f"search/{subspace}/L_prev_over_L_curr",
        ]


def _assert_hparams(acc: EventAccumulator, results: dict) -> None:
    """The HParams tab: the settings a user chose, by name (no Lightning defaults, no
    positional callback keys), and the stream metrics with the anchor counts."""
    from tensorboard.plugins.hparams import plugin_data_pb2

    content = acc.PluginTagToContent("hparams")
    start = plugin_data_pb2.HParamsPluginData.FromString(content["_hparams_/session_start_info"])
    hparams = start.session_start_info.hparams
    assert set(hparams) == {
        "method",
        "stream",
        "seed",
        "steps_per_task",
        "batch_size",
        "lr",
        "high_hidden",
        "low_hidden",
        "episodes",
        "eps_high",
        "eps_low",
    }
    assert hparams["method"].string_value == "HiSPO"
    assert hparams["stream"].string_value == " -> ".join(STREAM)
    assert hparams["steps_per_task"].number_value == 5
    experiment = plugin_data_pb2.HParamsPluginData.FromString(content["_hparams_/experiment"])
    metrics = {m.name.tag for m in experiment.experiment.metric_infos}
    assert metrics == {
        "stream/PER",
        "stream/BWT",
        "stream/MEM",
        "anchors/high/count",
        "anchors/low/count",
    }


def test_a_stream_logs_its_report_through_any_logger(tiny_umaze, tmp_path, capsys):
    """The run directory and the stream report do not depend on TensorBoard: with a CSV logger
    the stream finishes, its metrics.csv holds the tasks' curves at their gradient steps and
    stream/metrics.csv the stream scalars at the number of tasks trained."""
    logger = {
        "class_path": "lightning.pytorch.loggers.CSVLogger",
        "init_args": {"save_dir": str(tmp_path), "name": "csv", "version": "seed0"},
    }
    args = tiny_stream_args("hispo", tmp_path, STREAM, "--trainer.logger", json.dumps(logger))
    assert main([*args, "--trainer.log_every_n_steps", "2"]) == 0
    out = capsys.readouterr().out
    run_dir = tmp_path / "csv" / "seed0"
    assert (run_dir / "results.json").exists() and "tensorboard --logdir" not in out
    stream = list(csv.DictReader((run_dir / "stream" / "metrics.csv").open()))
    assert {"stream/PER", "stream/MEM", "stream/success/T02", "alpha/low/T02/anchor_1"} <= set(
        stream[0]
    )
    assert {"anchors/low/count", "search/low/L_prev"} <= set(stream[0])
    assert {int(row["step"]) for row in stream} == {0, 1, 2}  # tasks trained (0: at the start)
    curves = list(csv.DictReader((run_dir / "metrics.csv").open()))
    assert {"task_01/train/loss", "task_02/train/loss"} <= set(curves[0])
    assert all(k == "step" or k == "epoch" or k.startswith("task_0") for k in curves[0])


def test_a_logger_without_a_directory_gets_the_default_run_directory(
    tiny_umaze, tmp_path, monkeypatch, capsys
):
    from helpers import DirlessLogger

    monkeypatch.chdir(tmp_path)
    DirlessLogger.received.clear()
    args = tiny_stream_args(
        "hispo",
        tmp_path,
        STREAM,
        "--trainer.logger",
        json.dumps({"class_path": "helpers.DirlessLogger"}),
    )
    assert main(args) == 0
    run_dir = tmp_path / "runs" / "stream" / "seed0"  # a stream given as a list has no name
    assert (run_dir / "results.json").exists() and (run_dir / "task_02.ckpt").exists()
    stream_scalars = {k for metrics, _ in DirlessLogger.received for k in metrics}
    assert {"stream/PER", "stream/MEM", "stream/success/T01"} <= stream_scalars


def test_in_a_terminal_each_task_has_one_bar_over_its_steps(
    tiny_umaze, tmp_path, monkeypatch, capsys
):
    import hispo_pl.console as console
    import hispo_pl.progress as progress

    monkeypatch.setattr(console, "interactive", lambda: True)
    monkeypatch.setattr(progress, "interactive", lambda: True)
    args = tiny_stream_args("scn", tmp_path, STREAM, "--trainer.enable_progress_bar", "true")
    assert main(args) == 0
    captured = capsys.readouterr()
    bars = captured.out + captured.err
    assert "task 2/2: 100%" in bars and "5/5" in bars
    assert "Epoch 0" not in bars  # not Lightning's per-epoch bar
    assert "v_num" not in bars  # nor the logger's version, seed0 cut to "eed0"


def test_a_stream_on_a_minari_dataset_names_it_and_its_episodes(tiny_umaze, tmp_path, capsys):
    """The console and results.json say which dataset each task read and how many episodes
    it holds, not the spec's [episodes], which counts nothing for a named dataset."""
    own_minari_dataset("umaze-v1", episodes=5)
    stream = ["pointmaze-umaze-N[500]", "pointmaze-umaze-PO[500]"]
    args = tiny_stream_args("ftn", tmp_path, stream, "--data.dataset", "umaze-v1")
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "task 1/2: pointmaze-umaze-N from umaze-v1 (5 episodes), 5 steps" in out
    assert "task 2/2: pointmaze-umaze-PO from umaze-v1 (5 episodes)" in out
    # the stream's line too: the spec's [500] counted nothing
    assert "stream pointmaze-umaze-N -> pointmaze-umaze-PO, from umaze-v1 (5 episodes)" in out
    assert "[500]" not in out
    results = json.loads((tmp_path / "pointmaze-1" / "seed0" / "results.json").read_text())
    digest = load_episodes("umaze-v1").content_digest()
    assert results["datasets"] == [{"dataset": "umaze-v1", "episodes": 5, "digest": digest}] * 2
    assert results["stream"] == stream  # the specs as given: a rerun resumes the same run


def test_the_stream_line_names_a_named_dataset_where_a_task_read_one():
    from hispo_pl.console import stream_line

    ours = {"dataset": "hispo/pointmaze-umaze-expert-v0", "episodes": 3}
    own = {"dataset": "mydata/umaze-v0", "episodes": 12}
    specs = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[500]"]
    assert stream_line(specs, None) == "pointmaze-umaze-N[3] -> pointmaze-umaze-PO[500]"
    assert stream_line(specs, [ours, None]) == "pointmaze-umaze-N[3] -> pointmaze-umaze-PO[500]"
    assert stream_line(specs, [ours, own]) == (
        "pointmaze-umaze-N[3] -> pointmaze-umaze-PO from mydata/umaze-v0 (12 episodes)"
    )


def test_a_stream_on_our_data_records_it_too(tiny_run):
    results, _ = tiny_run
    digest = load_episodes("pointmaze-umaze-N[3]").content_digest()
    local = {"dataset": "hispo/pointmaze-umaze-expert-v0", "episodes": 3, "digest": digest}
    assert results["datasets"] == [local, local]  # PO reads N's stored episodes


def test_each_tasks_datamodule_takes_the_parsed_tasks(monkeypatch):
    """A stream is parsed once: the loop's per-task datamodules get the tasks the command's
    datamodule parsed, with its data settings, and parse no spec again."""
    from hispo_pl import tasks
    from hispo_pl.cli_stream import task_datamodules
    from hispo_pl.data import datamodule as datamodule_module
    from hispo_pl.data.datamodule import TaskDataModule

    first = TaskDataModule(stream=STREAM, batch_size=64, holdout=0.0)
    parsed: list[str] = []
    real = tasks.parse_task

    def counting(spec):
        if isinstance(spec, str):
            parsed.append(spec)
        return real(spec)

    monkeypatch.setattr(tasks, "parse_task", counting)
    monkeypatch.setattr(datamodule_module, "parse_task", counting)
    make = task_datamodules(first, {"batch_size": 64, "holdout": 0.0, "stream": STREAM})
    made = [make(task) for task in first.tasks]  # the loop hands over the Tasks it holds
    assert parsed == []
    assert [dm.task for dm in made] == first.tasks
    for dm in made:
        assert dm.tasks == first.tasks and dm.stream == STREAM
        assert (dm.batch_size, dm.holdout) == (64, 0.0)
