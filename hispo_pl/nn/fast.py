"""The fast training path of the residual MLP backbone (plain and subspace), same maths.

A training step of the backbone is a few large matmuls and a dozen elementwise passes over
``[batch, hidden]`` activations. Autograd runs each pass as its own node; here the whole
network (Linear→LN→GELU→dropout, the residual block, GELU→dropout, the head) is one autograd
:class:`torch.autograd.Function` with a hand-written backward and no per-op graph
bookkeeping. Each layer's LayerNorm → GELU → dropout runs as aten's kernels
(``native_layer_norm``, ``gelu`` and their backwards, in place where a buffer is fresh), on
any device torch runs on. Dropout is one draw of random bytes for all of a network's masks
(:func:`dropout_bytes`), which keeps :class:`~hispo_pl.nn.mlp.FastDropout`'s distribution
(keep a unit iff a uniform byte ≥ ``threshold``).

Networks take this path while training with gradients enabled; evaluation, ``torch.func``
transforms (which run in eval mode here) and batched subspace weights keep the plain modules.
:func:`reference_path` switches the fast path off (plain modules, byte-by-byte masks, the
default Adam, logging every step): the baseline of ``tests/methods/test_fast_step.py`` and
``benchmarks/step_speed.py``.
"""

from __future__ import annotations

import ctypes
import math
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from functools import partial
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor

from .residual import residual_mlp_maths

_aten = torch.ops.aten
_INT64_MIN = -(2**63)
_enabled = True
_allocator_tuned = False


def enabled() -> bool:
    """Whether networks and optimisers take the fast path (see :func:`reference_path`)."""
    return _enabled


@contextmanager
def reference_path() -> Iterator[None]:
    """Plain autograd modules, masks drawn byte by byte, the default (per-tensor) Adam and a
    log call every step, as before the fast path: the baseline of the tests and benchmarks.
    Modules and optimisers built or run inside the block use it."""
    global _enabled
    previous, _enabled = _enabled, False
    try:
        yield
    finally:
        _enabled = previous


def retain_freed_memory() -> bool:
    """Let glibc serve blocks under 32 MiB from its heap and keep up to 128 MiB of freed memory
    instead of handing it back to the system at once.

    A training step allocates and frees dozens of megabyte-sized activations; with glibc's
    defaults many of them are fresh ``mmap`` pages, and the page faults and zeroing cost a
    step about as much as its elementwise work. The setting is process-wide and idempotent;
    returns whether it applies (Linux with glibc). Called when a fast-path optimiser is built.
    """
    global _allocator_tuned
    if _allocator_tuned or not sys.platform.startswith("linux"):
        return _allocator_tuned
    try:
        libc = ctypes.CDLL("libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3  # from glibc's malloc.h
        ok = libc.mallopt(m_mmap_threshold, 32 << 20) and libc.mallopt(m_trim_threshold, 128 << 20)
    except (OSError, AttributeError):
        return False
    _allocator_tuned = bool(ok)
    return _allocator_tuned


class DropoutDraw(NamedTuple):
    """One draw of dropout for ``count`` masks: a unit is kept, and scaled by ``scale``, iff its
    random byte in ``noise`` (uint8 ``[count, *shape]``) is ≥ ``threshold``."""

    noise: Tensor
    threshold: int
    scale: float

    def masks(self, dtype: torch.dtype) -> list[Tensor]:
        """The ``count`` masks as ``dtype`` tensors: ``scale`` where kept, else 0."""
        masks = torch.empty(self.noise.shape, dtype=dtype, device=self.noise.device)
        torch.ge(self.noise, self.threshold, out=masks)
        return list(masks.mul_(self.scale).unbind(0))


def dropout_bytes(count: int, shape: Sequence[int], device: torch.device) -> Tensor:
    """Uniform random bytes, uint8 ``[count, *shape]``: on the fast path the bytes of one draw
    of full-range 64-bit words, on the reference path one draw per byte."""
    full = (count, *shape)
    if not _enabled:
        return torch.empty(full, dtype=torch.uint8, device=device).random_()
    n = math.prod(full)
    words = torch.empty((n + 7) // 8, dtype=torch.int64, device=device)
    return words.random_(_INT64_MIN, None).view(torch.uint8)[:n].view(full)


def dropout_masks(
    count: int, shape: Sequence[int], threshold: int, scale: float, like: Tensor
) -> list[Tensor]:
    """``count`` inverted-dropout masks of ``shape`` (dtype and device of ``like``): ``scale``
    where a uniform random byte is ≥ ``threshold``, else 0."""
    noise = dropout_bytes(count, shape, like.device)
    return DropoutDraw(noise, threshold, scale).masks(like.dtype)


def residual_mlp(
    x: Tensor,
    params: Sequence[Tensor],
    dropout: DropoutDraw | None,
    eps: Sequence[float] = (1e-5, 1e-5, 1e-5),
) -> Tensor:
    """The residual MLP's training forward as one autograd node.

    ``params``: the input linear's weight and bias, its LayerNorm's weight and bias, the
    block's two (linear, LayerNorm) pairs likewise, and the head's weight and bias (14
    tensors, weights ``[out, in]`` as ``nn.Linear`` keeps them). ``dropout``: the draw of the
    three masks (input, block, output; ``noise`` of shape ``[3, *x.shape[:-1], hidden]``), or
    ``None`` for no dropout. ``eps``: the three LayerNorms' epsilons.
    """
    if len(params) != 14:
        raise ValueError(f"residual_mlp takes 14 parameter tensors, got {len(params)}")
    noise, threshold, scale = dropout if dropout is not None else (None, 0, 1.0)
    return _ResidualMLPFunction.apply(x, noise, threshold, scale, tuple(eps), *params)


def residual_mlp_reference(
    x: Tensor,
    params: Sequence[Tensor],
    dropout: DropoutDraw | None,
    eps: Sequence[float] = (1e-5, 1e-5, 1e-5),
) -> Tensor:
    """:func:`residual_mlp` as :func:`~hispo_pl.nn.residual.residual_mlp_maths` with plain autograd
    ops: the definition its backward is checked against."""
    w0, b0, g0, e0, w1, b1, g1, e1, w2, b2, g2, e2, wh, bh = params
    masks = dropout.masks(x.dtype) if dropout is not None else (None,) * 3
    hidden = (w0.shape[0],)
    linears = [partial(F.linear, weight=w, bias=b) for w, b in ((w0, b0), (w1, b1), (w2, b2))]
    norms = [
        partial(F.layer_norm, normalized_shape=hidden, weight=g, bias=e, eps=eps[i])
        for i, (g, e) in enumerate(((g0, e0), (g1, e1), (g2, e2)))
    ]
    drops = [(lambda h: h) if m is None else partial(torch.mul, other=m) for m in masks]
    return residual_mlp_maths(x, [*linears, partial(F.linear, weight=wh, bias=bh)], norms, drops)


class _AtenLayers:
    """LayerNorm → GELU → dropout with aten kernels and float masks: each layer saves its
    input, the rows' statistics and the GELU's input."""

    def __init__(self, noise: Tensor | None, threshold: int, scale: float, dtype: torch.dtype):
        masks = DropoutDraw(noise, threshold, scale).masks(dtype) if noise is not None else None
        self.masks = [_flat(m) for m in masks] if masks is not None else [None] * 3

    def forward(self, i: int, a: Tensor, g: Tensor, e: Tensor, eps: float, res=None):
        pre, mu, rstd = _aten.native_layer_norm(a, (a.shape[-1],), g, e, eps)
        if res is not None:
            pre.add_(res)
        y = F.gelu(pre)
        if self.masks[i] is not None:
            y.mul_(self.masks[i])
        return y, (a, mu, rstd, pre)

    def backward(self, i: int, dy: Tensor, saved, g: Tensor, e: Tensor, res=None, dpre=False):
        """``dpre`` (when asked), ``da``, ``dg``, ``de`` and ``da``'s column sums (the bias
        gradient of the linear layer that made ``a``); ``dy`` is overwritten."""
        a, mu, rstd, pre = saved
        if self.masks[i] is not None:
            dy.mul_(self.masks[i])
        d_pre = _aten.gelu_backward(dy, pre)
        da, dg, de = _aten.native_layer_norm_backward(
            d_pre, a, (a.shape[-1],), mu, rstd, g, e, [True, True, True]
        )
        return (d_pre if dpre else None), da, dg, de, da.sum(0)


def _weight_grad(da: Tensor, inp: Tensor) -> Tensor:
    """The weight gradient of ``a = inp @ W.T + b`` (2-D).

    A GEMM whose result has few columns is several times slower than its transpose (a
    network's first layer has few inputs), so the product is taken with the smaller side
    first."""
    if inp.shape[1] < da.shape[1]:
        return inp.t().mm(da).t().contiguous()
    return da.t().mm(inp)


class _ResidualMLPFunction(torch.autograd.Function):
    """Forward and hand-written backward of :func:`residual_mlp` (2-D input)."""

    @staticmethod
    def forward(
        ctx, x, noise, threshold, scale, eps,
        w0, b0, g0, e0, w1, b1, g1, e1, w2, b2, g2, e2, wh, bh,
    ):  # fmt: skip
        lead = x.shape[:-1]
        x2 = x.reshape(-1, x.shape[-1])
        layers = _AtenLayers(noise, threshold, scale, x.dtype)
        a0 = torch.addmm(b0, x2, w0.t())
        h0, saved0 = layers.forward(0, a0, g0, e0, eps[0])
        u1, saved1 = layers.forward(1, torch.addmm(b1, h0, w1.t()), g1, e1, eps[1])
        # the block's last LayerNorm plus the skip is the input of the output GELU
        h2, saved2 = layers.forward(2, torch.addmm(b2, u1, w2.t()), g2, e2, eps[2], res=h0)
        out = torch.addmm(bh, h2, wh.t())
        ctx.save_for_backward(x2, w0, g0, e0, w1, g1, e1, w2, g2, e2, wh)
        ctx.layers, ctx.saved, ctx.lead = layers, (saved0, saved1, saved2, h0, u1, h2), lead
        return out.reshape(*lead, out.shape[-1])

    @staticmethod
    def backward(ctx, dout):
        x, w0, g0, e0, w1, g1, e1, w2, g2, e2, wh = ctx.saved_tensors
        (saved0, saved1, saved2, h0, u1, h2), layers = ctx.saved, ctx.layers
        dout = dout.reshape(-1, dout.shape[-1])
        dwh, dbh = _weight_grad(dout, h2), dout.sum(0)
        # ds, the output GELU's input gradient, flows into the block's output and the skip
        ds, da2, dg2, de2, db2 = layers.backward(2, dout.mm(wh), saved2, g2, e2, h0, dpre=True)
        dw2 = _weight_grad(da2, u1)
        _, da1, dg1, de1, db1 = layers.backward(1, da2.mm(w2), saved1, g1, e1)
        dw1 = _weight_grad(da1, h0)
        dh0 = torch.addmm(ds, da1, w1)  # the skip's gradient plus the block's
        _, da0, dg0, de0, db0 = layers.backward(0, dh0, saved0, g0, e0)
        dw0 = _weight_grad(da0, x)
        dx = da0.mm(w0).reshape(*ctx.lead, x.shape[-1]) if ctx.needs_input_grad[0] else None
        del ctx.layers, ctx.saved  # free the activations now, not with the graph
        grads = (dw0, db0, dg0, de0, dw1, db1, dg1, de1, dw2, db2, dg2, de2, dwh, dbh)
        return (dx, None, None, None, None, *grads)


def mix_newest(alpha: Tensor, frozen: Tensor, newest: Sequence[Tensor]) -> list[Tensor]:
    """``alpha[:-1] @ frozen + alpha[-1] · newest`` split back into ``newest``'s tensors, as
    one autograd node: a subspace's point while only its newest anchor trains.

    ``alpha`` [K]; ``frozen`` [K - 1, D]: the older anchors' parameters as rows (no
    gradient); ``newest``: the newest anchor's tensors (D values in all, in the rows'
    order). Gradients go to ``alpha`` and ``newest``."""
    shapes = tuple(p.shape for p in newest)
    return list(_MixNewestFunction.apply(alpha, frozen, shapes, *newest))


class _MixNewestFunction(torch.autograd.Function):
    """Forward and backward of :func:`mix_newest`: one concatenation each way, one product
    with the frozen rows each way, and no per-tensor graph nodes."""

    @staticmethod
    def forward(ctx, alpha, frozen, shapes, *newest):
        flat = torch.cat([p.reshape(-1) for p in newest])
        mixed = torch.addcmul(alpha[:-1] @ frozen, alpha[-1:], flat)
        ctx.save_for_backward(alpha, frozen, flat)
        ctx.shapes = shapes
        sizes = [math.prod(shape) for shape in shapes]
        return tuple(
            part.view(shape) for part, shape in zip(mixed.split(sizes), shapes, strict=True)
        )

    @staticmethod
    def backward(ctx, *grads):
        alpha, frozen, flat = ctx.saved_tensors
        g = torch.cat([grad.reshape(-1) for grad in grads])
        d_alpha = torch.cat([frozen.mv(g), flat.dot(g).reshape(1)])
        sizes = [math.prod(shape) for shape in ctx.shapes]
        d_newest = g.mul_(alpha[-1]).split(sizes)
        views = (part.view(shape) for part, shape in zip(d_newest, ctx.shapes, strict=True))
        return (d_alpha, None, None, *views)


def _flat(m: Tensor | None) -> Tensor | None:
    return None if m is None else m.reshape(-1, m.shape[-1])
