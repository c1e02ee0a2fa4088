"""``high_obs=False``: the high (and flat) policy sees the velocity of the sensed position in
the observation's place."""

from __future__ import annotations

import pytest
import torch
from helpers import fit_tiny_stream

from hispo_pl.config import BackboneConfig
from hispo_pl.data.datamodule import TaskDataModule
from hispo_pl.modules import GoalConditionedBC
from hispo_pl.modules.columns import NetworkPerTask
from hispo_pl.modules.hbc import HBC
from hispo_pl.modules.hispo import HiSPO
from hispo_pl.modules.pnn import PNN
from hispo_pl.nn.hierarchy import high_input, high_input_dim
from hispo_pl.nn.mlp import feature_dim

WIDTHS = {"high_hidden": 8, "low_hidden": 16, "dropout": 0.0}


def _batch(observation_seed: int, velocity_seed: int = 5, n: int = 32) -> dict:
    g = torch.Generator().manual_seed(1)
    batch = {k: torch.randn(n, 2, generator=g) for k in ("position", "goal", "subgoal", "action")}
    batch["observation"] = torch.randn(
        n, 4, generator=torch.Generator().manual_seed(observation_seed)
    )
    batch["velocity"] = torch.randn(n, 2, generator=torch.Generator().manual_seed(velocity_seed))
    return batch


def _high_loss(module: GoalConditionedBC, batch: dict) -> torch.Tensor:
    torch.manual_seed(0)
    return module.losses(batch)["loss_high"]


@pytest.mark.parametrize("cls", [HBC, HiSPO, PNN, NetworkPerTask], ids=lambda c: c.__name__)
def test_goal_space_high_policy_reads_velocity_and_not_the_observation(cls):
    module = cls(4, 2, backbone=BackboneConfig(**WIDTHS, high_obs=False))
    assert module.reference_model().high.net.inp[0].in_features == feature_dim(2) + 2 + 4
    batch = _batch(2)
    assert torch.equal(_high_loss(module, batch), _high_loss(module, _batch(3)))
    assert not torch.equal(_high_loss(module, batch), _high_loss(module, _batch(2, 6)))
    with_obs = cls(4, 2, backbone=BackboneConfig(**WIDTHS))
    assert not torch.equal(_high_loss(with_obs, batch), _high_loss(with_obs, _batch(3)))


def test_goal_space_high_policy_acts_only_with_a_velocity():
    module = HBC(4, 2, backbone=BackboneConfig(**WIDTHS, high_obs=False, low_obs=False)).eval()
    obs, pos, goal = torch.randn(3, 4), torch.zeros(3, 2), torch.ones(3, 2)
    with pytest.raises(ValueError, match="high level reads the goal-space velocity"):
        module.act(obs, pos, goal)
    velocity = torch.randn(3, 2)
    action = module.act(obs, pos, goal, velocity=velocity)
    assert torch.equal(action, module.act(torch.randn(3, 4), pos, goal, velocity=velocity))


def test_flat_policy_follows_the_high_inputs():
    module = HBC(4, 2, backbone=BackboneConfig(kind="bc", **WIDTHS, high_obs=False))
    assert module.reference_model().policy.net.inp[0].in_features == high_input_dim(4, 2, False)
    x = high_input(torch.zeros(1, 4), torch.zeros(1, 2), torch.ones(1, 2), torch.full((1, 2), 7.0))
    assert x.shape[-1] == high_input_dim(4, 2, False) and (x[0, feature_dim(2) :][:2] == 7).all()


@pytest.mark.parametrize(
    ("task", "choice", "expected"),
    [
        ("pointmaze-umaze-N[3]", "family", True),
        ("antmaze-umaze-N[3]", "family", False),
        ("amazeville-HOOO[3]", "family", True),
        ("pointmaze-umaze-N[3]", "observation", True),
        ("antmaze-umaze-N[3]", "observation", True),
    ],
)
def test_datamodule_says_what_the_high_policy_sees(task, choice, expected):
    assert TaskDataModule(task, high_inputs=choice).high_obs is expected


def test_unknown_high_inputs_are_refused():
    with pytest.raises(ValueError, match="--data.high_inputs must be family or one of"):
        TaskDataModule("pointmaze-umaze-N[3]", high_inputs="pixels")


def test_observation_variant_reaches_the_goal_space_high_policy_on_pointmaze(tiny_umaze):
    """The same relabelled batch of U-N and U-PO: PointMaze senses its position through the
    observation, so a goal-space high policy's inputs differ too, while its targets (subgoal
    offsets in maze coordinates) do not."""
    policy = HBC(4, 2, backbone=BackboneConfig(**WIDTHS, high_obs=False)).reference_model()
    batches = {}
    for variant in ("N", "PO"):
        dm = TaskDataModule(
            f"pointmaze-umaze-{variant}[6]", batch_size=64, holdout=0.5, high_inputs="goal"
        )
        assert dm.high_obs is False
        dm.setup("fit")
        batches[variant] = dm.fixed_batches(1, seed=3)[0]
    assert not torch.equal(batches["N"]["observation"], batches["PO"]["observation"])
    x_n, target_n = policy.inputs("high", batches["N"])
    x_po, target_po = policy.inputs("high", batches["PO"])
    assert not torch.equal(x_n, x_po) and torch.equal(target_n, target_po)


def test_stream_links_the_family_high_inputs_into_the_model(tiny_umaze, tmp_path):
    results, run_dir = fit_tiny_stream(
        "hispo", tmp_path, ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
    )
    assert len(results["R"]) == 2
    module = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    assert module.backbone_config.high_obs is True  # PointMaze's family choice
    assert module.reference_model().high.net.inp[0].in_features == high_input_dim(4, 2, True)
