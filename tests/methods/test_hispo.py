"""The HiSPO module: training with sampled anchor weights, growing and pruning subspaces,
stored per-task weights and scoring candidates (acting and checkpoints: test_hispo_tasks.py)."""

from __future__ import annotations

import copy

import pytest
import torch
from helpers import FLOAT32_REORDERED, SUBSPACE_PROTOCOLS, perturb_newest, random_batch, tiny_hispo

from hispo_pl.config import BackboneConfig
from hispo_pl.modules.hispo import SUBSPACES, HiSPO, training_alphas


def _params_of_anchor(module: HiSPO, subspace: str, k: int) -> set[str]:
    prefix = f"policies.{subspace}."
    return {n for n, _ in module.named_parameters() if n.startswith(prefix) and n.endswith(f".{k}")}


# --- a fresh module ---------------------------------------------------------------------------


def test_fresh_module_has_one_anchor_per_subspace_and_is_a_subspace_policy():
    m = tiny_hispo()
    assert all(isinstance(m, p) for p in SUBSPACE_PROTOCOLS)
    assert m.subspace_names == SUBSPACES == ("high", "low")
    for name in SUBSPACES:
        assert m.n_anchors(name) == 1
        assert m.scores[name].shape == (1,)
        assert m.task_alphas(name).shape[0] == 0
    assert m.n_tasks == 0


def test_losses_are_finite_and_backward_reaches_anchors_and_scores():
    m = tiny_hispo()
    m.train()
    out = m.losses(random_batch(32))
    assert {"loss", "loss_high", "loss_low"} <= set(out)
    for v in out.values():
        assert v.dim() == 0 and torch.isfinite(v)
    torch.testing.assert_close(out["loss"], out["loss_high"] + out["loss_low"])
    out["loss"].backward()
    for name, p in m.named_parameters():
        if name.startswith("scores."):  # one anchor: its weight is exactly 1, nothing to learn
            assert p.grad is None, name
            continue
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
    for name in SUBSPACES:
        first_layer = m.policies[name].net.inp_linear.weights[0]
        assert first_layer.grad.abs().sum() > 0
        m.add_anchor(name)
        perturb_newest(m, name)
    m.zero_grad()
    m.losses(random_batch(32))["loss"].backward()
    for name in SUBSPACES:
        assert m.scores[name].grad.abs().sum() > 0
        assert m.policies[name].net.inp_linear.weights[1].grad.abs().sum() > 0


def test_losses_with_cosine_regulariser():
    m = tiny_hispo(cosine_weight=0.5)
    for name in SUBSPACES:
        m.add_anchor(name)
        perturb_newest(m, name)
    out = m.losses(random_batch(16))
    assert out["cosine"] > 0
    expected = out["loss_high"] + out["loss_low"] + 0.5 * out["cosine"]
    torch.testing.assert_close(out["loss"], expected)


# --- training_alphas ------------------------------------------------------------------------


def test_training_alphas_rows_on_the_simplex_and_differentiable():
    scores = torch.tensor([0.3, -0.5, 1.2], requires_grad=True)
    generator = torch.Generator().manual_seed(0)
    alphas = training_alphas(scores, groups=5, noise=0.1, generator=generator)
    assert alphas.shape == (5, 3)
    assert torch.all(alphas > 0)
    torch.testing.assert_close(alphas.sum(-1), torch.ones(5))
    assert len({tuple(r) for r in alphas.tolist()}) == 5  # one noisy draw per group
    weights = torch.tensor([1.0, 2.0, 3.0])
    (alphas @ weights).sum().backward()
    assert scores.grad is not None and scores.grad.abs().sum() > 0


def test_training_alphas_without_noise_is_softmax_of_k_tanh_scores():
    scores = torch.tensor([0.3, -0.5, 1.2, 0.0])
    alphas = training_alphas(scores, groups=3, noise=0.0)
    expected = torch.softmax(4 * torch.tanh(scores), -1).expand(3, 4)
    torch.testing.assert_close(alphas, expected)


def test_training_alphas_deterministic_with_a_generator():
    scores = torch.zeros(3)
    a = training_alphas(scores, 4, 0.5, torch.Generator().manual_seed(1))
    b = training_alphas(scores, 4, 0.5, torch.Generator().manual_seed(1))
    assert torch.equal(a, b)


# --- growing and pruning ----------------------------------------------------------------------


def test_add_anchor_trains_only_the_newest_anchor_and_pads_stored_alphas():
    m = tiny_hispo()
    for name in SUBSPACES:
        m.set_task_alpha(0, name, torch.ones(1))
    m.freeze_all()
    assert not any(p.requires_grad for p in m.parameters())
    before = {n: p.detach().clone() for n, p in m.named_parameters() if n.startswith("policies")}

    m.add_anchor("high")
    assert m.n_anchors("high") == 2 and m.n_anchors("low") == 1
    trainable = {n for n, p in m.named_parameters() if p.requires_grad}
    assert trainable == _params_of_anchor(m, "high", 1) | {"scores.high"}
    assert m.scores["high"].shape == (2,) and torch.all(m.scores["high"] == 0)
    assert m.task_alphas("high").tolist() == [[1.0, 0.0]]
    assert m.task_alphas("low").tolist() == [[1.0]]
    for n, p in before.items():  # existing anchors untouched
        assert torch.equal(dict(m.named_parameters())[n], p), n
    # "mean" init: the newest anchor starts at the centre of the older ones (here: the one)
    net = m.policies["high"].net
    assert torch.equal(net.inp_linear.weights[1], net.inp_linear.weights[0])

    m.add_anchor("low")
    trainable = {n for n, p in m.named_parameters() if p.requires_grad}
    expected = _params_of_anchor(m, "high", 1) | _params_of_anchor(m, "low", 1)
    assert trainable == expected | {"scores.high", "scores.low"}
    assert m.task_alphas("low").tolist() == [[1.0, 0.0]]


def test_add_anchor_twice_freezes_the_previous_newest():
    m = tiny_hispo()
    m.add_anchor("low")
    m.add_anchor("low")
    assert m.n_anchors("low") == 3
    low = {n for n, p in m.named_parameters() if p.requires_grad and n.startswith("policies.low")}
    assert low == _params_of_anchor(m, "low", 2)


def test_new_anchor_score_starts_the_task_near_the_new_anchor():
    even, leaning = tiny_hispo(), tiny_hispo(new_anchor_score=2.0)
    for m in (even, leaning):
        m.add_anchor("low")
        m.add_anchor("low")
    assert torch.allclose(even.current_alpha("low"), torch.full((3,), 1 / 3))
    alpha = training_alphas(leaning.scores["low"], groups=1, noise=0.0)[0]
    assert alpha[-1] > 0.9 and torch.allclose(alpha[:-1], alpha[0].expand(2))
    assert leaning.scores["low"].tolist() == [0.0, 0.0, 2.0]


def test_prune_last_anchor_undoes_add_anchor():
    m = tiny_hispo()
    for name in SUBSPACES:
        m.set_task_alpha(0, name, torch.ones(1))
    m.add_anchor("high")
    m.set_task_alpha(1, "high", torch.tensor([0.25, 0.75]))
    m.add_anchor("high")
    perturb_newest(m, "high")
    state = {n: p.detach().clone() for n, p in m.named_parameters() if ".2" not in n[-2:]}
    assert m.task_alphas("high").shape == (2, 3)

    m.prune_last_anchor("high")
    assert m.n_anchors("high") == 2
    assert m.task_alphas("high").tolist() == [[1.0, 0.0], [0.25, 0.75]]
    assert m.scores["high"].shape == (2,)
    assert not any(p.requires_grad for p in m.policies["high"].parameters())
    for n, p in m.named_parameters():
        if n.startswith("policies.high"):
            assert torch.equal(p, state[n]), n  # the kept anchors are unchanged

    m.prune_last_anchor("high")  # stored rows lose their last coordinate, whatever it held
    assert m.n_anchors("high") == 1
    assert m.task_alphas("high").tolist() == [[1.0], [0.25]]
    with pytest.raises(RuntimeError, match="only anchor"):
        m.prune_last_anchor("high")


# --- stored task weights ----------------------------------------------------------------------


def test_set_task_alpha_appends_overwrites_and_validates():
    m = tiny_hispo()
    m.add_anchor("high")
    m.set_task_alpha(0, "high", torch.tensor([1.0, 0.0]))
    m.set_task_alpha(1, "high", torch.tensor([0.3, 0.7]))
    torch.testing.assert_close(m.task_alphas("high"), torch.tensor([[1.0, 0.0], [0.3, 0.7]]))
    m.set_task_alpha(0, "high", torch.tensor([0.6, 0.4]))  # overwrite an existing row
    torch.testing.assert_close(m.task_alphas("high"), torch.tensor([[0.6, 0.4], [0.3, 0.7]]))
    assert m.n_tasks == 2

    with pytest.raises(ValueError, match="3 entries, high has 2 anchors"):
        m.set_task_alpha(2, "high", torch.tensor([0.2, 0.3, 0.5]))
    with pytest.raises(ValueError, match="task 3 stored before"):
        m.set_task_alpha(3, "high", torch.tensor([0.5, 0.5]))
    assert m.task_alphas("high").shape == (2, 2)  # failed calls change nothing

    fresh = tiny_hispo()
    fresh.set_task_alpha(0, "low", torch.ones(1))
    with pytest.raises(ValueError, match="task 3 stored before"):
        fresh.set_task_alpha(3, "low", torch.ones(1))  # task 3 before tasks 1 and 2


def test_stored_alphas_are_buffers_in_the_state_dict():
    m = tiny_hispo()
    m.set_task_alpha(0, "high", torch.ones(1))
    sd = m.state_dict()
    assert torch.equal(sd["task_alpha_high"], torch.ones(1, 1))
    assert "task_alpha_low" in sd
    assert not any(n.startswith("task_alpha") for n, _ in m.named_parameters())


# --- score_alphas -------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SUBSPACES)
def test_score_alphas_shape_and_non_negative_mse(name):
    m = tiny_hispo()
    for seed in (1, 2):
        m.add_anchor(name)
        perturb_newest(m, name, seed=seed)
    m.eval()
    alphas = torch.tensor([[1.0, 0.0, 0.0], [0.2, 0.3, 0.5], [0.0, 0.0, 1.0], [0.5, 0.5, 0.0]])
    losses = m.score_alphas(name, alphas, random_batch(20))
    assert losses.shape == (4,)
    assert torch.all(losses >= 0) and torch.isfinite(losses).all()
    assert len(set(losses.tolist())) == 4  # distinct points, distinct losses
    nll = m.score_alphas(name, alphas, random_batch(20), loss="nll")
    assert nll.shape == (4,) and not torch.equal(nll, losses)


@pytest.mark.parametrize("name", SUBSPACES)
def test_score_alphas_matches_a_manual_mse(name):
    m = tiny_hispo()
    m.eval()
    batch = random_batch(9)
    x, target = m.policies.inputs(name, batch)
    mean, _ = m.policies[name](x, torch.ones(1))
    expected = (mean - target).pow(2).sum(-1).mean()
    torch.testing.assert_close(m.score_alphas(name, torch.ones(1, 1), batch)[0], expected)


@pytest.mark.parametrize("name", SUBSPACES)
def test_first_vertex_scores_like_the_one_anchor_module(name):
    """The vertex of the first anchor scores what the one-anchor module scores, to float32
    rounding: its mixed weights are the first anchor's exactly (1·θ₁ + 0·θ₂), but two
    candidates run one batched matmul of batch 2 instead of 1, which some CPUs' BLAS sums in
    another order (``helpers.FLOAT32_REORDERED``)."""
    one = tiny_hispo()
    two = copy.deepcopy(one)
    two.add_anchor(name)
    perturb_newest(two, name, scale=1.0)
    one.eval()
    two.eval()
    batch = random_batch(16)
    l_one = one.score_alphas(name, torch.ones(1, 1), batch)
    l_two = two.score_alphas(name, torch.tensor([[1.0, 0.0], [0.0, 1.0]]), batch)
    torch.testing.assert_close(l_two[0], l_one[0], **FLOAT32_REORDERED)
    assert not torch.allclose(l_two[1], l_one[0], rtol=1e-3)  # the new anchor really differs


def test_batched_scoring_equals_single_candidates():
    m = tiny_hispo()
    for _ in range(2):
        m.add_anchor("low")
        perturb_newest(m, "low", seed=m.n_anchors("low"))
    m.eval()
    alphas = torch.distributions.Dirichlet(torch.ones(3)).sample((7,))
    batch = random_batch(11)
    batched = m.score_alphas("low", alphas, batch, chunk=3)  # chunks of 3, 3, 1
    single = torch.cat([m.score_alphas("low", a[None], batch) for a in alphas])
    torch.testing.assert_close(batched, single)


def test_score_alphas_is_deterministic_in_training_mode():
    """The search's comparisons must not depend on dropout masks: scoring predicts
    deterministically even when the module is left in training mode."""
    m = tiny_hispo(backbone=BackboneConfig(high_hidden=8, low_hidden=16, dropout=0.5))
    m.add_anchor("high")
    perturb_newest(m, "high")
    m.train()
    alphas = torch.tensor([[1.0, 0.0], [0.4, 0.6]])
    batch = random_batch(16)
    a = m.score_alphas("high", alphas, batch)
    b = m.score_alphas("high", alphas, batch)
    assert torch.equal(a, b)
    assert m.training  # the module's mode is left as it was
    m.eval()
    assert torch.equal(m.score_alphas("high", alphas, batch), a)
