"""CSPO, the single-subspace ablation: one subspace of (high, low) anchor pairs, one weight
vector per task for both levels, one score, one decision; and a short stream end to end for
both ablations (CSPO and HiLOW) through ``hispo-pl fit``."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest
import torch
from helpers import (
    HISPO_SIZES,
    SUBSPACE_PROTOCOLS,
    quiet_trainer,
    random_batch,
    tiny_hispo,
    tiny_stream_args,
)
from torch.utils.data import DataLoader

import hispo_pl.modules.hispo as hispo_mod
from hispo_pl.callbacks import AnchorExtension, SubspacePruning
from hispo_pl.cli import main
from hispo_pl.config import BackboneConfig
from hispo_pl.metrics import module_bytes
from hispo_pl.modules.cspo import CSPO
from hispo_pl.modules.hbc import HBC, GoalConditionedBC
from hispo_pl.modules.hispo import HiSPO, training_alphas
from hispo_pl.nn.hierarchy import high_input, low_input
from hispo_pl.nn.mlp import gaussian_nll
from hispo_pl.results import SearchResult
from hispo_pl.rundir import RunDir
from hispo_pl.task_families import FAMILIES

ROOT = Path(__file__).resolve().parents[2]
LEVELS = ("high", "low")


def _module(seed: int = 0, **kw) -> CSPO:
    return tiny_hispo(seed, CSPO, **kw)


def _perturb_newest(module: HiSPO, seed: int = 1, scale: float = 0.3) -> None:
    """Move the newest anchor of both levels away from the others, so that weights matter."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for level in LEVELS:
            k = module.policies[level].net.n_anchors - 1
            for name, p in module.policies[level].named_parameters():
                if name.endswith(f".{k}"):
                    p.add_(scale * torch.randn(p.shape, generator=g))


def _anchor_params(module: HiSPO, level: str, k: int) -> set[str]:
    prefix = f"policies.{level}."
    return {n for n, _ in module.named_parameters() if n.startswith(prefix) and n.endswith(f".{k}")}


def _act(module: HiSPO, task: int | None, seed: int = 3) -> torch.Tensor:
    b = random_batch(7, seed)
    module.eval()
    return module.act(b["observation"], b["position"], b["goal"], task=task)


def _manual_act(module: HiSPO, alpha: torch.Tensor, seed: int = 3) -> torch.Tensor:
    """Both levels mixed with the same weights ``alpha``."""
    b = random_batch(7, seed)
    with torch.no_grad():
        offset, _ = module.policies["high"](
            high_input(b["observation"], b["position"], b["goal"]), alpha
        )
        action, _ = module.policies["low"](low_input(b["observation"], offset), alpha)
    return action


# --- one subspace for both levels ----------------------------------------------------------------


def test_one_subspace_named_policy_with_one_score_and_one_row_of_weights():
    m = _module()
    assert all(isinstance(m, p) for p in SUBSPACE_PROTOCOLS)
    assert m.subspace_names == ("policy",)
    assert m.n_anchors("policy") == 1
    assert [m.policies[level].net.n_anchors for level in LEVELS] == [1, 1]
    sd = m.state_dict()
    assert {k for k in sd if k.startswith(("scores", "task_alpha"))} == {
        "scores.policy",
        "task_alpha_policy",
    }
    hispo = HiSPO(**HISPO_SIZES)  # the same networks, parameter for parameter
    assert {k for k in sd if k.startswith("policies")} == {
        k for k in hispo.state_dict() if k.startswith("policies")
    }


def test_add_anchor_grows_both_levels_and_trains_only_the_newest_pair():
    m = _module()
    m.set_task_alpha(0, "policy", torch.ones(1))
    m.freeze_all()
    before = {n: p.detach().clone() for n, p in m.named_parameters()}

    m.add_anchor("policy")
    assert m.n_anchors("policy") == 2
    assert [m.policies[level].net.n_anchors for level in LEVELS] == [2, 2]
    trainable = {n for n, p in m.named_parameters() if p.requires_grad}
    newest = _anchor_params(m, "high", 1) | _anchor_params(m, "low", 1)
    assert newest and trainable == newest | {"scores.policy"}
    assert m.scores["policy"].shape == (2,)
    assert m.task_alphas("policy").tolist() == [[1.0, 0.0]]
    for n, p in before.items():
        if n.startswith("policies"):
            assert torch.equal(dict(m.named_parameters())[n], p), n


def test_prune_removes_the_newest_pair_from_both_levels():
    m = _module()
    m.set_task_alpha(0, "policy", torch.ones(1))
    m.add_anchor("policy")
    m.set_task_alpha(1, "policy", torch.tensor([0.25, 0.75]))
    kept = copy.deepcopy(m.state_dict())
    m.add_anchor("policy")
    _perturb_newest(m)
    m.prune_last_anchor("policy")
    assert [m.policies[level].net.n_anchors for level in LEVELS] == [2, 2]
    assert m.task_alphas("policy").tolist() == [[1.0, 0.0], [0.25, 0.75]]
    assert not any(p.requires_grad for p in m.policies.parameters())
    after = m.state_dict()
    assert after.keys() == kept.keys()
    for k in kept:
        if k.startswith("policies"):
            assert torch.equal(after[k], kept[k]), k


def test_the_callbacks_grow_and_prune_both_levels_with_one_decision():
    m = _module()
    m.set_task_alpha(0, "policy", torch.ones(1))
    m.task_index = 1
    AnchorExtension().setup(None, m, "fit")  # the hook needs only the module
    assert [m.policies[level].net.n_anchors for level in LEVELS] == [2, 2]

    res = SearchResult(l_curr=1.0, alpha_curr=[0.3, 0.7], l_prev=1.05, alpha_prev=[1.0, 0.0])
    pruning = SubspacePruning()  # no eps for "policy": the family's smallest, 0.1
    d = pruning._decide(m, "policy", res, pruning.tolerance("policy", FAMILIES["pointmaze"]))
    assert (d.subspace, d.decision, d.eps, d.anchors) == ("policy", "prune", 0.1, 1)
    assert [m.policies[level].net.n_anchors for level in LEVELS] == [1, 1]
    assert m.task_alphas("policy").tolist() == [[1.0], [1.0]]


def test_pruning_takes_the_tolerance_of_the_policy_subspace_from_eps():
    res = SearchResult(l_curr=1.0, alpha_curr=[0.3, 0.7], l_prev=1.3, alpha_prev=[1.0, 0.0])
    for eps, decision, anchors in (({"policy": 0.5}, "prune", 1), ({"policy": 0.2}, "keep", 2)):
        m = _module()
        m.set_task_alpha(0, "policy", torch.ones(1))
        m.add_anchor("policy")
        m.task_index = 1
        pruning = SubspacePruning(eps_high=1.0, eps_low=1.0, eps=eps)
        d = pruning._decide(m, "policy", res, pruning.tolerance("policy", FAMILIES["pointmaze"]))
        assert (d.decision, d.eps, m.n_anchors("policy")) == (
            decision,
            eps["policy"],
            anchors,
        )
    # HiSPO's names keep their own tolerances
    assert SubspacePruning(eps_high=0.05, eps_low=0.2).eps == {"high": 0.05, "low": 0.2}


def test_one_weight_draw_per_step_shared_by_both_levels(monkeypatch):
    seen = []

    def recording(scores, groups, noise, generator=None):
        alphas = training_alphas(scores, groups, noise, generator)
        seen.append(alphas)
        return alphas

    monkeypatch.setattr(hispo_mod, "training_alphas", recording)
    m = _module(backbone=BackboneConfig(high_hidden=8, low_hidden=16, dropout=0.0), alpha_groups=3)
    m.add_anchor("policy")
    _perturb_newest(m)
    with torch.no_grad():
        m.scores["policy"].copy_(torch.tensor([0.5, -0.4]))
    batch = random_batch(12)
    out = m.losses(batch)
    assert len(seen) == 1 and seen[0].shape == (3, 2)  # one draw (3 groups) for both levels
    alphas = seen[0]
    for level in LEVELS:
        x, target = m.policies.inputs(level, batch)
        mean, log_std = m.policies[level](x.reshape(3, 4, -1), alphas)
        expected = gaussian_nll(mean.reshape(12, -1), log_std.reshape(12, -1), target)
        torch.testing.assert_close(out[f"loss_{level}"], expected)
    torch.testing.assert_close(out["loss"], out["loss_high"] + out["loss_low"])
    out["loss"].backward()
    assert m.scores["policy"].grad.abs().sum() > 0


# --- scoring -------------------------------------------------------------------------------------


def _three_anchor_module() -> CSPO:
    m = _module()
    for seed in (1, 2):
        m.add_anchor("policy")
        _perturb_newest(m, seed=seed)
    return m.eval()


@pytest.mark.parametrize("loss", ["mse", "nll"])
def test_score_alphas_is_the_sum_of_both_levels_losses(loss):
    m = _three_anchor_module()
    alphas = torch.tensor([[1.0, 0.0, 0.0], [0.2, 0.3, 0.5], [0.0, 0.0, 1.0], [0.5, 0.5, 0.0]])
    batch = random_batch(20)
    scores = m.score_alphas("policy", alphas, batch, loss=loss, chunk=3)
    assert scores.shape == (4,) and len(set(scores.tolist())) == 4

    hispo = HiSPO(**HISPO_SIZES)  # the same networks as two subspaces: each level's loss alone
    for level in LEVELS:
        hispo.policies[level].net.set_n_anchors(3)
    hispo.load_state_dict(
        {k: v for k, v in m.state_dict().items() if k.startswith("policies")}, strict=False
    )
    hispo.eval()
    per_level = [hispo.score_alphas(level, alphas, batch, loss=loss) for level in LEVELS]
    torch.testing.assert_close(scores, per_level[0] + per_level[1])
    assert torch.all(per_level[0] > 0) and torch.all(per_level[1] > 0)


def test_score_alphas_matches_a_manual_sum_of_squared_errors():
    m = _three_anchor_module()
    alpha = torch.tensor([0.2, 0.3, 0.5])
    batch = random_batch(9)
    expected = 0.0
    with torch.no_grad():
        for level in LEVELS:
            x, target = m.policies.inputs(level, batch)
            mean, _ = m.policies[level](x, alpha)
            expected = expected + (mean - target).pow(2).sum(-1).mean()
    torch.testing.assert_close(m.score_alphas("policy", alpha[None], batch)[0], expected)


# --- acting and checkpoints ----------------------------------------------------------------------


def _three_task_module() -> CSPO:
    """Three stored tasks: two anchor pairs kept, the third task's extension pruned."""
    m = _module(seed=5)
    m.set_task_alpha(0, "policy", torch.ones(1))
    m.freeze_all()
    m.add_anchor("policy")
    _perturb_newest(m, seed=11, scale=1.0)
    m.set_task_alpha(1, "policy", torch.tensor([0.4, 0.6]))
    m.freeze_all()
    m.add_anchor("policy")
    _perturb_newest(m, seed=12)
    m.prune_last_anchor("policy")
    m.set_task_alpha(2, "policy", torch.tensor([0.9, 0.1]))
    m.task_index = 2
    return m


def test_act_mixes_both_levels_with_the_tasks_weights():
    m = _three_task_module()
    for task in (0, 1, 2):
        torch.testing.assert_close(_act(m, task), _manual_act(m, m.task_alphas("policy")[task]))
    assert not torch.allclose(_act(m, 0), _act(m, 1))


def test_checkpoint_round_trip_acts_identically_on_every_task(tmp_path):
    """Bit for bit, in one process: the restored module runs the saved weights through the same
    kernels on the same shapes as the original."""
    m = _three_task_module()
    m.add_anchor("policy")  # a fourth task in progress: its pair and scores train below
    batches = [random_batch(16, seed=s) for s in range(3)]
    trainer = quiet_trainer(max_steps=3)
    trainer.fit(m, train_dataloaders=DataLoader(batches, batch_size=None))
    path = tmp_path / "task_04.ckpt"
    trainer.save_checkpoint(path)
    assert m.scores["policy"].abs().sum() > 0  # trained, so the round trip has values to keep

    raw = torch.load(path, map_location="cpu", weights_only=True)
    assert raw["hispo_pl_class"] == "hispo_pl.modules.cspo.CSPO"
    fresh = _module(seed=99)  # one anchor pair: the structure comes from the file
    fresh.load_checkpoint_file(path)
    for loaded in (fresh, GoalConditionedBC.from_checkpoint_file(str(path))):
        assert type(loaded) is CSPO and loaded.task_index == 2
        assert loaded.n_anchors("policy") == 3
        assert [loaded.policies[level].net.n_anchors for level in LEVELS] == [3, 3]
        expected, got = m.state_dict(), loaded.state_dict()
        assert expected.keys() == got.keys()
        for k, v in expected.items():
            assert torch.equal(got[k], v), k
        for task in (0, 1, 2, 3):
            assert torch.equal(_act(loaded, task), _act(m, task)), task


def test_memory_of_a_kept_anchor_pair_is_one_hbc():
    m = _module()
    one = module_bytes(m)
    m.add_anchor("policy")
    # one more anchor: both networks once, and one more float32 score
    assert module_bytes(m) - one == module_bytes(HBC(**HISPO_SIZES)) + 4


# --- a short stream end to end, for both ablations ----------------------------------------------


STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]
SUBSPACES_OF = {"cspo": ["policy"], "hilow": ["high", "low"]}


@pytest.mark.parametrize("method", ["cspo", "hilow"])
def test_a_stream_end_to_end_through_the_cli(method, tiny_umaze, tmp_path, capsys):
    assert main(tiny_stream_args(method, tmp_path, STREAM)) == 0
    out = capsys.readouterr().out
    run_dir = tmp_path / "pointmaze-1" / "seed0"
    results = json.loads((run_dir / "results.json").read_text())
    assert len(results["R"]) == 2 and all(len(row) == 2 for row in results["R"])
    assert results["BWT"] == 0.0 and results["R"][1][0] == results["R"][0][0]
    assert sorted(results["anchors"]) == SUBSPACES_OF[method]
    assert all(k in (1, 2) for k in results["anchors"].values())
    assert f"anchors per subspace: {results['anchors']}" in out
    assert results["MEM"] > 0

    decisions = RunDir(run_dir).decisions()
    assert [(d.task, d.subspace) for d in decisions] == [
        (t, s) for t in (0, 1) for s in SUBSPACES_OF[method]
    ]
    assert [d.decision for d in decisions[: len(SUBSPACES_OF[method])]] == ["first"] * len(
        SUBSPACES_OF[method]
    )
    module = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    assert type(module).__name__ == {"cspo": "CSPO", "hilow": "HiLOW"}[method]
    assert {n: module.n_anchors(n) for n in module.subspace_names} == results["anchors"]
    assert module_bytes(module) == results["stored_bytes"]
