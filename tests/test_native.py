"""The fused kernels (hispo_pl/nn/fused.c): built here whenever a C compiler is, the same maths
as the aten kernels they replace (row lengths that fill no vector too), and the aten kernels
stand in where they are off."""

from __future__ import annotations

import os
import shutil

import pytest
import torch
import torch.nn.functional as F

from hispo_pl.nn import fast, native
from hispo_pl.nn.mlp import ResidualMLP


def test_kernels_are_built_where_a_compiler_is_unless_turned_off():
    if os.environ.get("HISPO_PL_NATIVE") == "0":  # the suite run with the kernels off
        assert native.library() is None
    elif shutil.which("cc") or shutil.which("gcc"):
        assert native.library() is not None
    else:
        assert native.library() is None


def aten_layer(a, g, e, eps, dropout, res):
    """LayerNorm → (+ res) → GELU → dropout with torch's ops, differentiable."""
    pre = F.layer_norm(a, (a.shape[-1],), g, e, eps)
    if res is not None:
        pre = pre + res
    y = F.gelu(pre)
    if dropout is not None:
        keep, threshold, scale = dropout
        y = y * (keep >= threshold).to(y.dtype) * scale
    return y, pre


@pytest.mark.parametrize("rows, cols", [(64, 256), (7, 37), (1, 3)])
@pytest.mark.parametrize("dropout", [True, False])
@pytest.mark.parametrize("residual", [True, False])
def test_fused_layer_matches_aten(rows, cols, dropout, residual):
    if native.library() is None:
        pytest.skip("no C compiler here: the aten kernels run instead (tested below)")
    gen = torch.Generator().manual_seed(rows * cols)
    a = torch.randn(rows, cols, generator=gen) * 3 + 1
    g, e = torch.rand(cols, generator=gen) + 0.5, torch.randn(cols, generator=gen)
    keep = torch.randint(0, 256, (rows, cols), generator=gen, dtype=torch.uint8)
    res = torch.randn(rows, cols, generator=gen) if residual else None
    threshold, scale = 26, 256 / 230

    dropout = (keep, threshold, scale) if dropout else None
    y, mu, rstd = native.ln_gelu_drop_forward(a, g, e, 1e-5, dropout, res)
    a_, g_, e_ = (t.clone().requires_grad_() for t in (a, g, e))
    y_ref, pre_ref = aten_layer(a_, g_, e_, 1e-5, dropout, res)
    pre_ref.retain_grad()
    torch.testing.assert_close(y, y_ref.detach())
    torch.testing.assert_close(mu, a.mean(1))
    torch.testing.assert_close(rstd, (a.var(1, unbiased=False) + 1e-5).rsqrt())

    dy = torch.randn(rows, cols, generator=gen)
    dpre, da, dg, de, db = native.ln_gelu_drop_backward(
        dy, (a, mu, rstd), g, e, dropout, res, want_dpre=True
    )
    y_ref.backward(dy)
    torch.testing.assert_close(dpre, pre_ref.grad)
    torch.testing.assert_close(da, a_.grad, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(dg, g_.grad, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(de, e_.grad, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(db, a_.grad.sum(0), rtol=1e-4, atol=1e-5)
    no_dpre = native.ln_gelu_drop_backward(dy, (a, mu, rstd), g, e, dropout, res)
    assert no_dpre[0] is None and torch.equal(no_dpre[1], da)


def network_gradients(monkeypatch, lib_state):
    """Output and gradients of a residual MLP's fast path, the kernels on or off."""
    monkeypatch.setattr(native, "_state", lib_state)
    torch.manual_seed(0)
    net = ResidualMLP(5, 33, 3)
    params = net.parameter_tensors()
    x = torch.randn(20, 5)
    dropout = fast.DropoutDraw(torch.randint(0, 256, (3, 20, 33), dtype=torch.uint8), 26, 1.1)
    out = fast.residual_mlp(x, params, dropout)
    return [out, *torch.autograd.grad(out, params, torch.ones_like(out))]


def test_network_fast_path_with_and_without_the_kernels(monkeypatch):
    """The fast path gives the same with the kernels off (no compiler, HISPO_PL_NATIVE=0)."""
    with_kernels = network_gradients(monkeypatch, {})
    monkeypatch.setenv("HISPO_PL_NATIVE", "0")
    without = network_gradients(monkeypatch, {})
    assert native.library() is None and not native.usable(torch.zeros(1))
    for a, b in zip(with_kernels, without, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)


def test_kernels_wait_for_one_thread_float32_contiguous_tensors(monkeypatch):
    if native.library() is None:
        pytest.skip("no C compiler here")
    x = torch.zeros(4, 6)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 1)  # whatever the suite runs at
    assert native.usable(x, None, torch.zeros(4, 6, dtype=torch.uint8))
    assert not native.usable(x.double())
    assert not native.usable(x.t())
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)
    assert not native.usable(x)


def test_a_failed_build_leaves_the_kernels_off(tmp_path):
    assert native.build(compiler=str(tmp_path / "no-such-cc"), directory=tmp_path) is None
    assert native.build(compiler=shutil.which("false") or "false", directory=tmp_path) is None
    assert not list(tmp_path.glob("*.so"))


def test_the_library_is_cached_by_source_and_machine(tmp_path):
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler here")
    first = native.build(compiler, tmp_path)
    assert first is not None and first.parent == tmp_path
    mtime = first.stat().st_mtime_ns
    assert native.build(compiler, tmp_path) == first and first.stat().st_mtime_ns == mtime


def test_an_unwritable_cache_falls_back_to_the_temporary_directory(tmp_path, monkeypatch):
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler here")
    blocked = tmp_path / "file"
    blocked.write_text("not a directory")
    monkeypatch.setenv("HISPO_PL_CACHE", str(blocked / "cache"))
    monkeypatch.setattr(native.tempfile, "gettempdir", lambda: str(tmp_path / "tmp"))
    path = native.build(compiler)
    assert path is not None and path.parent.parent == tmp_path / "tmp"


@pytest.mark.parametrize("n", [1, 7, 8, 4099])
def test_random_bytes_are_uniform_and_follow_torchs_seed(n):
    if native.library() is None:
        pytest.skip("no C compiler here")
    torch.manual_seed(5)
    a = native.random_bytes(torch.empty(n, dtype=torch.uint8))
    torch.manual_seed(5)
    b = native.random_bytes(torch.empty(n, dtype=torch.uint8))
    assert torch.equal(a, b)  # one draw from torch's generator seeds them
    assert not torch.equal(native.random_bytes(torch.empty(n, dtype=torch.uint8)), a) or n == 1
    big = native.random_bytes(torch.empty(256 * 4000, dtype=torch.uint8))
    counts = torch.bincount(big.long(), minlength=256).double()
    chi2 = ((counts - 4000) ** 2 / 4000).sum().item()
    assert chi2 < 400  # 255 degrees of freedom: mean 255, sd 22.6
    # the tail bytes are those of the next word, cut: a prefix of a longer draw
    torch.manual_seed(5)
    longer = native.random_bytes(torch.empty(n + 9, dtype=torch.uint8))
    assert torch.equal(longer[:n], a)


def test_cache_dir_without_a_home(monkeypatch, tmp_path):
    monkeypatch.delenv("HISPO_PL_CACHE", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setattr(native.tempfile, "gettempdir", lambda: str(tmp_path))

    def no_home():
        raise RuntimeError("Could not determine home directory.")

    monkeypatch.setattr(native.Path, "home", staticmethod(no_home))
    assert native.cache_dir().parent == tmp_path
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert native.cache_dir() == tmp_path / "xdg" / "hispo-pl"
