"""The typed backbone and optimiser configs, and checkpoints written before them."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from helpers import FLOAT32_REORDERED

from hispo_pl.config import BackboneConfig, OptimConfig, upgrade_hparams
from hispo_pl.modules import HBC, HiSPO
from hispo_pl.modules.checkpoints import read_checkpoint
from hispo_pl.modules.hbc import GoalConditionedBC

# Made by main at e51e6bb (flat hyperparameters: high_hidden, lr, a ``backbone: bc`` string,
# flat BC's ``hidden``; PNN's heads at the top of its state dict), with each module's actions
# on fixed inputs for the policies of its first and last task.
LEGACY = Path(__file__).parent / "fixtures" / "legacy_checkpoints.pt"


@pytest.mark.parametrize(
    "name", ["hbc", "bc", "hispo", "hilow", "cspo", "pnn_hbc", "pnn_bc", "scn_bc"]
)
def test_a_checkpoint_of_the_previous_version_loads_and_acts_the_same(name, tmp_path):
    """The upgraded checkpoint acts as the old version did, to float32 rounding: the expected
    actions were recorded on another machine, whose kernels sum in another order
    (``helpers.FLOAT32_REORDERED``)."""
    fixture = torch.load(LEGACY, weights_only=True)
    path = tmp_path / "task_02.ckpt"
    torch.save(fixture["checkpoints"][name], path)
    module = GoalConditionedBC.from_checkpoint_file(str(path))
    x = fixture["inputs"]
    for task, expected in fixture["actions"][name].items():
        action = module.act(x["observation"], x["position"], x["goal"], task, x["velocity"])
        torch.testing.assert_close(action, expected, **FLOAT32_REORDERED)


def test_the_legacy_hyperparameters_become_configs():
    fixture = torch.load(LEGACY, weights_only=True)
    hispo = upgrade_hparams(fixture["checkpoints"]["hispo"]["hyper_parameters"])
    assert BackboneConfig.of(hispo["backbone"]).low_velocity is True
    assert OptimConfig.of(hispo["optim"]) == OptimConfig(lr=1e-3, schedule="cosine")
    bc = upgrade_hparams(fixture["checkpoints"]["bc"]["hyper_parameters"])
    assert BackboneConfig.of(bc["backbone"]).kind == "bc" and bc["backbone"]["low_hidden"] == 16
    assert upgrade_hparams(hispo) == hispo  # current hyperparameters pass unchanged


def test_a_new_checkpoint_holds_plain_values(tmp_path):
    module = HiSPO(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16, low_obs=False))
    checkpoint = {"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams)}
    module.on_save_checkpoint(checkpoint)
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


@pytest.mark.parametrize("name", ["hispo", "pnn_hbc"])
def test_hispo_pl_evaluate_rolls_out_a_checkpoint_of_the_previous_version(name, tmp_path, capsys):
    from hispo_pl.cli import main

    fixture = torch.load(LEGACY, weights_only=True)
    path = tmp_path / "task_02.ckpt"
    torch.save(fixture["checkpoints"][name], path)
    args = ["evaluate", "--ckpt", str(path), "--task", "pointmaze-umaze", "--episodes", "2"]
    assert main([*args, "--as-task", "1", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["as_task"] == 1 and report["episodes"] == 2 and 0 <= report["success"] <= 1
