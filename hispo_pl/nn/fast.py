"""The fast training path of the residual MLP backbone (plain and subspace), same maths.

A training step of the backbone is a few large matmuls and a dozen elementwise passes over
``[batch, hidden]`` activations. Autograd runs each pass as its own node; here the whole
network (Linear→LN→GELU→dropout, the residual block, GELU→dropout, the head) is one autograd
:class:`torch.autograd.Function` with a hand-written backward: the same aten kernels
(``addmm``, ``native_layer_norm``, ``gelu`` and their backwards), in place where a buffer is
fresh, and no per-op graph bookkeeping. Dropout masks come from random 64-bit words viewed
as bytes (one draw for all of a network's masks), which keeps :class:`~hispo_pl.nn.mlp.
FastDropout`'s distribution (keep a unit iff a uniform byte ≥ ``threshold``).

Networks take this path while training with gradients enabled; evaluation, ``torch.func``
transforms (which run in eval mode here) and batched subspace weights keep the plain modules.
:func:`reference_path` switches the fast path off (plain modules, byte-by-byte masks, the
default Adam, logging every step): the baseline of ``tests/test_fast_step.py`` and
``benchmarks/step_speed.py``.
"""

from __future__ import annotations

import ctypes
import math
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import torch
import torch.nn.functional as F
from torch import Tensor

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


def dropout_masks(
    count: int, shape: Sequence[int], threshold: int, scale: float, like: Tensor
) -> list[Tensor]:
    """``count`` inverted-dropout masks of ``shape`` (dtype and device of ``like``): ``scale``
    where a uniform random byte is ≥ ``threshold``, else 0.

    Fast path: the bytes of one draw of full-range 64-bit words for all masks, compared
    straight into a float buffer. Reference path: one uint8 draw per mask, compared, cast.
    """
    n = math.prod(shape)
    if not _enabled:
        out = []
        for _ in range(count):
            noise = torch.empty(tuple(shape), dtype=torch.uint8, device=like.device).random_()
            out.append((noise >= threshold).to(like.dtype).mul_(scale))
        return out
    words = torch.empty((count * n + 7) // 8, dtype=torch.int64, device=like.device)
    noise = words.random_(_INT64_MIN, None).view(torch.uint8)[: count * n]
    masks = torch.empty((count, *shape), dtype=like.dtype, device=like.device)
    torch.ge(noise.view(masks.shape), threshold, out=masks)
    return list(masks.mul_(scale).unbind(0))


def residual_mlp(
    x: Tensor,
    params: Sequence[Tensor],
    masks: Sequence[Tensor] | None,
    eps: Sequence[float] = (1e-5, 1e-5, 1e-5),
) -> Tensor:
    """The residual MLP's training forward as one autograd node.

    ``params``: the input linear's weight and bias, its LayerNorm's weight and bias, the
    block's two (linear, LayerNorm) pairs likewise, and the head's weight and bias (14
    tensors, weights ``[out, in]`` as ``nn.Linear`` keeps them). ``masks``: the three dropout
    masks (input, block, output; already scaled), or ``None`` for no dropout. ``eps``: the
    three LayerNorms' epsilons.
    """
    if len(params) != 14:
        raise ValueError(f"residual_mlp takes 14 parameter tensors, got {len(params)}")
    m0, m1, m2 = masks if masks is not None else (None, None, None)
    return _ResidualMLPFunction.apply(x, m0, m1, m2, tuple(eps), *params)


def residual_mlp_reference(
    x: Tensor,
    params: Sequence[Tensor],
    masks: Sequence[Tensor] | None,
    eps: Sequence[float] = (1e-5, 1e-5, 1e-5),
) -> Tensor:
    """:func:`residual_mlp` with plain autograd ops (its definition, for tests)."""
    w0, b0, g0, e0, w1, b1, g1, e1, w2, b2, g2, e2, wh, bh = params
    m0, m1, m2 = masks if masks is not None else (1.0, 1.0, 1.0)
    hidden = (w0.shape[0],)
    h = F.gelu(F.layer_norm(F.linear(x, w0, b0), hidden, g0, e0, eps[0])) * m0
    b = F.gelu(F.layer_norm(F.linear(h, w1, b1), hidden, g1, e1, eps[1])) * m1
    b = F.layer_norm(F.linear(b, w2, b2), hidden, g2, e2, eps[2])
    return F.linear(F.gelu(h + b) * m2, wh, bh)


def _ln_gelu_drop(a: Tensor, g: Tensor, e: Tensor, eps: float, m: Tensor | None):
    """LayerNorm → GELU → dropout; returns the output and what the backward needs."""
    z, mu, rstd = _aten.native_layer_norm(a, (a.shape[-1],), g, e, eps)
    y = F.gelu(z)
    if m is not None:
        y.mul_(m)
    return y, z, mu, rstd


def _ln_backward(dz: Tensor, a: Tensor, mu: Tensor, rstd: Tensor, g: Tensor, e: Tensor):
    return _aten.native_layer_norm_backward(
        dz, a, (a.shape[-1],), mu, rstd, g, e, [True, True, True]
    )


def _linear_backward(da: Tensor, inp: Tensor) -> tuple[Tensor, Tensor]:
    """Weight and bias gradients of ``a = inp @ W.T + b`` (2-D).

    A GEMM whose result has few columns is several times slower than its transpose (a
    network's first layer has few inputs), so the product is taken with the smaller side
    first."""
    if inp.shape[1] < da.shape[1]:
        return inp.t().mm(da).t().contiguous(), da.sum(0)
    return da.t().mm(inp), da.sum(0)


class _ResidualMLPFunction(torch.autograd.Function):
    """Forward and hand-written backward of :func:`residual_mlp` (2-D input)."""

    @staticmethod
    def forward(ctx, x, m0, m1, m2, eps, w0, b0, g0, e0, w1, b1, g1, e1, w2, b2, g2, e2, wh, bh):
        lead = x.shape[:-1]
        x2 = x.reshape(-1, x.shape[-1])
        a0 = torch.addmm(b0, x2, w0.t())
        h0, z0, mu0, rs0 = _ln_gelu_drop(a0, g0, e0, eps[0], _flat(m0))
        a1 = torch.addmm(b1, h0, w1.t())
        u1, z1, mu1, rs1 = _ln_gelu_drop(a1, g1, e1, eps[1], _flat(m1))
        a2 = torch.addmm(b2, u1, w2.t())
        s, mu2, rs2 = _aten.native_layer_norm(a2, (a2.shape[-1],), g2, e2, eps[2])
        s.add_(h0)  # the residual sum, input of the output GELU
        h2 = F.gelu(s)
        if m2 is not None:
            h2.mul_(_flat(m2))
        out = torch.addmm(bh, h2, wh.t())
        ctx.save_for_backward(
            x2, w0, g0, e0, w1, g1, e1, w2, g2, e2, wh, _flat(m0), _flat(m1), _flat(m2),
            a0, mu0, rs0, z0, h0, a1, mu1, rs1, z1, u1, a2, mu2, rs2, s, h2,
        )  # fmt: skip
        ctx.has_masks = m0 is not None
        ctx.lead = lead
        return out.reshape(*lead, out.shape[-1])

    @staticmethod
    def backward(ctx, dout):
        saved = ctx.saved_tensors
        x, w0, g0, e0, w1, g1, e1, w2, g2, e2, wh, m0, m1, m2 = saved[:14]
        a0, mu0, rs0, z0, h0, a1, mu1, rs1, z1, u1, a2, mu2, rs2, s, h2 = saved[14:]
        dout = dout.reshape(-1, dout.shape[-1])
        dwh, dbh = _linear_backward(dout, h2)
        dh2 = dout.mm(wh)
        if ctx.has_masks:
            dh2.mul_(m2)
        ds = _aten.gelu_backward(dh2, s)  # flows into the block's output and the skip
        da2, dg2, de2 = _ln_backward(ds, a2, mu2, rs2, g2, e2)
        dw2, db2 = _linear_backward(da2, u1)
        du1 = da2.mm(w2)
        if ctx.has_masks:
            du1.mul_(m1)
        da1, dg1, de1 = _ln_backward(_aten.gelu_backward(du1, z1), a1, mu1, rs1, g1, e1)
        dw1, db1 = _linear_backward(da1, h0)
        dh0 = torch.addmm(ds, da1, w1)  # the skip's gradient plus the block's
        if ctx.has_masks:
            dh0.mul_(m0)
        da0, dg0, de0 = _ln_backward(_aten.gelu_backward(dh0, z0), a0, mu0, rs0, g0, e0)
        dw0, db0 = _linear_backward(da0, x)
        dx = da0.mm(w0).reshape(*ctx.lead, x.shape[-1]) if ctx.needs_input_grad[0] else None
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
