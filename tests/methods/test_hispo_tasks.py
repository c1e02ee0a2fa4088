"""HiSPO across tasks: acting with each task's stored weights, the grouped training forward,
and checkpoints that restore every task."""

from __future__ import annotations

import pytest
import torch
from helpers import (
    HISPO_SIZES,
    act_on,
    grow_three_tasks,
    perturb_newest,
    quiet_trainer,
    random_batch,
    tiny_hispo,
)
from torch.utils.data import DataLoader

import hispo_pl.modules.hispo as hispo_mod
from hispo_pl.config import BackboneConfig
from hispo_pl.modules.hispo import SUBSPACES, HiSPO, training_alphas
from hispo_pl.nn.hierarchy import high_input, low_input
from hispo_pl.nn.mlp import gaussian_nll

# --- acting -------------------------------------------------------------------------------------


def _two_task_module() -> HiSPO:
    m = tiny_hispo()
    for name in SUBSPACES:
        m.set_task_alpha(0, name, torch.ones(1))
        m.add_anchor(name)
        perturb_newest(m, name, scale=1.0)
        m.set_task_alpha(1, name, torch.tensor([0.2, 0.8]))
    m.task_index = 1
    return m


def _manual_act(m: HiSPO, alphas: dict[str, torch.Tensor], seed: int = 3) -> torch.Tensor:
    b = random_batch(7, seed)
    with torch.no_grad():
        offset, _ = m.policies["high"](
            high_input(b["observation"], b["position"], b["goal"]), alphas["high"]
        )
        action, _ = m.policies["low"](low_input(b["observation"], offset), alphas["low"])
    return action


def test_act_uses_the_stored_weights_of_the_task():
    m = _two_task_module()
    a0, a1 = act_on(m, 0), act_on(m, 1)
    assert a0.shape == (7, 2)
    assert not torch.allclose(a0, a1)
    torch.testing.assert_close(
        a0, _manual_act(m, {"high": m.task_alphas("high")[0], "low": m.task_alphas("low")[0]})
    )
    row1 = {n: torch.tensor([0.2, 0.8]) for n in SUBSPACES}
    torch.testing.assert_close(a1, _manual_act(m, row1))
    assert torch.equal(act_on(m, None), a1)  # defaults to the module's task_index


def test_act_on_an_unfinished_task_uses_the_current_scores():
    m = _two_task_module()
    m.task_index = 2
    with torch.no_grad():
        for name in SUBSPACES:
            m.scores[name].copy_(torch.tensor([1.0, -1.0]))
    current = {n: torch.softmax(torch.tensor([1.0, -1.0]), -1) for n in SUBSPACES}
    torch.testing.assert_close(m.current_alpha("high"), current["high"])
    torch.testing.assert_close(act_on(m, None), _manual_act(m, current))
    torch.testing.assert_close(act_on(m, 5), _manual_act(m, current))


def test_act_is_deterministic_in_eval_mode_and_leaves_rows_alone():
    m = _two_task_module()
    rows = m.task_alphas("low").clone()
    assert torch.equal(act_on(m, 0), act_on(m, 0))
    assert torch.equal(m.task_alphas("low"), rows)


# --- grouped training forward -----------------------------------------------------------------


@pytest.mark.parametrize(("batch_size", "groups"), [(18, 9), (17, 1), (10, 10), (32, 16)])
def test_grouped_forward_with_indivisible_batch(monkeypatch, batch_size, groups):
    seen = []

    def recording(scores, g, noise, generator=None):
        seen.append(g)
        return training_alphas(scores, g, noise, generator)

    monkeypatch.setattr(hispo_mod, "training_alphas", recording)
    m = tiny_hispo(alpha_groups=16)
    m.add_anchor("high")
    perturb_newest(m, "high")  # identical anchors would leave the scores without gradient
    out = m.losses(random_batch(batch_size))
    assert seen == [groups, groups]  # high, then low
    assert torch.isfinite(out["loss"])
    out["loss"].backward()
    assert m.scores["high"].grad.abs().sum() > 0


def test_grouped_forward_without_noise_equals_a_plain_forward():
    m = tiny_hispo(
        alpha_groups=4,
        alpha_noise=0.0,
        backbone=BackboneConfig(high_hidden=8, low_hidden=16, dropout=0.0),
    )
    for name in SUBSPACES:
        m.add_anchor(name)
        perturb_newest(m, name)
        with torch.no_grad():
            m.scores[name].copy_(torch.tensor([0.7, -0.2]))
    batch = random_batch(18)  # 18 is not divisible by 4: 3 groups of 6
    out = m.losses(batch)
    for name in SUBSPACES:
        x, target = m.policies.inputs(name, batch)
        alpha = torch.softmax(2 * torch.tanh(m.scores[name].detach()), -1)
        mean, log_std = m.policies[name](x, alpha)
        torch.testing.assert_close(out[f"loss_{name}"], gaussian_nll(mean, log_std, target))


# --- checkpoints --------------------------------------------------------------------------------


def _three_task_module() -> HiSPO:
    """3 high anchors, 2 low anchors (the low extension of task 3 pruned), 3 stored tasks."""
    return grow_three_tasks(tiny_hispo(seed=5), lambda m, name, seed: perturb_newest(m, name, seed))


def _saved_by_trainer(module: HiSPO, path) -> None:
    """A short real fit (so the newest anchors and the scores have trained values), then
    ``trainer.save_checkpoint`` exactly as the ContinualLoop does."""
    batches = [random_batch(16, seed=s) for s in range(3)]
    trainer = quiet_trainer(max_steps=3)
    trainer.fit(module, train_dataloaders=DataLoader(batches, batch_size=None))
    trainer.save_checkpoint(path)


def test_checkpoint_round_trip_restores_structure_and_every_task(tmp_path):
    """Bit for bit, in one process: the restored module runs the saved weights through the same
    kernels on the same shapes as the original."""
    m = _three_task_module()
    m.add_anchor("high")  # a fourth, trainable high anchor, trained by the fit below
    path = tmp_path / "task_03.ckpt"
    _saved_by_trainer(m, path)
    assert (m.n_anchors("high"), m.n_anchors("low"), m.n_tasks) == (4, 2, 3)

    raw = torch.load(path, map_location="cpu", weights_only=True)
    assert raw["hispo_pl_task_index"] == 2
    assert raw["hispo_pl_class"] == "hispo_pl.modules.hispo.HiSPO"

    fresh = tiny_hispo(seed=99)
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
        assert torch.equal(act_on(fresh, task), act_on(m, task)), task

    classmethod_loaded = HiSPO.load_from_checkpoint(path, map_location="cpu")
    assert classmethod_loaded.backbone_config == HISPO_SIZES["backbone"]
    assert classmethod_loaded.task_index == 2
    for task in (0, 1, 2):
        assert torch.equal(act_on(classmethod_loaded, task), act_on(m, task)), task


def test_load_into_a_larger_module_shrinks_it(tmp_path):
    """Bit for bit, in one process: the restored module runs the saved weights through the same
    kernels on the same shapes as the original."""
    m = _three_task_module()
    path = tmp_path / "task_03.ckpt"
    _saved_by_trainer(m, path)
    big = tiny_hispo(seed=1)
    for _ in range(4):
        big.add_anchor("low")
    big.load_checkpoint_file(path)
    assert (big.n_anchors("high"), big.n_anchors("low")) == (3, 2)
    for task in (0, 1, 2):
        assert torch.equal(act_on(big, task), act_on(m, task))


@pytest.mark.parametrize("seed", [0, 1])
def test_anchors_added_later_leave_a_finished_task_bit_identical(seed):
    """A finished task's weights get a 0 for every later anchor; its actions must not change by
    a single bit (BWT exactly 0). Mixing the zero-weighted anchors too changes the rounding of
    the sum (7e-7 here), enough to flip a rollout of a 600-step episode. A promise within one
    process, whose kernels run on the same shapes before and after."""
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
