"""CSP, the paper's first ablation: IQL's losses, the subspace critic on a chain whose values
are known, the sampler's transitions, the extend rule, the module, and a stream end to end."""

from __future__ import annotations

import pytest
import torch

from hispo_pl.iql import expectile_loss, goal_reward, polyak_update, td_loss, td_target
from hispo_pl.nn.critic import CriticConfig, SubspaceCritic

pytestmark = pytest.mark.usefixtures("one_thread")


# --- IQL's losses --------------------------------------------------------------------------------


def test_expectile_loss_weighs_positive_residuals_by_tau():
    diff = torch.tensor([1.0, -2.0, 3.0, 0.0])
    # (0.8 * 1 + 0.2 * 4 + 0.8 * 9 + 0) / 4
    torch.testing.assert_close(expectile_loss(diff, 0.8), torch.tensor(8.8 / 4))
    torch.testing.assert_close(expectile_loss(diff, 0.5), 0.5 * diff.pow(2).mean())
    with pytest.raises(ValueError, match="expectile"):
        expectile_loss(diff, 1.0)


def test_expectile_loss_is_minimised_by_the_expectile():
    """The minimiser v of E[|τ − 1(q < v)| (q − v)²] over q ∈ {0, 1} (equal weights) solves
    τ (1 − v) = (1 − τ) v, i.e. v = τ: gradient descent finds it."""
    q = torch.tensor([0.0, 1.0])
    for tau in (0.5, 0.7, 0.9):
        v = torch.zeros((), requires_grad=True)
        opt = torch.optim.SGD([v], lr=0.5)
        for _ in range(300):
            opt.zero_grad()
            expectile_loss(q - v, tau).backward()
            opt.step()
        assert v.item() == pytest.approx(tau, abs=1e-4)


def test_td_target_and_loss():
    reward, done = torch.tensor([0.0, 1.0]), torch.tensor([0.0, 1.0])
    target = td_target(reward, done, torch.tensor([2.0, 5.0]), 0.9)
    torch.testing.assert_close(target, torch.tensor([1.8, 1.0]))  # done: no bootstrap
    twins = torch.tensor([[1.8, 0.8], [2.0, 1.0]])  # second estimate off by 1 then 0
    torch.testing.assert_close(td_loss(twins, target), torch.tensor(0.0 + 1.0 / 2 + 1.0 / 2))
    torch.testing.assert_close(td_loss(target + 1.0, target), torch.tensor(1.0))


def test_goal_reward_within_the_success_radius():
    goal = torch.zeros(3, 2)
    nxt = torch.tensor([[0.3, 0.0], [0.45, 0.0], [0.3, 0.4]])
    reward, done = goal_reward(nxt, goal, 0.45)
    assert reward.tolist() == [1.0, 1.0, 0.0] and torch.equal(reward, done)


def test_polyak_update_moves_the_target_by_the_rate():
    source, target = torch.nn.Linear(2, 1), torch.nn.Linear(2, 1)
    before = target.weight.detach().clone()
    polyak_update(target, source, 0.25)
    torch.testing.assert_close(target.weight, 0.75 * before + 0.25 * source.weight.detach())


def test_critic_config_rejects_unknown_settings():
    assert CriticConfig.from_dict({"expectile": 0.9}).expectile == 0.9
    with pytest.raises(ValueError, match="known: "):
        CriticConfig.from_dict({"tau": 0.9})


def test_the_critic_learns_the_values_of_a_chain():
    """A deterministic chain 0 → 1 → … → N with reward 1 on reaching N (done there): one
    action per state, so V(k) = Q(k) = γ^(N−1−k) for k < N, whatever the expectile."""
    torch.manual_seed(0)
    n, gamma = 5, 0.8
    eye = torch.eye(n + 1)
    x, next_x = eye[:n], eye[1:]
    reward = done = (torch.arange(n) == n - 1).float()
    action, alpha = torch.zeros(n, 1), torch.ones(n, 1)
    critic = SubspaceCritic(state_dim=n + 1, action_dim=1, alpha_dim=1, hidden=32)
    opt = torch.optim.Adam([p for p in critic.parameters() if p.requires_grad], lr=3e-3)
    for _ in range(600):
        out = critic.losses(x, action, alpha, next_x, reward, done, gamma, expectile=0.7)
        opt.zero_grad()
        (out["loss_v"] + out["loss_q"]).backward()
        opt.step()
        critic.update_targets(0.05)
    expected = torch.tensor([gamma ** (n - 1 - k) for k in range(n)])
    with torch.no_grad():
        torch.testing.assert_close(critic.value(x, alpha), expected, atol=0.03, rtol=0)
        torch.testing.assert_close(critic.q(x, action, alpha), expected, atol=0.03, rtol=0)
