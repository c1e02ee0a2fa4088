"""Gamepad buttons: the low policy's first ``binary_actions`` outputs are Bernoulli logits
(cross-entropy loss, pressed iff p > 1/2) and the rest Gaussian, in every method."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from hispo_pl.config import BackboneConfig
from hispo_pl.modules import CSPO, HBC, PNN, HiLOW, HiSPO
from hispo_pl.modules.columns import NetworkPerTask
from hispo_pl.modules.hbc import BC
from hispo_pl.modules.regularized import RegularizedFineTuning
from hispo_pl.nn.mlp import GaussianPolicy

OBS, ACT, GOAL, BUTTONS = 5, 8, 3, 6


def test_mixed_nll_act_and_prediction():
    policy = GaussianPolicy(4, 8, 3, binary=2)
    mean = torch.tensor([[2.0, -1.0, 0.3], [-0.5, 0.0, -0.2]])
    log_std = torch.tensor([[9.0, 9.0, -1.0], [9.0, 9.0, 0.5]])  # binary log-stds unused
    target = torch.tensor([[1.0, 0.0, 0.1], [1.0, 1.0, 0.0]])
    bce = F.binary_cross_entropy_with_logits(mean[:, :2], target[:, :2], reduction="none").sum(-1)
    z = (target[:, 2] - mean[:, 2]) / log_std[:, 2].exp()
    gauss = 0.5 * z**2 + log_std[:, 2] + 0.5 * math.log(2 * math.pi)
    torch.testing.assert_close(policy.nll(mean, log_std, target), bce + gauss)
    torch.testing.assert_close(policy.loss(mean, log_std, target), (bce + gauss).mean())
    unnormalised = policy.nll(mean, log_std, target, normalised=False)
    torch.testing.assert_close(unnormalised, bce + gauss - 0.5 * math.log(2 * math.pi))
    expected_act = torch.tensor([[1.0, 0.0, 0.3], [0.0, 0.0, -0.2]])  # p = 1/2: released
    torch.testing.assert_close(policy.act(mean), expected_act)
    torch.testing.assert_close(policy.prediction(mean)[:, :2], torch.sigmoid(mean[:, :2]))
    torch.testing.assert_close(policy.prediction(mean)[:, 2], mean[:, 2])
    plain = GaussianPolicy(4, 8, 3)
    assert plain.act(mean) is mean and plain.prediction(mean) is mean
    with pytest.raises(ValueError, match="binary"):
        GaussianPolicy(4, 8, 3, binary=4)


def _batch(n: int = 256, seed: int = 0) -> dict[str, torch.Tensor]:
    """Buttons that depend on the observation (press i iff obs_i > 0) and a rotation that is
    the unit vector of the first two observation values: learnable from the inputs."""
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(n, OBS, generator=g)
    pos, goal = torch.randn(n, GOAL, generator=g), torch.randn(n, GOAL, generator=g)
    buttons = (torch.cat([obs, obs[:, :1]], dim=1) > 0).float()
    rotation = F.normalize(obs[:, :2], dim=-1)
    return {
        "observation": obs,
        "position": pos,
        "goal": goal,
        "subgoal": pos + 0.1 * torch.randn(n, GOAL, generator=g),
        "action": torch.cat([buttons, rotation], dim=1),
    }


NET = BackboneConfig(high_hidden=16, low_hidden=64, binary_actions=BUTTONS)
FLAT = BackboneConfig(kind="bc", low_hidden=64, binary_actions=BUTTONS)
MODULES = {
    "hbc": lambda: HBC(OBS, ACT, GOAL, NET),
    "bc": lambda: BC(OBS, ACT, GOAL, backbone=FLAT),
    "hispo": lambda: HiSPO(OBS, ACT, GOAL, NET),
    "cspo": lambda: CSPO(OBS, ACT, GOAL, NET),
    "hilow": lambda: HiLOW(OBS, ACT, GOAL, NET, rank=2),
    "pnn": lambda: PNN(OBS, ACT, GOAL, NET),
    "bc-pnn": lambda: PNN(OBS, ACT, GOAL, FLAT),
    "scn": lambda: NetworkPerTask(OBS, ACT, GOAL, NET),
    "ewc": lambda: RegularizedFineTuning(OBS, ACT, GOAL, NET),
}


@pytest.mark.parametrize("name", list(MODULES))
def test_every_method_learns_buttons_and_presses_them(name):
    torch.manual_seed(0)
    module = MODULES[name]()
    batch = _batch()
    params = [p for p in module.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=3e-3)
    module.train()
    first = None
    for _ in range(150):
        loss = module.losses(batch)["loss"]
        first = loss.item() if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < first - 1.0
    module.eval()
    test = _batch(512, seed=1)
    action = module.act(test["observation"], test["position"], test["goal"])
    buttons = action[:, :BUTTONS]
    assert set(buttons.unique().tolist()) <= {0.0, 1.0}
    accuracy = (buttons == test["action"][:, :BUTTONS]).float().mean().item()
    assert accuracy > 0.9, accuracy
    # the rotation stays continuous, and is learnt
    assert not set(action[:, BUTTONS:].unique().tolist()) <= {0.0, 1.0}
    cosine = F.cosine_similarity(action[:, BUTTONS:], test["action"][:, BUTTONS:]).mean().item()
    assert cosine > 0.7, cosine


def test_reference_model_has_the_same_head():
    module = HiSPO(OBS, ACT, GOAL, NET)
    assert module.reference_model().low.binary == BUTTONS
    assert BC(OBS, ACT, GOAL, backbone=FLAT).reference_model().policy.binary == 6


def test_search_scores_buttons_by_probability():
    """The squared-error score compares button probabilities with the data, so a weight vector
    whose logits are right but over-confident is not punished as if logits were actions."""
    torch.manual_seed(0)
    module = HiSPO(OBS, ACT, GOAL, NET)
    batch = _batch(64)
    alphas = torch.ones(1, 1)
    low = module.policies["low"]
    with torch.no_grad():
        low.eval()
        x, target = module.policies.inputs("low", batch)
        mean, _ = low(x, alphas)
    expected = (low.prediction(mean.float()) - target).pow(2).sum(-1).mean(-1)
    scored = module.score_alphas("low", alphas, batch, loss="mse")
    torch.testing.assert_close(scored, expected)
    raw = (mean - target).pow(2).sum(-1).mean(-1)
    assert not torch.allclose(scored, raw)
