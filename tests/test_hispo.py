"""The HiSPO module: training with sampled anchor weights, growing and pruning subspaces,
stored per-task weights, scoring candidates, acting per task, and checkpoints."""

from __future__ import annotations

import copy

import pytest
import torch
from helpers import quiet_trainer
from torch.utils.data import DataLoader

import hispo_pl.modules.hispo as hispo_mod
from hispo_pl.config import BackboneConfig
from hispo_pl.modules.hispo import SUBSPACES, HiSPO, SubspacePolicy, training_alphas
from hispo_pl.nn.hierarchy import high_input, low_input
from hispo_pl.nn.mlp import gaussian_nll

SIZES = {"obs_dim": 4, "action_dim": 2, "backbone": BackboneConfig(high_hidden=8, low_hidden=16)}

pytestmark = pytest.mark.usefixtures("one_thread")


def _module(seed: int = 0, **kw) -> HiSPO:
    torch.manual_seed(seed)
    return HiSPO(**{**SIZES, **kw})


def _batch(n: int = 12, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    dims = {"observation": 4, "position": 2, "goal": 2, "subgoal": 2, "action": 2}
    return {k: torch.randn(n, d, generator=g) for k, d in dims.items()}


def _perturb_newest(module: HiSPO, subspace: str, seed: int = 1, scale: float = 0.3) -> None:
    """Move the newest anchor of a subspace away from the others (a "mean" anchor starts at
    their centre, and LayerNorm anchors start identical), so that mixing weights matter."""
    g = torch.Generator().manual_seed(seed)
    k = module.n_anchors(subspace) - 1
    with torch.no_grad():
        for name, p in module.policies[subspace].named_parameters():
            if name.endswith(f".{k}"):
                p.add_(scale * torch.randn(p.shape, generator=g))


def _params_of_anchor(module: HiSPO, subspace: str, k: int) -> set[str]:
    prefix = f"policies.{subspace}."
    return {n for n, _ in module.named_parameters() if n.startswith(prefix) and n.endswith(f".{k}")}


def _act(module: HiSPO, task: int | None, seed: int = 3) -> torch.Tensor:
    b = _batch(7, seed)
    module.eval()
    return module.act(b["observation"], b["position"], b["goal"], task=task)


# --- a fresh module ---------------------------------------------------------------------------


def test_fresh_module_has_one_anchor_per_subspace_and_is_a_subspace_policy():
    m = _module()
    assert isinstance(m, SubspacePolicy)
    assert m.subspace_names == SUBSPACES == ("high", "low")
    for name in SUBSPACES:
        assert m.n_anchors(name) == 1
        assert m.scores[name].shape == (1,)
        assert m.task_alphas(name).shape[0] == 0
    assert m.n_tasks == 0


def test_losses_are_finite_and_backward_reaches_anchors_and_scores():
    m = _module()
    m.train()
    out = m.losses(_batch(32))
    assert {"loss", "loss_high", "loss_low"} <= set(out)
    for v in out.values():
        assert v.dim() == 0 and torch.isfinite(v)
    torch.testing.assert_close(out["loss"], out["loss_high"] + out["loss_low"])
    out["loss"].backward()
    for name, p in m.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
    for name in SUBSPACES:
        first_layer = m.policies[name].net.inp_linear.weights[0]
        assert first_layer.grad.abs().sum() > 0
        assert m.scores[name].grad is not None  # one anchor: softmax is constant, grad is 0


def test_losses_with_cosine_regulariser():
    m = _module(cosine_weight=0.5)
    for name in SUBSPACES:
        m.add_anchor(name)
        _perturb_newest(m, name)
    out = m.losses(_batch(16))
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
    m = _module()
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
    m = _module()
    m.add_anchor("low")
    m.add_anchor("low")
    assert m.n_anchors("low") == 3
    low = {n for n, p in m.named_parameters() if p.requires_grad and n.startswith("policies.low")}
    assert low == _params_of_anchor(m, "low", 2)


def test_new_anchor_score_starts_the_task_near_the_new_anchor():
    even, leaning = _module(), _module(new_anchor_score=2.0)
    for m in (even, leaning):
        m.add_anchor("low")
        m.add_anchor("low")
    assert torch.allclose(even.current_alpha("low"), torch.full((3,), 1 / 3))
    alpha = training_alphas(leaning.scores["low"], groups=1, noise=0.0)[0]
    assert alpha[-1] > 0.9 and torch.allclose(alpha[:-1], alpha[0].expand(2))
    assert leaning.scores["low"].tolist() == [0.0, 0.0, 2.0]


def test_prune_last_anchor_undoes_add_anchor():
    m = _module()
    for name in SUBSPACES:
        m.set_task_alpha(0, name, torch.ones(1))
    m.add_anchor("high")
    m.set_task_alpha(1, "high", torch.tensor([0.25, 0.75]))
    m.add_anchor("high")
    _perturb_newest(m, "high")
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
    m = _module()
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

    fresh = _module()
    fresh.set_task_alpha(0, "low", torch.ones(1))
    with pytest.raises(ValueError, match="task 3 stored before"):
        fresh.set_task_alpha(3, "low", torch.ones(1))  # task 3 before tasks 1 and 2


def test_stored_alphas_are_buffers_in_the_state_dict():
    m = _module()
    m.set_task_alpha(0, "high", torch.ones(1))
    sd = m.state_dict()
    assert torch.equal(sd["task_alpha_high"], torch.ones(1, 1))
    assert "task_alpha_low" in sd
    assert not any(n.startswith("task_alpha") for n, _ in m.named_parameters())


# --- score_alphas -------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SUBSPACES)
def test_score_alphas_shape_and_non_negative_mse(name):
    m = _module()
    for seed in (1, 2):
        m.add_anchor(name)
        _perturb_newest(m, name, seed=seed)
    m.eval()
    alphas = torch.tensor([[1.0, 0.0, 0.0], [0.2, 0.3, 0.5], [0.0, 0.0, 1.0], [0.5, 0.5, 0.0]])
    losses = m.score_alphas(name, alphas, _batch(20))
    assert losses.shape == (4,)
    assert torch.all(losses >= 0) and torch.isfinite(losses).all()
    assert len(set(losses.tolist())) == 4  # distinct points, distinct losses
    nll = m.score_alphas(name, alphas, _batch(20), loss="nll")
    assert nll.shape == (4,) and not torch.equal(nll, losses)


@pytest.mark.parametrize("name", SUBSPACES)
def test_score_alphas_matches_a_manual_mse(name):
    m = _module()
    m.eval()
    batch = _batch(9)
    x, target = m.policies.inputs(name, batch)
    mean, _ = m.policies[name](x, torch.ones(1))
    expected = (mean - target).pow(2).sum(-1).mean()
    torch.testing.assert_close(m.score_alphas(name, torch.ones(1, 1), batch)[0], expected)


@pytest.mark.parametrize("name", SUBSPACES)
def test_first_vertex_scores_like_the_one_anchor_module(name):
    one = _module()
    two = copy.deepcopy(one)
    two.add_anchor(name)
    _perturb_newest(two, name, scale=1.0)
    one.eval()
    two.eval()
    batch = _batch(16)
    l_one = one.score_alphas(name, torch.ones(1, 1), batch)
    l_two = two.score_alphas(name, torch.tensor([[1.0, 0.0], [0.0, 1.0]]), batch)
    assert torch.equal(l_two[0], l_one[0])  # a zero weight leaves the first anchor exactly
    assert l_two[1] != l_one[0]  # the new anchor really is different


def test_batched_scoring_equals_single_candidates():
    m = _module()
    for _ in range(2):
        m.add_anchor("low")
        _perturb_newest(m, "low", seed=m.n_anchors("low"))
    m.eval()
    alphas = torch.distributions.Dirichlet(torch.ones(3)).sample((7,))
    batch = _batch(11)
    batched = m.score_alphas("low", alphas, batch, chunk=3)  # chunks of 3, 3, 1
    single = torch.cat([m.score_alphas("low", a[None], batch) for a in alphas])
    torch.testing.assert_close(batched, single)


def test_score_alphas_is_deterministic_in_training_mode():
    """The search's comparisons must not depend on dropout masks: scoring predicts
    deterministically even when the module is left in training mode."""
    m = _module(backbone=BackboneConfig(high_hidden=8, low_hidden=16, dropout=0.5))
    m.add_anchor("high")
    _perturb_newest(m, "high")
    m.train()
    alphas = torch.tensor([[1.0, 0.0], [0.4, 0.6]])
    batch = _batch(16)
    a = m.score_alphas("high", alphas, batch)
    b = m.score_alphas("high", alphas, batch)
    assert torch.equal(a, b)
    assert m.training  # the module's mode is left as it was
    m.eval()
    assert torch.equal(m.score_alphas("high", alphas, batch), a)


# --- acting -------------------------------------------------------------------------------------


def _two_task_module() -> HiSPO:
    m = _module()
    for name in SUBSPACES:
        m.set_task_alpha(0, name, torch.ones(1))
        m.add_anchor(name)
        _perturb_newest(m, name, scale=1.0)
        m.set_task_alpha(1, name, torch.tensor([0.2, 0.8]))
    m.task_index = 1
    return m


def _manual_act(m: HiSPO, alphas: dict[str, torch.Tensor], seed: int = 3) -> torch.Tensor:
    b = _batch(7, seed)
    with torch.no_grad():
        offset, _ = m.policies["high"](
            high_input(b["observation"], b["position"], b["goal"]), alphas["high"]
        )
        action, _ = m.policies["low"](low_input(b["observation"], offset), alphas["low"])
    return action


def test_act_uses_the_stored_weights_of_the_task():
    m = _two_task_module()
    a0, a1 = _act(m, 0), _act(m, 1)
    assert a0.shape == (7, 2)
    assert not torch.allclose(a0, a1)
    torch.testing.assert_close(
        a0, _manual_act(m, {"high": m.task_alphas("high")[0], "low": m.task_alphas("low")[0]})
    )
    row1 = {n: torch.tensor([0.2, 0.8]) for n in SUBSPACES}
    torch.testing.assert_close(a1, _manual_act(m, row1))
    assert torch.equal(_act(m, None), a1)  # defaults to the module's task_index


def test_act_on_an_unfinished_task_uses_the_current_scores():
    m = _two_task_module()
    m.task_index = 2
    with torch.no_grad():
        for name in SUBSPACES:
            m.scores[name].copy_(torch.tensor([1.0, -1.0]))
    current = {n: torch.softmax(torch.tensor([1.0, -1.0]), -1) for n in SUBSPACES}
    torch.testing.assert_close(m.current_alpha("high"), current["high"])
    torch.testing.assert_close(_act(m, None), _manual_act(m, current))
    torch.testing.assert_close(_act(m, 5), _manual_act(m, current))


def test_act_is_deterministic_in_eval_mode_and_leaves_rows_alone():
    m = _two_task_module()
    rows = m.task_alphas("low").clone()
    assert torch.equal(_act(m, 0), _act(m, 0))
    assert torch.equal(m.task_alphas("low"), rows)


# --- grouped training forward -----------------------------------------------------------------


@pytest.mark.parametrize(("batch_size", "groups"), [(18, 9), (17, 1), (10, 10), (32, 16)])
def test_grouped_forward_with_indivisible_batch(monkeypatch, batch_size, groups):
    seen = []

    def recording(scores, g, noise, generator=None):
        seen.append(g)
        return training_alphas(scores, g, noise, generator)

    monkeypatch.setattr(hispo_mod, "training_alphas", recording)
    m = _module(alpha_groups=16)
    m.add_anchor("high")
    _perturb_newest(m, "high")  # identical anchors would leave the scores without gradient
    out = m.losses(_batch(batch_size))
    assert seen == [groups, groups]  # high, then low
    assert torch.isfinite(out["loss"])
    out["loss"].backward()
    assert m.scores["high"].grad.abs().sum() > 0


def test_grouped_forward_without_noise_equals_a_plain_forward():
    m = _module(
        alpha_groups=4,
        alpha_noise=0.0,
        backbone=BackboneConfig(high_hidden=8, low_hidden=16, dropout=0.0),
    )
    for name in SUBSPACES:
        m.add_anchor(name)
        _perturb_newest(m, name)
        with torch.no_grad():
            m.scores[name].copy_(torch.tensor([0.7, -0.2]))
    batch = _batch(18)  # 18 is not divisible by 4: 3 groups of 6
    out = m.losses(batch)
    for name in SUBSPACES:
        x, target = m.policies.inputs(name, batch)
        alpha = torch.softmax(2 * torch.tanh(m.scores[name].detach()), -1)
        mean, log_std = m.policies[name](x, alpha)
        torch.testing.assert_close(out[f"loss_{name}"], gaussian_nll(mean, log_std, target))


# --- checkpoints --------------------------------------------------------------------------------


def _three_task_module() -> HiSPO:
    """3 high anchors, 2 low anchors (the low extension of task 3 pruned), 3 stored tasks."""
    m = _module(seed=5)
    for name in SUBSPACES:
        m.set_task_alpha(0, name, torch.ones(1))
    m.freeze_all()
    for name in SUBSPACES:
        m.add_anchor(name)
        _perturb_newest(m, name, seed=11)
    m.set_task_alpha(1, "high", torch.tensor([0.4, 0.6]))
    m.set_task_alpha(1, "low", torch.tensor([0.3, 0.7]))
    m.freeze_all()
    for name in SUBSPACES:
        m.add_anchor(name)
        _perturb_newest(m, name, seed=12)
    m.set_task_alpha(2, "high", torch.tensor([0.2, 0.3, 0.5]))
    m.prune_last_anchor("low")
    m.set_task_alpha(2, "low", torch.tensor([0.5, 0.5]))
    m.task_index = 2
    return m


def _saved_by_trainer(module: HiSPO, path) -> None:
    """A short real fit (so the newest anchors and the scores have trained values), then
    ``trainer.save_checkpoint`` exactly as the ContinualLoop does."""
    batches = [_batch(16, seed=s) for s in range(3)]
    trainer = quiet_trainer(max_steps=3)
    trainer.fit(module, train_dataloaders=DataLoader(batches, batch_size=None))
    trainer.save_checkpoint(path)


def test_checkpoint_round_trip_restores_structure_and_every_task(tmp_path):
    m = _three_task_module()
    m.add_anchor("high")  # a fourth, trainable high anchor, trained by the fit below
    path = tmp_path / "task_03.ckpt"
    _saved_by_trainer(m, path)
    assert (m.n_anchors("high"), m.n_anchors("low"), m.n_tasks) == (4, 2, 3)

    raw = torch.load(path, map_location="cpu", weights_only=True)
    assert raw["hispo_pl_task_index"] == 2
    assert raw["hispo_pl_class"] == "hispo_pl.modules.hispo.HiSPO"

    fresh = _module(seed=99)
    assert fresh.n_anchors("high") == fresh.n_anchors("low") == 1
    fresh.load_checkpoint_file(path)
    assert fresh.task_index == 2
    for name in SUBSPACES:
        assert fresh.n_anchors(name) == m.n_anchors(name)
        assert torch.equal(fresh.task_alphas(name), m.task_alphas(name))
        assert torch.equal(fresh.scores[name], m.scores[name])
    expected_sd, loaded_sd = m.state_dict(), fresh.state_dict()
    assert expected_sd.keys() == loaded_sd.keys()
    for k, v in expected_sd.items():
        assert torch.equal(loaded_sd[k], v), k
    for task in (0, 1, 2, None):
        assert torch.equal(_act(fresh, task), _act(m, task)), task

    classmethod_loaded = HiSPO.load_from_checkpoint(path, map_location="cpu")
    assert classmethod_loaded.backbone_config == SIZES["backbone"]
    assert classmethod_loaded.task_index == 2
    for task in (0, 1, 2):
        assert torch.equal(_act(classmethod_loaded, task), _act(m, task)), task


def test_load_into_a_larger_module_shrinks_it(tmp_path):
    m = _three_task_module()
    path = tmp_path / "task_03.ckpt"
    _saved_by_trainer(m, path)
    big = _module(seed=1)
    for _ in range(4):
        big.add_anchor("low")
    big.load_checkpoint_file(path)
    assert (big.n_anchors("high"), big.n_anchors("low")) == (3, 2)
    for task in (0, 1, 2):
        assert torch.equal(_act(big, task), _act(m, task))


@pytest.mark.parametrize("seed", [0, 1])
def test_anchors_added_later_leave_a_finished_task_bit_identical(seed):
    """A finished task's weights get a 0 for every later anchor; its actions must not change by
    a single bit (BWT exactly 0). Mixing the zero-weighted anchors too changes the rounding of
    the sum (7e-7 here), enough to flip a rollout of a 600-step episode."""
    torch.manual_seed(seed)
    m = HiSPO(4, 2, backbone=BackboneConfig(high_log_std=0.0)).eval()  # the method config's widths
    for name in SUBSPACES:
        m.set_task_alpha(0, name, torch.ones(1))
        m.add_anchor(name)
        m.set_task_alpha(1, name, torch.softmax(torch.randn(2), 0))
    g = torch.Generator().manual_seed(0)
    obs, pos, goal = (torch.randn(1000, d, generator=g) for d in (4, 2, 2))
    before = m.act(obs, pos, goal, task=1)
    for _ in range(2):  # two later tasks
        for name in SUBSPACES:
            m.add_anchor(name)
    assert torch.equal(m.act(obs, pos, goal, task=1), before)
