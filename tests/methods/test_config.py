"""The typed backbone and optimiser configs, as checkpoints store them."""

from __future__ import annotations

import pytest
import torch
from helpers import checkpoint_of

from hispo_pl.config import BackboneConfig
from hispo_pl.errors import CheckpointError
from hispo_pl.modules import HBC, HiSPO
from hispo_pl.modules.checkpoints import read_checkpoint
from hispo_pl.modules.hbc import GoalConditionedBC


def test_a_checkpoint_of_an_earlier_layout_is_refused_in_one_line(tmp_path):
    """Flat hyperparameters (``high_hidden``, ``lr``), as checkpoints had them before the
    configs: refused, naming the file, rather than guessed at."""
    module = HBC(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16))
    checkpoint = checkpoint_of(module)
    flat = {
        k: v for k, v in checkpoint["hyper_parameters"].items() if k not in ("backbone", "optim")
    }
    checkpoint["hyper_parameters"] = {**flat, "high_hidden": 8, "low_hidden": 16, "lr": 1e-3}
    path = tmp_path / "task_02.ckpt"
    torch.save(checkpoint, path)
    with pytest.raises(CheckpointError, match="not a readable hispo-pl checkpoint") as err:
        GoalConditionedBC.from_checkpoint_file(str(path))
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_a_new_checkpoint_holds_plain_values(tmp_path):
    module = HiSPO(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16, low_obs=False))
    checkpoint = checkpoint_of(module)
    torch.save(checkpoint, tmp_path / "m.ckpt")
    loaded = read_checkpoint(tmp_path / "m.ckpt")  # weights_only=True
    assert loaded["hyper_parameters"]["backbone"]["low_obs"] is False
    again = GoalConditionedBC.from_checkpoint_file(str(tmp_path / "m.ckpt"))
    assert again.backbone_config == module.backbone_config


def test_an_unknown_backbone_kind_is_refused():
    with pytest.raises(ValueError, match="expected 'hbc' or 'bc'"):
        BackboneConfig(kind="mlp")
    with pytest.raises(ValueError, match="hierarchical backbone"):
        HiSPO(4, 2, backbone=BackboneConfig(kind="bc"))
    assert HBC(4, 2, backbone={"kind": "bc", "low_hidden": 8}).net.names == ("policy",)
