"""HiSPO's PAC zero-shot transfer (ZeroShotTransfer) through hispo-pl fit on a tiny stream."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
import yaml
from helpers import fit_tiny_stream

from hispo_pl.callbacks import AnchorExtension, ZeroShotTransfer
from hispo_pl.config import BackboneConfig
from hispo_pl.modules import GoalConditionedBC, HiSPO

ROOT = Path(__file__).resolve().parents[2]
STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-N[3]"]  # the same task twice


def _method_config(tmp_path: Path, **transfer) -> Path:
    config = yaml.safe_load((ROOT / "configs/methods/hispo-pac.yaml").read_text())
    first = config["trainer"]["callbacks"][0]
    assert first["class_path"].endswith("ZeroShotTransfer")
    first["init_args"].update(transfer, n_candidates=16, n_batches=2)
    path = tmp_path / "method.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def _fit(tmp_path: Path, **transfer) -> tuple[dict, list[dict], Path]:
    results, run_dir = fit_tiny_stream(_method_config(tmp_path, **transfer), tmp_path, STREAM)
    decisions = [
        json.loads(line) for line in (run_dir / "decisions.jsonl").read_text().splitlines()
    ]
    return results, decisions, run_dir


def test_accepted_task_is_not_extended_nor_trained(tiny_umaze, tmp_path):
    results, decisions, run_dir = _fit(tmp_path, eps_high=100.0, eps_low=100.0, delta=0.0)
    transfers = [d for d in decisions if d["decision"] in ("zero-shot", "train")]
    assert {(d["task"], d["subspace"], d["decision"]) for d in transfers} == {
        (1, "high", "zero-shot"),
        (1, "low", "zero-shot"),
    }
    assert all(d["pac_rate"] == {d["subspace"]: 1.0} for d in transfers)
    assert all(d["steps_skipped"] == 5 and d["time_saved_s"] > 0 for d in transfers)
    assert results["anchors"] == {"high": 1, "low": 1}  # no extension
    first = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_01.ckpt"))
    second = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    for k, v in first.state_dict().items():
        if not k.startswith("task_alpha"):
            assert torch.equal(v, second.state_dict()[k]), k  # nothing trained on task 2
    assert second.task_alphas("high").tolist() == [[1.0], [1.0]]
    assert results["R"][1] == results["R"][0]  # the same policy on the same tasks


def test_rejected_task_trains_and_extends_as_usual(tiny_umaze, tmp_path):
    results, decisions, run_dir = _fit(tmp_path, eps_high=0.0, eps_low=0.0, delta=0.0)
    transfers = [d for d in decisions if d["decision"] in ("zero-shot", "train")]
    assert {(d["subspace"], d["decision"]) for d in transfers} == {
        ("high", "train"),
        ("low", "train"),
    }
    pruning = [d for d in decisions if d["decision"] in ("keep", "prune") and d["task"] == 1]
    assert {d["subspace"] for d in pruning} == {"high", "low"}  # searched and decided as usual
    first = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_01.ckpt"))
    second = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    assert second.n_tasks == 2 and first.n_tasks == 1


def test_one_subspace_transferred_the_other_trained():
    m = HiSPO(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16))
    m.set_task_alpha(0, "high", torch.ones(1))
    m.set_task_alpha(0, "low", torch.ones(1))
    m.task_index = 1
    m.transfer("high", torch.ones(1))
    assert m.transferred("high") and not m.transferred("low")
    g = torch.Generator().manual_seed(0)
    sizes = {"observation": 4, "position": 2, "goal": 2, "subgoal": 2, "action": 2}
    batch = {k: torch.randn(8, d, generator=g) for k, d in sizes.items()}
    losses = m.losses(batch)
    assert "loss_high" not in losses and torch.equal(losses["loss"], losses["loss_low"])
    m.task_index = 2  # the mark belongs to its task
    assert not m.transferred("high")


def test_transfer_must_come_before_extension(tiny_umaze):
    import lightning as L

    from hispo_pl.data.datamodule import TaskDataModule

    m = HiSPO(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16))
    trainer = L.Trainer(
        max_steps=1,
        callbacks=[AnchorExtension(), ZeroShotTransfer()],
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
    )
    with pytest.raises(ValueError, match="before AnchorExtension"):
        trainer.fit(m, datamodule=TaskDataModule(task="pointmaze-umaze-N[3]", batch_size=8))


def test_the_grid_report_counts_a_runs_zero_shot_decisions(tiny_umaze, tmp_path):
    """The zero-shot report (beside the paper's zero-shot section) reads a real run's tests."""
    import shutil

    from hispo_pl.benchmark.grid_report import Committed
    from hispo_pl.benchmark.transfer_report import zero_shot_markdown

    _, _, run_dir = _fit(tmp_path, eps_high=100.0, eps_low=100.0, delta=0.0)
    committed = tmp_path / "committed" / "tiny"
    for seed in (0, 1):  # two seeds of the same run: the counts are summed over seeds
        dest = committed / "hispo-pac" / f"seed{seed}"
        dest.mkdir(parents=True)
        for name in ("results.json", "decisions.jsonl"):
            shutil.copy(run_dir / name, dest / name)
    text = zero_shot_markdown(Committed(committed.parent), ["tiny", "absent"])
    (row,) = [line for line in text.splitlines() if line.startswith("| tiny |")]
    per = 100 * sum(json.loads((run_dir / "results.json").read_text())["R"][-1]) / 2
    # both subspaces taken on each seed's task 2: no anchor grown, no HiSPO run to compare
    assert (
        row == f"| tiny | 2 | high 2 of 2, low 2 of 2 | 2 | {per:.1f} ± 0.0 |  | 1.00 ± 0.00 |  |"
    )
    assert "| absent | 0 | not run yet |" in text
