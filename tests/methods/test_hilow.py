"""HiLOW: low-rank (LoRA) anchors W_k = W_1 + A_k B_k. The layer's mixing, what trains, what
a new anchor starts at, the bytes it stores, and the module's checkpoints. (The stream end to
end runs in ``test_cspo.py``, parametrised over both ablations.)"""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from helpers import (
    HISPO_SIZES,
    SUBSPACE_PROTOCOLS,
    act_on,
    grow_three_tasks,
    quiet_trainer,
    random_batch,
    tiny_hispo,
)
from torch.utils.data import DataLoader

from hispo_pl.metrics import module_bytes
from hispo_pl.modules.hbc import GoalConditionedBC
from hispo_pl.modules.hilow import HiLOW
from hispo_pl.modules.hispo import SUBSPACES, HiSPO
from hispo_pl.nn.lowrank import LowRankSubspaceLinear, low_rank_
from hispo_pl.nn.simplex import sample_dirichlet
from hispo_pl.nn.subspace import SubspaceLinear, subspace_layers

IN, OUT, RANK, K, M, B = 12, 10, 3, 4, 5, 7


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _layer(k: int = K, seed: int = 0) -> LowRankSubspaceLinear:
    """A layer with ``k`` anchors whose offsets are all non-zero and distinct."""
    torch.manual_seed(seed)
    layer = LowRankSubspaceLinear(IN, OUT, RANK)
    for _ in range(k - 1):
        layer.add_anchor()
    g = _gen(seed + 1)
    with torch.no_grad():
        for p in layer.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=g))
    return layer


def _mixed_weight(layer: LowRankSubspaceLinear, alpha: torch.Tensor) -> torch.Tensor:
    """W_1 + Σ_{k≥2} α_k A_k B_k, written out (α on the simplex)."""
    weight = layer.weight.clone()
    for k in range(1, layer.n_anchors):
        weight = weight + alpha[k] * layer.lora_a[k - 1] @ layer.lora_b[k - 1]
    return weight


# --- the layer -----------------------------------------------------------------------------------


def test_layer_equals_a_plain_linear_with_the_mixed_weight():
    layer = _layer()
    x = torch.randn(B, IN)
    for alpha in sample_dirichlet(M, K, _gen(2)):
        bias = sum(alpha[k] * layer.biases[k] for k in range(K))
        expected = F.linear(x, _mixed_weight(layer, alpha), bias)
        torch.testing.assert_close(layer(x, alpha), expected)
    for k in range(K):  # a vertex is the anchor W_k = W_1 + A_k B_k itself
        one_hot = F.one_hot(torch.tensor(k), K).float()
        torch.testing.assert_close(
            layer(x, one_hot), F.linear(x, layer.anchor_weights()[k], layer.biases[k])
        )
    assert layer(torch.randn(2, 3, IN), torch.ones(K) / K).shape == (2, 3, OUT)


def test_layer_with_factors_and_a_plain_subspace_linear_of_materialised_anchors_agree():
    layer = _layer()
    full = SubspaceLinear(IN, OUT, n_anchors=K)
    with torch.no_grad():
        for k, w in enumerate(layer.anchor_weights()):
            full.weights[k].copy_(w)
            full.biases[k].copy_(layer.biases[k])
    alphas, x = sample_dirichlet(M, K, _gen(3)), torch.randn(B, IN)
    torch.testing.assert_close(layer(x, alphas), full(x, alphas), atol=1e-5, rtol=1e-5)
    assert layer.anchor_vectors().shape == full.anchor_vectors().shape
    torch.testing.assert_close(layer.anchor_vectors(), full.anchor_vectors())


def test_batched_forward_equals_the_unbatched_one_per_alpha():
    layer = _layer()
    alphas = sample_dirichlet(M, K, _gen(4))
    x = torch.randn(B, IN)  # shared by all M
    out = layer(x, alphas)
    assert out.shape == (M, B, OUT)
    torch.testing.assert_close(out, torch.stack([layer(x, a) for a in alphas]))
    xm = torch.randn(M, 2, B, IN)  # one input per alpha, extra leading dims
    expected = torch.stack([layer(xm[i], alphas[i]) for i in range(M)])
    torch.testing.assert_close(layer(xm, alphas), expected)
    with pytest.raises(ValueError, match="leading dim"):
        layer(torch.randn(M + 1, B, IN), alphas)
    with pytest.raises(ValueError, match="alpha must have shape"):
        layer(x, torch.ones(K + 1) / (K + 1))


def test_one_anchor_layer_is_a_plain_linear_and_stores_no_factors():
    layer = _layer(k=1)
    x = torch.randn(B, IN)
    torch.testing.assert_close(layer(x, torch.ones(1)), F.linear(x, layer.weight, layer.biases[0]))
    assert len(layer.lora_a) == len(layer.lora_b) == 0
    assert [n for n, p in layer.named_parameters() if p.requires_grad] == ["weight", "biases.0"]


def test_a_new_anchor_starts_at_the_first_and_only_it_trains():
    layer = _layer(k=2)
    layer.add_anchor("first")
    a, b = layer.lora_a[-1], layer.lora_b[-1]
    assert torch.equal(a, torch.zeros(OUT, RANK)) and b.abs().sum() > 0  # LoRA: A B = 0
    assert torch.equal(layer.biases[-1], layer.biases[0])
    x = torch.randn(B, IN)
    e = torch.eye(3)
    torch.testing.assert_close(layer(x, e[2]), layer(x, e[0]))  # the new vertex is θ_1
    trainable = {n for n, p in layer.named_parameters() if p.requires_grad}
    assert trainable == {"biases.2", "lora_a.1", "lora_b.1"}

    layer(x, torch.tensor([0.2, 0.3, 0.5])).pow(2).sum().backward()
    assert layer.weight.grad is None and layer.lora_a[0].grad is None
    assert layer.lora_b[0].grad is None and layer.biases[0].grad is None
    assert layer.lora_a[1].grad.abs().sum() > 0  # B is random: A gets the first gradient
    assert torch.equal(layer.lora_b[1].grad, torch.zeros(RANK, IN))  # A = 0: none for B yet

    layer.add_anchor("random")
    assert torch.equal(layer.biases[-1], torch.zeros(OUT))  # a fresh bias
    with pytest.raises(ValueError, match="unknown anchor init"):
        layer.add_anchor("bogus")  # type: ignore[arg-type]
    assert (layer.n_anchors, len(layer.lora_a), len(layer.lora_b)) == (4, 3, 3)  # unchanged


def test_remove_and_set_n_anchors_keep_the_older_anchors():
    layer = _layer()
    state = {k: v.clone() for k, v in layer.state_dict().items()}
    x, alpha = torch.randn(B, IN), torch.tensor([0.1, 0.2, 0.3, 0.4])
    before = layer(x, alpha)
    layer.add_anchor()
    layer.remove_last_anchor()
    assert not any(p.requires_grad for p in layer.parameters())
    assert layer.state_dict().keys() == state.keys()
    torch.testing.assert_close(layer(x, alpha), before)

    layer.set_n_anchors(2)
    assert (layer.n_anchors, len(layer.lora_a), len(layer.lora_b)) == (2, 1, 1)
    layer.set_n_anchors(5)  # zero placeholders, the newest trainable: ready for load_state_dict
    assert (layer.n_anchors, len(layer.lora_a), len(layer.lora_b)) == (5, 4, 4)
    assert torch.equal(layer.lora_a[3], torch.zeros(OUT, RANK))
    assert {n for n, p in layer.named_parameters() if p.requires_grad} == {
        "biases.4",
        "lora_a.3",
        "lora_b.3",
    }
    layer.set_n_anchors(4)
    layer.load_state_dict(state)
    torch.testing.assert_close(layer(x, alpha), before)
    with pytest.raises(RuntimeError, match="only anchor"):
        _layer(k=1).remove_last_anchor()


def test_rank_is_capped_and_bytes_follow_the_formula():
    assert LowRankSubspaceLinear(64, 2, rank=8).rank == 2
    layer = _layer()
    per_value = 4  # float32
    expected = OUT * IN + K * OUT + (K - 1) * RANK * (IN + OUT)
    assert module_bytes(layer) == per_value * expected
    full = SubspaceLinear(IN, OUT, n_anchors=K)
    assert module_bytes(full) == per_value * K * (OUT * IN + OUT)
    with pytest.raises(ValueError, match="rank"):
        LowRankSubspaceLinear(IN, OUT, rank=0)


def test_low_rank_conversion_keeps_the_outputs():
    torch.manual_seed(0)
    full = SubspaceLinear(IN, OUT)
    parent = torch.nn.ModuleDict({"layer": full})
    low_rank_(parent, RANK)
    assert isinstance(parent["layer"], LowRankSubspaceLinear)
    x = torch.randn(B, IN)
    torch.testing.assert_close(parent["layer"](x, torch.ones(1)), full(x, torch.ones(1)))
    with pytest.raises(ValueError, match="one anchor"):
        LowRankSubspaceLinear.from_linear(SubspaceLinear(IN, OUT, n_anchors=2), RANK)


# --- the module ----------------------------------------------------------------------------------


def _module(seed: int = 0, **kw) -> HiLOW:
    return tiny_hispo(seed, HiLOW, rank=RANK, **kw)


def _perturb_newest(module: HiLOW, subspace: str, seed: int = 1, scale: float = 0.3) -> None:
    """Give the newest anchor of a subspace a non-zero offset (a new one starts at θ_1)."""
    g = _gen(seed)
    j = module.n_anchors(subspace) - 1
    with torch.no_grad():
        for name, p in module.policies[subspace].named_parameters():
            if name.endswith(f".{j}") or name.endswith(f"lora_a.{j - 1}"):
                p.add_(scale * torch.randn(p.shape, generator=g))


def test_every_linear_layer_is_low_rank_and_the_module_is_a_subspace_policy():
    m = _module()
    assert all(isinstance(m, p) for p in SUBSPACE_PROTOCOLS) and m.subspace_names == SUBSPACES
    for name in SUBSPACES:
        layers = list(subspace_layers(m.policies[name].net))
        assert sum(isinstance(layer, LowRankSubspaceLinear) for layer in layers) == 4
        assert not any(type(layer) is SubspaceLinear for layer in layers)
    assert m.hparams.rank == RANK and m.hparams.anchor_init == "first"
    with pytest.raises(ValueError, match="'first' or 'random'"):
        HiLOW(**HISPO_SIZES, anchor_init="mean")


def test_first_task_is_hispo_exactly():
    """Bit for bit, in one process: with one anchor HiLOW's layers scale their weights by
    exactly 1 and run HiSPO's kernels on HiSPO's shapes."""
    hilow = _module(seed=4)
    torch.manual_seed(4)
    hispo = HiSPO(**HISPO_SIZES)
    assert module_bytes(hilow) == module_bytes(hispo)
    hilow_sd, hispo_sd = hilow.state_dict(), hispo.state_dict()
    assert len(hilow_sd) == len(hispo_sd)
    for key, value in hispo_sd.items():  # SubspaceLinear's weights.0 is HiLOW's weight
        assert torch.equal(hilow_sd[key.replace(".weights.0", ".weight")], value), key
    for task in (0, None):
        assert torch.equal(act_on(hilow, task), act_on(hispo, task))
    batch = random_batch(16)
    alphas = torch.ones(1, 1)
    for name in SUBSPACES:
        assert torch.equal(
            hilow.score_alphas(name, alphas, batch), hispo.score_alphas(name, alphas, batch)
        )


@pytest.mark.parametrize("name", SUBSPACES)
def test_a_new_anchor_of_the_module_is_the_first_one(name):
    m = _module().eval()
    m.add_anchor(name)
    _perturb_newest(m, name)  # anchor 2 away from θ_1
    m.add_anchor(name)  # anchor 3: θ_1 again (zero offset, copied biases and affines)
    x, _ = m.policies.inputs(name, random_batch(10))
    e = torch.eye(3)
    first, second, third = (m.policies[name](x, e[k])[0] for k in range(3))
    torch.testing.assert_close(third, first)
    assert not torch.allclose(second, first)
    gammas = m.policies[name].net.inp_norm.gammas
    assert torch.equal(gammas[2], gammas[0]) and not torch.equal(gammas[1], gammas[0])


def test_cosine_regulariser_reaches_the_newest_factors():
    m = _module(cosine_weight=0.5)
    m.add_anchor("low")
    _perturb_newest(m, "low")
    out = m.losses(random_batch(16))
    assert 0 < out["cosine"] <= 2  # a sum of two means of squared cosines
    out["loss"].backward()
    head = m.policies["low"].net.head
    assert head.lora_a[0].grad.abs().sum() > 0 and head.lora_b[0].grad.abs().sum() > 0


def test_only_the_newest_anchor_trains_after_two_extensions():
    m = _module()
    for name in SUBSPACES:
        m.set_task_alpha(0, name, torch.ones(1))
    m.freeze_all()
    for _ in range(2):
        m.add_anchor("low")
        _perturb_newest(m, "low", seed=m.n_anchors("low"))
    trainable = {n for n, p in m.named_parameters() if p.requires_grad}
    newest = {n for n in trainable if n.startswith("policies.low.")}
    assert trainable == newest | {"scores.low"}
    assert {n.rsplit(".", 2)[-2] for n in newest} == {
        "biases",
        "lora_a",
        "lora_b",
        "gammas",
        "betas",
    }
    assert all(n.endswith((".2", "lora_a.1", "lora_b.1")) for n in newest)

    before = {n: p.detach().clone() for n, p in m.named_parameters()}
    opt = torch.optim.Adam([p for p in m.parameters() if p.requires_grad], lr=1e-2)
    m.train()
    m.losses(random_batch(32))["loss"].backward()
    opt.step()
    for n, p in m.named_parameters():
        assert torch.equal(p, before[n]) == (n not in trainable), n


def test_stored_bytes_with_four_anchors_are_below_hispos():
    hilow, hispo = _module(), HiSPO(**HISPO_SIZES)
    for module in (hilow, hispo):
        for _ in range(3):
            for name in SUBSPACES:
                module.add_anchor(name)
        assert [module.n_anchors(n) for n in SUBSPACES] == [4, 4]
    assert module_bytes(hilow) < module_bytes(hispo)
    # exactly: HiLOW keeps one full weight per linear layer where HiSPO keeps four, and adds
    # three rank-r offsets; biases, LayerNorm affines, scores and stored weights are the same
    low_rank = [layer for layer in subspace_layers(hilow) if hasattr(layer, "lora_a")]
    weights = sum(4 * layer.in_features * layer.out_features for layer in low_rank)
    offsets = sum(
        4 * 3 * layer.rank * (layer.in_features + layer.out_features) for layer in low_rank
    )
    assert len(low_rank) == 8 and 0 < offsets < 3 * weights
    assert module_bytes(hilow) == module_bytes(hispo) - 3 * weights + offsets


# --- checkpoints ---------------------------------------------------------------------------------


def _three_task_module() -> HiLOW:
    """3 high anchors, 2 low anchors (the low extension of task 3 pruned), 3 stored tasks."""
    return grow_three_tasks(
        _module(seed=5), lambda m, name, seed: _perturb_newest(m, name, seed, scale=1.0)
    )


def test_checkpoint_round_trip_restores_every_task(tmp_path):
    """Bit for bit, in one process: the restored module runs the saved weights through the same
    kernels on the same shapes as the original."""
    m = _three_task_module()
    m.add_anchor("high")  # a fourth high anchor, trained below
    batches = [random_batch(16, seed=s) for s in range(3)]
    trainer = quiet_trainer(max_steps=3)
    trainer.fit(m, train_dataloaders=DataLoader(batches, batch_size=None))
    path = tmp_path / "task_03.ckpt"
    trainer.save_checkpoint(path)
    assert m.policies["high"].net.head.lora_a[2].abs().sum() > 0  # the newest A trained

    raw = torch.load(path, map_location="cpu", weights_only=True)
    assert raw["hispo_pl_class"] == "hispo_pl.modules.hilow.HiLOW"
    assert raw["hyper_parameters"]["rank"] == RANK
    fresh = _module(seed=99)
    fresh.load_checkpoint_file(path)
    for loaded in (fresh, GoalConditionedBC.from_checkpoint_file(str(path))):
        assert type(loaded) is HiLOW and loaded.task_index == 2
        assert (loaded.n_anchors("high"), loaded.n_anchors("low")) == (4, 2)
        expected, got = m.state_dict(), loaded.state_dict()
        assert expected.keys() == got.keys()
        for k, v in expected.items():
            assert torch.equal(got[k], v), k
        for task in (0, 1, 2, None):
            assert torch.equal(act_on(loaded, task), act_on(m, task)), task
    assert not torch.equal(act_on(m, 0), act_on(m, 1))  # the tasks really act differently
