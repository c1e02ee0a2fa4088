"""Every method takes the base's five arguments (``obs_dim``, ``action_dim``, ``goal_dim``,
``backbone``, ``optim``) on the command line and stores them, with its own, in the
hyperparameters a checkpoint rebuilds it from."""

from __future__ import annotations

import pytest
import torch
from helpers import checkpoint_of
from jsonargparse import ArgumentParser

from hispo_pl.config import BackboneConfig, OptimConfig, plain
from hispo_pl.modules import (
    BC,
    CSP,
    CSPO,
    HBC,
    PNN,
    GoalConditionedBC,
    HiLOW,
    HiSPO,
    NetworkPerTask,
    RegularizedFineTuning,
)

BASE = ("obs_dim", "action_dim", "goal_dim", "backbone", "optim")
SMALL = {"high_hidden": 8, "low_hidden": 16}
# each method with its own arguments, at values other than their defaults
METHODS = {
    HBC: {},
    BC: {},
    NetworkPerTask: {"init": "previous", "keep": "last"},
    RegularizedFineTuning: {"penalty": "l2", "penalty_lambda": 0.5},
    PNN: {},
    HiSPO: {"anchor_init": "random", "alpha_noise": 0.2, "new_anchor_score": 1.0},
    CSPO: {"cosine_weight": 0.1},
    CSP: {"alpha_sampling": "scores", "critic": {"hidden": 16}},
    HiLOW: {"rank": 4, "alpha_groups": 2},
}


def parsed_arguments(method: type) -> dict:
    """The ``--model.*`` arguments LightningCLI's parser gives ``method``: name -> default."""
    parser = ArgumentParser()
    parser.add_class_arguments(method, "model")
    defaults = parser.get_defaults().as_dict()["model"]
    return {key: defaults.get(key) for key in defaults}


@pytest.mark.parametrize("method", list(METHODS), ids=lambda m: m.__name__)
def test_the_parser_gives_every_method_the_base_arguments_and_its_own(method):
    arguments = parsed_arguments(method)
    assert set(BASE) <= set(arguments)
    assert set(METHODS[method]) <= set(arguments)
    assert arguments["goal_dim"] == 2 and arguments["obs_dim"] is None
    kind = "bc" if method is BC else "hbc"
    assert arguments["backbone"]["kind"] == kind
    assert arguments["optim"] == plain(OptimConfig())
    if method is RegularizedFineTuning:  # fixed by the method, not arguments
        assert not {"init", "keep"} & set(arguments)


@pytest.mark.parametrize("method", list(METHODS), ids=lambda m: m.__name__)
def test_the_hyperparameters_hold_the_base_arguments_and_round_trip(method, tmp_path):
    backbone = BackboneConfig(kind="bc" if method is BC else "hbc", **SMALL)
    module = method(obs_dim=4, action_dim=2, backbone=backbone, **METHODS[method])
    hparams = dict(module.hparams)
    assert set(BASE) <= set(hparams)  # in any order
    assert hparams["goal_dim"] == 2  # a default is stored too
    assert hparams["backbone"] == plain(backbone) and isinstance(hparams["optim"], dict)
    for name, value in METHODS[method].items():
        assert hparams[name] == value
    assert method(4, 2, backbone=backbone, **METHODS[method]).hparams == module.hparams

    checkpoint = checkpoint_of(module)
    torch.save(checkpoint, tmp_path / "task_01.ckpt")
    loaded = GoalConditionedBC.from_checkpoint_file(str(tmp_path / "task_01.ckpt"))
    assert type(loaded) is method
    assert dict(loaded.hparams) == hparams
    assert loaded.state_dict().keys() == module.state_dict().keys()
