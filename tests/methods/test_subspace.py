"""Subspace layers: Dirichlet sampling, parameter-space mixing, anchor management, penalty."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from hispo_pl.nn.mlp import ResidualMLP
from hispo_pl.nn.simplex import sample_dirichlet
from hispo_pl.nn.subspace import (
    SubspaceLayerNorm,
    SubspaceLinear,
    SubspaceResidualMLP,
    cosine_similarity_penalty,
    subspace_layers,
)

K, M, B = 3, 4, 5
IN, HID, OUT = 6, 16, 4


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _perturb(module: nn.Module, seed: int = 1) -> None:
    """Make every anchor distinct (LayerNorm anchors start identical) so mixing is tested."""
    g = _gen(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.add_(0.3 * torch.randn(p.shape, generator=g))


# --- Dirichlet ------------------------------------------------------------------------------


def test_dirichlet_shape_simplex_and_dtype():
    a = sample_dirichlet(1000, 5, _gen())
    assert a.shape == (1000, 5) and a.dtype == torch.float32
    assert (a >= 0).all()
    torch.testing.assert_close(a.sum(1), torch.ones(1000))
    one = sample_dirichlet(7, 1)
    assert one.shape == (7, 1) and torch.equal(one, torch.ones(7, 1))
    with pytest.raises(ValueError):
        sample_dirichlet(3, 0)


def test_dirichlet_marginal_moments_k4():
    k, n = 4, 200_000
    a = sample_dirichlet(n, k, _gen(123)).double()
    mean, var = a.mean(0), a.var(0)
    assert torch.allclose(mean, torch.full((k,), 1 / k, dtype=torch.double), atol=3e-3)
    expected_var = (k - 1) / (k**2 * (k + 1))  # 0.0375
    assert torch.allclose(var, torch.full((k,), expected_var, dtype=torch.double), atol=1e-3)
    cov = torch.cov(a.T)
    expected_cov = -1 / (k**2 * (k + 1))
    off = cov[~torch.eye(k, dtype=torch.bool)]
    assert torch.allclose(off, torch.full_like(off, expected_cov), atol=1e-3)


def test_dirichlet_k2_marginal_is_uniform():
    n = 200_000
    x = sample_dirichlet(n, 2, _gen(7))[:, 0]
    frac = torch.histc(x, bins=10, min=0.0, max=1.0) / n
    assert torch.allclose(frac, torch.full((10,), 0.1), atol=5e-3)
    ecdf = torch.arange(1, n + 1, dtype=torch.double) / n
    ks = (ecdf - x.sort().values.double()).abs().max().item()
    assert ks < 1.63 / n**0.5  # Kolmogorov-Smirnov at the 1% level


def test_dirichlet_generator_is_deterministic():
    a = sample_dirichlet(50, 3, _gen(5))
    b = sample_dirichlet(50, 3, _gen(5))
    c = sample_dirichlet(50, 3, _gen(6))
    assert torch.equal(a, b) and not torch.equal(a, c)


# --- SubspaceLinear ---------------------------------------------------------------------------


def test_linear_init_matches_mlp_init():
    layer = SubspaceLinear(IN, HID)
    bound = (3.0 * 0.1 / (0.5 * (IN + HID))) ** 0.5
    assert layer.n_anchors == 1
    assert layer.weights[0].shape == (HID, IN) and layer.biases[0].shape == (HID,)
    assert layer.weights[0].abs().max() <= bound and layer.weights[0].abs().max() > 0.5 * bound
    assert torch.equal(layer.biases[0], torch.zeros(HID))


def test_linear_unbatched_equals_manual_mix_and_one_hot():
    torch.manual_seed(0)
    layer = SubspaceLinear(IN, OUT, n_anchors=K)
    _perturb(layer)
    x, alpha = torch.randn(B, IN), sample_dirichlet(1, K, _gen())[0]
    w = sum(alpha[k] * layer.weights[k] for k in range(K))
    b = sum(alpha[k] * layer.biases[k] for k in range(K))
    torch.testing.assert_close(layer(x, alpha), F.linear(x, w, b))
    for k in range(K):
        one_hot = F.one_hot(torch.tensor(k), K).float()
        torch.testing.assert_close(
            layer(x, one_hot), F.linear(x, layer.weights[k], layer.biases[k])
        )
    # arbitrary leading dims in the unbatched form
    assert layer(torch.randn(2, 3, IN), alpha).shape == (2, 3, OUT)


def test_linear_batched_equals_stacked_and_broadcasts():
    torch.manual_seed(0)
    layer = SubspaceLinear(IN, OUT, n_anchors=K)
    _perturb(layer)
    alphas = sample_dirichlet(M, K, _gen())
    x = torch.randn(M, B, IN)
    expected = torch.stack([layer(x[i], alphas[i]) for i in range(M)])
    out = layer(x, alphas)
    assert out.shape == (M, B, OUT)
    torch.testing.assert_close(out, expected, atol=1e-5, rtol=1e-5)
    shared = torch.randn(B, IN)
    torch.testing.assert_close(
        layer(shared, alphas), layer(shared.expand(M, B, IN).clone(), alphas), atol=1e-6, rtol=0
    )
    with pytest.raises(ValueError):
        layer(shared, torch.ones(K + 1) / (K + 1))


# --- SubspaceLayerNorm ------------------------------------------------------------------------


def test_layernorm_unbatched_batched_and_one_hot():
    torch.manual_seed(0)
    ln = SubspaceLayerNorm(HID, n_anchors=K)
    _perturb(ln)
    x, alpha = torch.randn(B, HID), sample_dirichlet(1, K, _gen())[0]
    g = sum(alpha[k] * ln.gammas[k] for k in range(K))
    b = sum(alpha[k] * ln.betas[k] for k in range(K))
    torch.testing.assert_close(ln(x, alpha), F.layer_norm(x, (HID,), g, b, 1e-5))
    for k in range(K):
        one_hot = F.one_hot(torch.tensor(k), K).float()
        torch.testing.assert_close(
            ln(x, one_hot), F.layer_norm(x, (HID,), ln.gammas[k], ln.betas[k], 1e-5)
        )
    alphas = sample_dirichlet(M, K, _gen(1))
    xm = torch.randn(M, B, HID)
    expected = torch.stack([ln(xm[i], alphas[i]) for i in range(M)])
    torch.testing.assert_close(ln(xm, alphas), expected, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(
        ln(x, alphas), ln(x.expand(M, B, HID).clone(), alphas), atol=1e-6, rtol=0
    )


# --- SubspaceResidualMLP ----------------------------------------------------------------------


def _mlp(k: int = K, seed: int = 0) -> SubspaceResidualMLP:
    torch.manual_seed(seed)
    net = SubspaceResidualMLP(IN, HID, OUT, dropout=0.1, n_anchors=k)
    _perturb(net, seed + 1)
    return net.eval()


def test_mlp_unbatched_one_hot_batched_and_broadcast():
    net = _mlp()
    x = torch.randn(B, IN)
    alphas = sample_dirichlet(M, K, _gen())
    assert net(x, alphas[0]).shape == (B, OUT)
    expected = torch.stack([net(x, alphas[i]) for i in range(M)])
    out = net(x, alphas)
    assert out.shape == (M, B, OUT)
    torch.testing.assert_close(out, expected, atol=1e-5, rtol=1e-5)
    xm = torch.randn(M, B, IN)
    expected_m = torch.stack([net(xm[i], alphas[i]) for i in range(M)])
    torch.testing.assert_close(net(xm, alphas), expected_m, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(net(x.expand(M, B, IN), alphas), out, atol=1e-6, rtol=0)
    # one-hot alpha = the network built from that anchor alone
    for k in range(K):
        single = SubspaceResidualMLP(IN, HID, OUT, n_anchors=1).eval()
        with torch.no_grad():
            for src, dst in zip(subspace_layers(net), subspace_layers(single), strict=True):
                for s_list, d_list in zip(src._lists(), dst._lists(), strict=True):
                    d_list[0].copy_(s_list[k])
        one_hot = F.one_hot(torch.tensor(k), K).float()
        torch.testing.assert_close(net(x, one_hot), single(x, torch.ones(1)))


def test_mlp_single_anchor_matches_plain_residual_mlp():
    torch.manual_seed(3)
    plain = ResidualMLP(IN, HID, OUT, dropout=0.1)
    _perturb(plain, 4)
    plain.eval()
    net = SubspaceResidualMLP(IN, HID, OUT, dropout=0.1, n_anchors=1).eval()
    net.load_residual_mlp(plain)
    x = torch.randn(B, IN)
    torch.testing.assert_close(net(x, torch.ones(1)), plain(x), atol=1e-6, rtol=1e-6)
    # and the parameter counts agree: nothing extra, nothing missing
    assert sum(p.numel() for p in net.parameters()) == sum(p.numel() for p in plain.parameters())


def test_mlp_dropout_active_in_train_mode():
    net = _mlp().train()
    x, alpha = torch.randn(64, IN), torch.ones(K) / K
    assert not torch.equal(net(x, alpha), net(x, alpha))


# --- anchor management ------------------------------------------------------------------------


def test_add_anchor_mean_freezes_older():
    net = _mlp()
    before = [
        [p.detach().clone() for p in plist]
        for layer in subspace_layers(net)
        for plist in layer._lists()
    ]
    net.add_anchor("mean")
    assert net.n_anchors == K + 1
    lists = [plist for layer in subspace_layers(net) for plist in layer._lists()]
    for old, plist in zip(before, lists, strict=True):
        torch.testing.assert_close(plist[K], torch.stack(old).mean(0))
        for k in range(K):
            assert torch.equal(plist[k], old[k])
        assert [p.requires_grad for p in plist] == [False] * K + [True]


def test_add_anchor_random_differs_from_mean():
    torch.manual_seed(0)
    net = SubspaceResidualMLP(IN, HID, OUT, n_anchors=2)
    mean_w = torch.stack(list(net.inp_linear.weights)).mean(0)
    net.add_anchor("random")
    assert net.n_anchors == 3
    assert not torch.allclose(net.inp_linear.weights[2], mean_w)
    assert torch.equal(net.inp_linear.biases[2], torch.zeros(HID))  # fresh init: zero bias
    assert net.inp_linear.weights[2].requires_grad and not net.inp_linear.weights[0].requires_grad
    with pytest.raises(ValueError):
        net.add_anchor("bogus")  # type: ignore[arg-type]


def test_gradients_reach_only_newest_anchor():
    net = _mlp().train()
    net.add_anchor("mean")
    alphas = sample_dirichlet(M, K + 1, _gen())
    loss = net(torch.randn(B, IN), alphas).pow(2).mean() + cosine_similarity_penalty(net)
    loss.backward()
    for layer in subspace_layers(net):
        for plist in layer._lists():
            assert all(p.grad is None for p in list(plist)[:-1])
            assert plist[-1].grad is not None and plist[-1].grad.abs().sum() > 0


def test_remove_last_anchor_restores_previous():
    net = _mlp()
    x, alpha = torch.randn(B, IN), sample_dirichlet(1, K, _gen())[0]
    before_out = net(x, alpha)
    before_state = {k: v.clone() for k, v in net.state_dict().items()}
    net.add_anchor("random")
    net.remove_last_anchor()
    assert net.n_anchors == K
    after = net.state_dict()
    assert after.keys() == before_state.keys()
    assert all(torch.equal(after[k], v) for k, v in before_state.items())
    torch.testing.assert_close(net(x, alpha), before_out)
    assert not any(p.requires_grad for p in net.parameters())
    single = SubspaceLinear(IN, OUT)
    with pytest.raises(RuntimeError):
        single.remove_last_anchor()


def test_set_n_anchors_then_load_state_dict():
    """Bit for bit, in one process: the loaded network runs the same weights through the same
    kernels on the same shapes."""
    src = _mlp(k=4, seed=10)
    dst = SubspaceResidualMLP(IN, HID, OUT, n_anchors=1).eval()
    with pytest.raises(RuntimeError):
        dst.load_state_dict(src.state_dict())
    dst.set_n_anchors(4)
    assert dst.n_anchors == 4
    dst.load_state_dict(src.state_dict())
    x, alphas = torch.randn(B, IN), sample_dirichlet(M, 4, _gen())
    torch.testing.assert_close(dst(x, alphas), src(x, alphas), atol=0, rtol=0)
    assert [p.requires_grad for p in dst.head.weights] == [False, False, False, True]
    dst.set_n_anchors(2)
    assert dst.n_anchors == 2 and len(dst.inp_norm.betas) == 2
    torch.testing.assert_close(dst.head.weights[1], src.head.weights[1])


# --- cosine penalty ---------------------------------------------------------------------------


def test_cosine_penalty_values():
    torch.manual_seed(0)
    net = SubspaceResidualMLP(IN, HID, OUT, n_anchors=1)
    zero = cosine_similarity_penalty(net)
    assert zero.shape == () and zero.item() == 0.0
    net.add_anchor("mean")  # identical copy in every layer
    torch.testing.assert_close(cosine_similarity_penalty(net), torch.tensor(1.0))
    net = _mlp(k=3)
    pen = cosine_similarity_penalty(net).item()
    assert 0.0 <= pen <= 1.0 and 0.0 < pen < 1.0 - 1e-3
    # a single linear layer with orthogonal anchors: exactly 0
    lin = SubspaceLinear(2, 1, n_anchors=2)
    with torch.no_grad():
        lin.weights[0].copy_(torch.tensor([[1.0, 0.0]]))
        lin.weights[1].copy_(torch.tensor([[0.0, 1.0]]))
        lin.biases[0].zero_()
        lin.biases[1].zero_()
    assert cosine_similarity_penalty(lin).item() == pytest.approx(0.0, abs=1e-7)
    # opposite anchors: squared cosine is 1
    with torch.no_grad():
        lin.weights[1].copy_(-lin.weights[0])
    assert cosine_similarity_penalty(lin).item() == pytest.approx(1.0, abs=1e-6)


def test_training_mix_follows_changes_to_frozen_anchors():
    """The frozen anchors' rows are kept between steps; writing to a frozen anchor, or
    replacing the anchors, must show in the next training mix."""
    torch.manual_seed(0)
    net = SubspaceResidualMLP(4, 8, 2, n_anchors=1)
    net.add_anchor("random")
    net.add_anchor("random")
    alpha = torch.tensor([0.2, 0.3, 0.5], requires_grad=True)

    def mixed_matches_layers() -> bool:
        mixed = net._mixed_parameters(alpha)
        plain = [t for layer in net._layers() for t in layer.mixed(alpha.detach())]
        return all(torch.allclose(a, b, atol=1e-6) for a, b in zip(mixed, plain, strict=True))

    assert mixed_matches_layers()
    with torch.no_grad():
        net.inp_linear.weights[0].add_(1.0)  # an in-place write to a frozen anchor
    assert mixed_matches_layers()
    net.remove_last_anchor()
    net.add_anchor("random")  # a new newest anchor, the older ones the same objects
    assert mixed_matches_layers()
    net.set_n_anchors(2)
    net.add_anchor("random")
    with torch.no_grad():
        net.head.biases[1].fill_(3.0)
    assert mixed_matches_layers()
    net.double()  # a cast gives the anchors new storage
    alpha = alpha.detach().double().requires_grad_()
    assert mixed_matches_layers()
    loss = sum(t.sum() for t in net._mixed_parameters(alpha))
    loss.backward()
    assert all(p.grad is None for p in net.parameters() if not p.requires_grad)
    assert alpha.grad is not None and net.head.weights[-1].grad is not None
