"""``low_obs=False``: the low policy sees only the features of the relative subgoal, in every
method built on the HBC backbone."""

from __future__ import annotations

import pytest
import torch
from helpers import fit_tiny_stream

from hispo_pl.config import BackboneConfig
from hispo_pl.metrics import module_bytes
from hispo_pl.modules import GoalConditionedBC
from hispo_pl.modules.columns import NetworkPerTask
from hispo_pl.modules.cspo import CSPO
from hispo_pl.modules.hbc import HBC
from hispo_pl.modules.hilow import HiLOW
from hispo_pl.modules.hispo import HiSPO
from hispo_pl.modules.pnn import PNN
from hispo_pl.modules.regularized import RegularizedFineTuning
from hispo_pl.nn.hierarchy import HierarchicalPolicy, high_input, low_input
from hispo_pl.nn.mlp import feature_dim

WIDTHS = {"high_hidden": 8, "low_hidden": 16, "dropout": 0.0}


def _net(**kw) -> dict:
    return {"backbone": BackboneConfig(**WIDTHS, **kw)}


MODULES = [HBC, HiSPO, CSPO, HiLOW, PNN, NetworkPerTask, RegularizedFineTuning]


def _batch(observation_seed: int, n: int = 32) -> dict[str, torch.Tensor]:
    """A batch whose observations come from their own seed; everything else is fixed."""
    g = torch.Generator().manual_seed(1)
    batch = {k: torch.randn(n, 2, generator=g) for k in ("position", "goal", "subgoal", "action")}
    batch["observation"] = torch.randn(
        n, 4, generator=torch.Generator().manual_seed(observation_seed)
    )
    return batch


def _low_loss(module: GoalConditionedBC, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    torch.manual_seed(0)  # HiSPO draws noisy anchor weights per step
    return module.losses(batch)["loss_low"]


@pytest.mark.parametrize("cls", MODULES, ids=lambda c: c.__name__)
def test_low_policy_never_reads_the_observation(cls):
    module = cls(4, 2, **_net(low_obs=False))
    reference = module.reference_model()
    assert isinstance(reference, HierarchicalPolicy)
    assert reference.low.net.inp[0].in_features == feature_dim(2)
    a, b = _low_loss(module, _batch(2)), _low_loss(module, _batch(3))
    assert torch.equal(a, b)  # other observations, same low loss
    with_obs = cls(4, 2, **_net())  # the default still reads it
    assert not torch.equal(_low_loss(with_obs, _batch(2)), _low_loss(with_obs, _batch(3)))
    # MEM's unit shrinks with the low policy's input: one unit is one network of this backbone
    assert module_bytes(reference) < module_bytes(with_obs.reference_model())


def test_hispo_stream_without_observation_in_the_low_policy(tiny_umaze, tmp_path):
    results, run_dir = fit_tiny_stream(
        "hispo",
        tmp_path,
        ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"],
        "--data.low_inputs",
        "subgoal",
        "--data.high_inputs",
        "observation",
    )
    assert results["BWT"] == 0.0
    module = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    assert isinstance(module, HiSPO) and module.backbone_config.low_obs is False
    module.eval()
    obs = torch.randn(5, 4)
    pos, goal = torch.zeros(5, 2), torch.ones(5, 2)
    offset, _ = module.policies["high"](high_input(obs, pos, goal), module.alpha_for("high", 1))
    low_x = low_input(obs, offset, with_obs=False)
    expected, _ = module.policies["low"](low_x, module.alpha_for("low", 1))
    assert torch.equal(module.act(obs, pos, goal, task=1), expected)


def _with_velocity(batch: dict[str, torch.Tensor], seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {**batch, "velocity": torch.randn(len(batch["action"]), 2, generator=g)}


@pytest.mark.parametrize("cls", MODULES, ids=lambda c: c.__name__)
def test_goal_space_low_policy_reads_velocity_and_not_the_observation(cls):
    module = cls(4, 2, **_net(low_obs=False, low_velocity=True))
    assert module.reference_model().low.net.inp[0].in_features == feature_dim(2) + 2
    batch = _with_velocity(_batch(2), seed=5)
    other_obs = _with_velocity(_batch(3), seed=5)
    other_velocity = _with_velocity(_batch(2), seed=6)
    assert torch.equal(_low_loss(module, batch), _low_loss(module, other_obs))
    assert not torch.equal(_low_loss(module, batch), _low_loss(module, other_velocity))
    obs, pos, goal = torch.randn(3, 4), torch.zeros(3, 2), torch.ones(3, 2)
    module.eval()
    with pytest.raises(ValueError, match="velocity="):
        module.act(obs, pos, goal)
    assert module.act(obs, pos, goal, velocity=torch.zeros(3, 2)).shape == (3, 2)


def test_sampler_velocity_is_the_balls_from_its_positions(tiny_umaze):
    from hispo_pl.data.sampler import HERConfig, HERSampler

    sampler = HERSampler(tiny_umaze, HERConfig(), 4096, seed=0, step_seconds=0.01)
    batch = sampler.sample()
    first = torch.from_numpy(tiny_umaze.episode_end)  # rows that start an episode: velocity 0
    starts = {0} | {int(e) + 1 for e in first.unique()[:-1]}
    obs = batch["observation"]
    is_start = torch.tensor(
        [
            any(torch.equal(obs[k], torch.from_numpy(tiny_umaze.observations[s])) for s in starts)
            for k in range(64)
        ]
    )
    rows = slice(0, 64)
    expected = torch.where(is_start[:, None], torch.zeros(64, 2), obs[rows, 2:])
    assert torch.allclose(batch["velocity"][rows], expected, atol=1e-3)


def test_hispo_stream_with_a_goal_space_low_policy(tiny_umaze, tmp_path):
    results, run_dir = fit_tiny_stream(
        "hispo",
        tmp_path,
        ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"],
        "--data.low_inputs",
        "goal",
    )
    assert results["BWT"] == 0.0 and len(results["R"]) == 2
    module = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    assert module.backbone_config.low_velocity is True
