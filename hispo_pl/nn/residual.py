"""The residual MLP backbone's maths, written once, over the layers a network supplies."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch.nn.functional as F
from torch import Tensor

Layer = Callable[[Tensor], Tensor]


def residual_mlp_maths(
    x: Tensor, linears: Sequence[Layer], norms: Sequence[Layer], drops: Sequence[Layer]
) -> Tensor:
    """The backbone's maths, written once: Linear→LN→GELU→dropout, a residual block
    (Linear→LN→GELU→dropout→Linear→LN) added to its input, GELU→dropout, and a bare linear
    head. ``linears``: the input layer, the block's two and the head (4); ``norms``: the
    input's and the block's two LayerNorms (3); ``drops``: the input's, the block's and the
    output's dropout (3), each a map of a tensor. Every network of the backbone (plain, a
    subspace of them, a progressive column) is this with its own layers; the fast path
    (:func:`~hispo_pl.nn.fast.residual_mlp`) is its hand-written gradient for one set of
    parameters, pinned to it by ``tests/methods/test_fast_step.py``."""
    h = drops[0](F.gelu(norms[0](linears[0](x))))
    b = drops[1](F.gelu(norms[1](linears[1](h))))
    b = norms[2](linears[2](b))
    return linears[3](drops[2](F.gelu(h + b)))
