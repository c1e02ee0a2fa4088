"""CSP, the paper's first ablation: IQL's losses, the subspace critic on a chain whose values
are known, the sampler's transitions, the extend rule, the module, and a stream end to end."""

from __future__ import annotations

import math

import pytest
import torch
from helpers import fit_tiny_stream

from hispo_pl.callbacks import CriticEvaluation, CriticPruning
from hispo_pl.callbacks.anchors import check_task_end_order
from hispo_pl.callbacks.protocols import CriticScoredSubspaces
from hispo_pl.config import BackboneConfig
from hispo_pl.decisions import critic_extends
from hispo_pl.iql import expectile_loss, goal_reward, polyak_update, td_loss, td_target
from hispo_pl.metrics import module_bytes
from hispo_pl.modules import CSP, CSPO
from hispo_pl.modules.hbc import GoalConditionedBC
from hispo_pl.nn.hierarchy import high_input, low_input
from hispo_pl.nn.subspace_critic import CriticConfig, SubspaceCritic
from hispo_pl.results import CriticDecision, CriticSearchResult
from hispo_pl.rundir import RunDir

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
    assert CriticConfig.from_dict({"hidden": 32.0}).hidden == 32
    with pytest.raises(ValueError, match="integer"):
        CriticConfig.from_dict({"hidden": 32.5})
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


# --- the extend rule -----------------------------------------------------------------------------


def test_critic_extends_iff_the_new_value_beats_the_old_by_eps():
    assert critic_extends(1.2, 1.0, 0.1)  # 1.2 > 1.1
    assert not critic_extends(1.1, 1.0, 0.1)  # equal to (1 + eps) W_old: prune
    assert not critic_extends(1.05, 1.0, 0.1)
    assert not critic_extends(0.9, 1.0, 0.0)
    assert critic_extends(1.0 + 1e-6, 1.0, 0.0)
    # negative values: better by eps of the old value's size, never by less than W_old
    assert critic_extends(-0.8, -1.0, 0.1) and not critic_extends(-0.95, -1.0, 0.1)
    assert not critic_extends(-1.05, -1.0, 0.1)  # (1 + eps) W_old = -1.1 would have extended
    assert critic_extends(0.01, 0.0, 0.5) and not critic_extends(0.0, 0.0, 0.5)
    with pytest.raises(ValueError, match="eps"):
        critic_extends(1.0, 1.0, -0.1)


# --- the module ----------------------------------------------------------------------------------

SIZES = {"obs_dim": 4, "action_dim": 2, "backbone": BackboneConfig(high_hidden=8, low_hidden=16)}


def _module(seed: int = 0, **kw) -> CSP:
    torch.manual_seed(seed)
    return CSP(**SIZES, critic={"hidden": 16}, **kw)


def _batch(n: int = 12, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    dims = {"observation": 4, "position": 2, "velocity": 2, "goal": 2, "subgoal": 2, "action": 2}
    dims |= {"next_observation": 4, "next_position": 2}
    return {k: torch.randn(n, d, generator=g) for k, d in dims.items()}


def _grown(seed: int = 0) -> CSP:
    """A second task in progress: two anchor pairs, the newest moved away, a fresh critic."""
    m = _module(seed)
    m.set_task_alpha(0, "policy", torch.ones(1))
    m.freeze_all()
    m.add_anchor("policy")
    g = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        for level in ("high", "low"):
            for name, p in m.policies[level].named_parameters():
                if name.endswith(".1"):
                    p.add_(0.5 * torch.randn(p.shape, generator=g))
    m.task_index = 1
    m.setup("fit")
    return m


def test_a_fresh_critic_per_task_over_the_grown_subspace_left_out_of_mem():
    m = _module()
    assert isinstance(m, CriticScoredSubspaces) and m.critic.alpha_dim == 1
    policy_only = module_bytes(CSPO(**SIZES))
    assert module_bytes(m) == policy_only  # the critic is stored, not counted
    assert module_bytes(m.critic) > 0 and any(k.startswith("critic.") for k in m.state_dict())
    first = m.critic
    m.add_anchor("policy")
    m.setup("fit")
    assert m.critic is not first and m.critic.alpha_dim == 2
    assert all(p.requires_grad for p in m.critic.q1.parameters())
    assert not any(p.requires_grad for p in m.critic.q1_target.parameters())


def test_losses_train_the_newest_anchor_and_the_critic_and_need_transitions():
    m = _grown()
    out = m.losses(_batch())
    assert {"loss_bc", "critic_loss_v", "critic_loss_q", "critic_reward"} <= set(out)
    torch.testing.assert_close(
        out["loss"], out["loss_bc"] + out["critic_loss_v"] + out["critic_loss_q"]
    )
    out["loss"].backward()
    assert m.critic.v.head.weight.grad.abs().sum() > 0
    assert m.critic.q1.head.weight.grad.abs().sum() > 0
    newest = dict(m.policies["low"].net.named_parameters())["head.weights.1"]
    assert newest.grad.abs().sum() > 0
    batch = _batch()
    del batch["next_observation"]
    with pytest.raises(ValueError, match="--data.transitions true"):
        m.losses(batch)


def test_critic_values_are_the_mean_q_of_the_mixed_policys_action():
    m = _grown().eval()
    batch = _batch(9)
    alphas = torch.tensor([[1.0, 0.0], [0.3, 0.7], [0.0, 1.0]])
    values = m.critic_values(alphas, batch, chunk=2)
    assert values.shape == (3,) and len(set(values.tolist())) == 3
    x = high_input(batch["observation"], batch["position"], batch["goal"])
    with torch.no_grad():
        for alpha, value in zip(alphas, values, strict=True):
            offset, _ = m.policies["high"](x, alpha)
            action, _ = m.policies["low"](low_input(batch["observation"], offset), alpha)
            q = m.critic.q(x, action, alpha.expand(9, 2))
            torch.testing.assert_close(value, q.mean())
    # a point of the pruned subspace is valued as the grown one's with a 0 weight
    m.prune_last_anchor("policy")
    torch.testing.assert_close(m.critic_values(torch.ones(1, 1), batch), values[:1])


def test_the_diagnostic_compares_spreads_over_actions_and_states():
    m = _grown().eval()
    d = m.critic_diagnostic(torch.tensor([0.5, 0.5]), _batch(32), n_actions=8)
    assert set(d) == {
        "q_action_std",
        "q_state_std",
        "action_dependence",
        "q_data",
        "q_policy",
        "q_uniform",
    }
    assert d["q_action_std"] > 0 and d["q_state_std"] > 0
    assert d["action_dependence"] == pytest.approx(d["q_action_std"] / d["q_state_std"])


@pytest.mark.parametrize(
    ("w_curr", "decision", "anchors", "alpha"),
    [(1.2, "keep", 2, [0.3, 0.7]), (1.05, "prune", 1, [1.0])],
)
def test_critic_pruning_applies_the_rule(w_curr, decision, anchors, alpha):
    m = _grown()
    res = CriticSearchResult(
        w_curr=w_curr,
        alpha_curr=[0.3, 0.7],
        w_prev=1.0,
        alpha_prev=[1.0, 0.0],
        l_curr=0.5,
        l_prev=0.6,
        action_dependence=0.01,
    )
    d = CriticPruning(eps=0.1)._decide(m, "policy", res)
    assert (d.decision, d.anchors, d.rule, d.eps) == (decision, anchors, "critic", 0.1)
    assert (d.w_curr, d.w_prev, d.action_dependence) == (w_curr, 1.0, 0.01)
    assert m.n_anchors("policy") == anchors
    assert m.task_alphas("policy")[1].tolist() == pytest.approx(alpha)


def test_critic_callbacks_check_the_module_and_their_order():
    with pytest.raises(TypeError, match="CriticScoredSubspaces protocol"):
        CriticEvaluation().setup(None, CSPO(**SIZES), "fit")
    pruning = CriticPruning()
    with pytest.raises(ValueError, match="CriticEvaluation callback listed before"):
        check_task_end_order([pruning, CriticEvaluation()], pruning, CriticEvaluation)


# --- a tiny stream end to end ---------------------------------------------------------------------


@pytest.mark.e2e
def test_csp_end_to_end_through_the_cli(tiny_umaze, tmp_path):
    results, run_dir = fit_tiny_stream("csp", tmp_path)
    assert len(results["R"]) == 2 and results["BWT"] == 0.0
    assert results["anchors"]["policy"] in (1, 2) and results["MEM"] > 0
    records = RunDir(run_dir).decisions()
    assert all(isinstance(d, CriticDecision) for d in records)
    assert [(d.task, d.subspace, d.rule) for d in records] == [
        (0, "policy", "critic"),
        (1, "policy", "critic"),
    ]
    assert records[0].decision == "first" and records[0].w_prev is None
    assert records[1].decision in ("keep", "prune")
    for d in records:
        assert math.isfinite(d.w_curr) and math.isfinite(d.l_curr)
        for key in ("q_action_std", "q_state_std", "action_dependence", "q_policy"):
            assert math.isfinite(getattr(d, key)), key
    assert math.isfinite(records[1].w_prev) and len(records[1].alpha_prev) == 2

    module = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    assert type(module) is CSP and module.n_anchors("policy") == results["anchors"]["policy"]
    assert module.critic.alpha_dim == 2  # the second task's critic, over its grown subspace
    assert module_bytes(module) == results["stored_bytes"]
    b = _batch(5)
    obs = torch.randn(5, tiny_umaze.observations.shape[1])
    for task in (0, 1):
        action = module.act(obs, b["position"], b["goal"], task=task, velocity=b["velocity"])
        assert action.shape == (5, 2) and torch.isfinite(action).all()
    tags = set()
    for event in run_dir.glob("events.out.tfevents.*"):
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

        tags |= set(EventAccumulator(str(event)).Reload().Tags()["scalars"])
    assert {"critic/policy/W_curr", "critic/policy/action_dependence"} <= tags
