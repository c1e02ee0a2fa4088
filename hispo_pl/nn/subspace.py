"""Subspaces of networks: K anchors per layer, mixed in parameter space.

A point of the subspace is a convex combination ``θ(α) = Σ_k α_k θ_k`` of the anchors' weights,
biases and LayerNorm affines. Mixing the parameters (not the outputs) keeps one forward as cheap
as a plain network's whatever K is; a batch of M points ``α`` of shape [M, K] runs as one
``baddbmm``. Growing the subspace appends an anchor and freezes the older ones, so what was
learned on earlier tasks stays reachable and only the newest direction trains.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from functools import partial
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from hispo_pl.nn import fast
from hispo_pl.nn.mlp import FastDropout, ResidualMLP, _init_linear
from hispo_pl.nn.residual import residual_mlp_maths
from hispo_pl.nn.simplex import check_alpha

AnchorInit = Literal["mean", "random", "first"]


class SubspaceLayer(nn.Module):
    """Anchor bookkeeping shared by the subspace layers.

    A subclass lists the names of its ``nn.ParameterList`` attributes in ``anchor_lists`` (one
    Parameter per anchor in each, so older anchors can be frozen one by one) and says how to
    initialise a fresh anchor in ``_fresh_anchor``.
    """

    mixes_as_rows = True
    """Its anchors are whole parameter copies, so one row product over the network mixes them
    (a low-rank layer's are not)."""

    anchor_lists: tuple[str, ...] = ()

    def _fresh_anchor(self) -> tuple[Tensor, ...]:
        """One freshly initialised tensor per entry of ``anchor_lists``."""
        raise NotImplementedError

    def _lists(self) -> list[nn.ParameterList]:
        return [getattr(self, name) for name in self.anchor_lists]

    def _init_anchors(self, n_anchors: int) -> None:
        """Independent fresh anchors, all trainable: nothing has been learned yet to protect."""
        if n_anchors < 1:
            raise ValueError(f"need at least one anchor, got {n_anchors}")
        fresh = [self._fresh_anchor() for _ in range(n_anchors)]
        for i, name in enumerate(self.anchor_lists):
            setattr(self, name, nn.ParameterList([nn.Parameter(f[i]) for f in fresh]))

    @property
    def n_anchors(self) -> int:
        return len(self._lists()[0])

    def _used(self, alpha: Tensor) -> int:
        """Anchors one stored weight vector mixes: up to its last non-zero weight. Anchors
        added after a task get weight 0 in its row; leaving them out of the sum keeps that
        task's parameters bit-identical (a zero-weighted term still changes how the reduction
        rounds), so BWT stays exactly 0. Trained weights (requiring grad) mix every anchor."""
        if alpha.requires_grad:
            return alpha.shape[-1]
        nonzero = torch.nonzero(alpha)
        return int(nonzero.max()) + 1 if len(nonzero) else alpha.shape[-1]

    def anchor_vectors(self) -> Tensor:
        """All of each anchor's parameters flattened into one row: [K, D]."""
        rows = [
            torch.cat([plist[k].reshape(-1) for plist in self._lists()])
            for k in range(self.n_anchors)
        ]
        return torch.stack(rows)

    def _set_trainable_last(self) -> None:
        """Older anchors frozen, newest trainable: the layout while learning a new task."""
        last = self.n_anchors - 1
        for plist in self._lists():
            for k, p in enumerate(plist):
                p.requires_grad_(k == last)

    @torch.no_grad()
    def add_anchor(self, init: AnchorInit = "mean") -> None:
        """Append an anchor (the mean of the existing ones, a fresh init, or a copy of the
        ``first``) and make it the only trainable one; starting from the mean keeps the
        subspace's centre unchanged."""
        new = self._new_anchor(init)
        for plist, tensor in zip(self._lists(), new, strict=True):
            plist.append(nn.Parameter(tensor.clone()))
        self._set_trainable_last()

    def _new_anchor(self, init: AnchorInit) -> list[Tensor]:
        """Starting values of a new anchor, one tensor per entry of ``anchor_lists``."""
        if init == "mean":
            return [torch.stack(list(plist)).mean(0) for plist in self._lists()]
        if init == "first":
            return [plist[0] for plist in self._lists()]
        if init == "random":
            ref = self._lists()[0][0]
            return [t.to(device=ref.device, dtype=ref.dtype) for t in self._fresh_anchor()]
        raise ValueError(f"unknown anchor init {init!r}; expected 'mean', 'random' or 'first'")

    def remove_last_anchor(self) -> None:
        """Drop the newest anchor (a pruned extension); the remaining ones are all frozen."""
        if self.n_anchors <= 1:
            raise RuntimeError("cannot remove the only anchor of a subspace")
        self._truncate(self.n_anchors - 1)
        for plist in self._lists():
            for p in plist:
                p.requires_grad_(False)

    def _truncate(self, k: int) -> None:
        for name in self.anchor_lists:
            setattr(self, name, nn.ParameterList(list(getattr(self, name))[:k]))

    @torch.no_grad()
    def set_n_anchors(self, k: int) -> None:
        """Resize to ``k`` anchors (zero placeholders when growing) so that a checkpoint with
        ``k`` anchors loads with ``load_state_dict``; the newest anchor is left trainable."""
        if k < 1:
            raise ValueError(f"need at least one anchor, got {k}")
        if k < self.n_anchors:
            self._truncate(k)
        for plist in self._lists():
            while len(plist) < k:
                plist.append(nn.Parameter(torch.zeros_like(plist[0])))
        self._set_trainable_last()


class SubspaceLinear(SubspaceLayer):
    """A linear layer whose weight and bias are a convex mix of K anchors."""

    anchor_lists = ("weights", "biases")

    def __init__(self, in_features: int, out_features: int, n_anchors: int = 1):
        super().__init__()
        self.in_features, self.out_features = in_features, out_features
        self._init_anchors(n_anchors)

    def _fresh_anchor(self) -> tuple[Tensor, ...]:
        layer = nn.Linear(self.in_features, self.out_features)
        _init_linear(layer)
        return layer.weight.detach(), layer.bias.detach()

    def forward(self, x: Tensor, alpha: Tensor) -> Tensor:
        """alpha [K]: x [..., in] → [..., out]. alpha [M, K]: x [B, in] (shared by all M) or
        [M, ..., in] → [M, ..., out], one batched matmul for the M mixed weights."""
        check_alpha(alpha, self.n_anchors)
        if alpha.dim() == 1:
            return F.linear(x, *self.mixed(alpha))
        weights, biases = torch.stack(list(self.weights)), torch.stack(list(self.biases))
        weight_t = torch.einsum("mk,koi->mio", alpha, weights)  # [M, in, out]
        return batched_affine(x, weight_t, alpha @ biases)

    def mixed(self, alpha: Tensor) -> tuple[Tensor, Tensor]:
        """The weight [out, in] and bias [out] of one point ``alpha`` [K] of the subspace."""
        check_alpha(alpha, self.n_anchors)
        k = self._used(alpha)
        weights = torch.stack(list(self.weights)[:k])
        bias = alpha[:k] @ torch.stack(list(self.biases)[:k])
        return torch.einsum("k,koi->oi", alpha[:k], weights), bias

    def extra_repr(self) -> str:
        return (
            f"in_features={self.in_features}, out_features={self.out_features}, "
            f"n_anchors={self.n_anchors}"
        )


def batched_affine(x: Tensor, weight_t: Tensor, bias: Tensor) -> Tensor:
    """M affine maps in one ``baddbmm``: weight_t [M, in, out], bias [M, out]; x [B, in]
    (shared by all M) or [M, ..., in] → [M, B, out] or [M, ..., out]."""
    m, in_features, out_features = weight_t.shape
    bias = bias.unsqueeze(1)  # [M, 1, out]
    if x.dim() == 2:
        return torch.baddbmm(bias, x.expand(m, *x.shape), weight_t)
    if x.shape[0] != m:
        raise ValueError(f"x has leading dim {x.shape[0]} but alpha has {m} rows")
    out = torch.baddbmm(bias, x.reshape(m, -1, in_features), weight_t)
    return out.reshape(*x.shape[:-1], out_features)


class SubspaceLayerNorm(SubspaceLayer):
    """LayerNorm whose affine γ, β are a convex mix of K anchors."""

    anchor_lists = ("gammas", "betas")

    def __init__(self, dim: int, n_anchors: int = 1, eps: float = 1e-5):
        super().__init__()
        self.dim, self.eps = dim, eps
        self._init_anchors(n_anchors)

    def _fresh_anchor(self) -> tuple[Tensor, ...]:
        return torch.ones(self.dim), torch.zeros(self.dim)

    def forward(self, x: Tensor, alpha: Tensor) -> Tensor:
        """alpha [K]: x [..., dim] → same shape. alpha [M, K]: x [B, dim] (shared by all M) or
        [M, ..., dim] → [M, ..., dim]."""
        check_alpha(alpha, self.n_anchors)
        if alpha.dim() == 1:
            return F.layer_norm(x, (self.dim,), *self.mixed(alpha), self.eps)
        gammas, betas = torch.stack(list(self.gammas)), torch.stack(list(self.betas))
        m = alpha.shape[0]
        normed = F.layer_norm(x, (self.dim,), eps=self.eps)
        if x.dim() == 2:
            normed = normed.unsqueeze(0)
        elif x.shape[0] != m:
            raise ValueError(f"x has leading dim {x.shape[0]} but alpha has {m} rows")
        shape = (m,) + (1,) * (normed.dim() - 2) + (self.dim,)
        return torch.addcmul((alpha @ betas).view(shape), normed, (alpha @ gammas).view(shape))

    def mixed(self, alpha: Tensor) -> tuple[Tensor, Tensor]:
        """The affine γ, β [dim] of one point ``alpha`` [K] of the subspace."""
        check_alpha(alpha, self.n_anchors)
        k = self._used(alpha)
        gamma = alpha[:k] @ torch.stack(list(self.gammas)[:k])
        return gamma, alpha[:k] @ torch.stack(list(self.betas)[:k])

    def extra_repr(self) -> str:
        return f"{self.dim}, eps={self.eps}, n_anchors={self.n_anchors}"


def subspace_layers(module: nn.Module) -> Iterator[SubspaceLayer]:
    """Every subspace layer inside ``module`` (itself included), in registration order."""
    return (m for m in module.modules() if isinstance(m, SubspaceLayer))


class SubspaceResidualMLP(nn.Module):
    """``mlp.ResidualMLP`` with every Linear and LayerNorm replaced by its subspace version:
    Linear→LN→GELU→Dropout, a residual block, GELU→Dropout, and a bare linear head."""

    def __init__(
        self, in_dim: int, hidden: int, out_dim: int, dropout: float = 0.1, n_anchors: int = 1
    ):
        super().__init__()
        self.inp_linear = SubspaceLinear(in_dim, hidden, n_anchors)
        self.inp_norm = SubspaceLayerNorm(hidden, n_anchors)
        self.block_linear1 = SubspaceLinear(hidden, hidden, n_anchors)
        self.block_norm1 = SubspaceLayerNorm(hidden, n_anchors)
        self.block_linear2 = SubspaceLinear(hidden, hidden, n_anchors)
        self.block_norm2 = SubspaceLayerNorm(hidden, n_anchors)
        self.head = SubspaceLinear(hidden, out_dim, n_anchors)
        self.drop_inp = FastDropout(dropout)
        self.drop_block = FastDropout(dropout)
        self.drop_out = FastDropout(dropout)
        self._frozen_cache: tuple[list[Tensor], list[int], Tensor] | None = None

    def forward(self, x: Tensor, alpha: Tensor) -> Tensor:
        """alpha [K]: x [B, in] → [B, out]. alpha [M, K]: x [B, in] or [M, B, in] → [M, B, out].

        Training on one point (alpha [K], gradients on) mixes each layer's parameters once and
        runs the plain network's fast path (:func:`~hispo_pl.nn.fast.residual_mlp`)."""
        if alpha.dim() == 1 and self.training and torch.is_grad_enabled() and fast.enabled():
            params = self._mixed_parameters(alpha)
            shape = (*x.shape[:-1], self.inp_norm.dim)
            dropout = self.drop_inp.draw(3, shape, x)
            eps = (self.inp_norm.eps, self.block_norm1.eps, self.block_norm2.eps)
            return fast.residual_mlp(x, params, dropout, eps)
        linears = (self.inp_linear, self.block_linear1, self.block_linear2, self.head)
        norms = (self.inp_norm, self.block_norm1, self.block_norm2)
        return residual_mlp_maths(
            x,
            [partial(layer, alpha=alpha) for layer in linears],
            [partial(layer, alpha=alpha) for layer in norms],
            (self.drop_inp, self.drop_block, self.drop_out),
        )

    def _layers(self) -> tuple[SubspaceLayer, ...]:
        """The layers in :func:`~hispo_pl.nn.fast.residual_mlp`'s parameter order."""
        return (
            self.inp_linear,
            self.inp_norm,
            self.block_linear1,
            self.block_norm1,
            self.block_linear2,
            self.block_norm2,
            self.head,
        )

    def _mixed_parameters(self, alpha: Tensor) -> list[Tensor]:
        """Every layer's parameters at the point ``alpha`` [K], in :meth:`_layers` order.

        While the weights train (``alpha`` requires grad, every anchor mixed) and all layers
        are full subspace layers, the whole network is mixed in one product: each anchor's
        parameters side by side in one row, ``alpha @ rows``, split back into tensors (a few
        ops instead of a few per layer); while only the newest anchor trains, the older rows
        are kept between steps (:meth:`_frozen_rows`, :func:`~hispo_pl.nn.fast.mix_newest`);
        with one anchor, its parameters are the point. Otherwise each layer mixes its own
        (which also leaves out trailing zero-weighted anchors, see
        :meth:`SubspaceLayer._used`)."""
        layers = self._layers()
        if not alpha.requires_grad or not all(layer.mixes_as_rows for layer in layers):
            return [t for layer in layers for t in layer.mixed(alpha)]
        check_alpha(alpha, self.n_anchors)
        # each tensor's anchors, read without ParameterList's per-item lookup
        anchors = [
            tuple(plist._parameters.values()) for layer in layers for plist in layer._lists()
        ]
        k = len(alpha)
        if k == 1:  # a weight over one anchor is exactly 1 (and has no free direction)
            return [a[0] for a in anchors]
        frozen = self._frozen_rows(anchors)
        if frozen is not None:  # the usual layout of a task: only the newest anchor trains
            return fast.mix_newest(alpha, frozen, [a[-1] for a in anchors])
        rows = torch.cat([a[i].reshape(-1) for i in range(k) for a in anchors])
        mixed = alpha @ rows.view(k, -1)
        shapes = [a[0].shape for a in anchors]
        parts = mixed.split([math.prod(shape) for shape in shapes])
        return [part.view(shape) for part, shape in zip(parts, shapes, strict=True)]

    def _frozen_rows(self, anchors: list[tuple[Tensor, ...]]) -> Tensor | None:
        """The older anchors' parameters as rows [K - 1, D], kept between steps, when every
        older anchor is frozen and the newest trains (else ``None``). ``anchors``: each
        tensor's anchors, in the network's order.

        Copying every anchor into one matrix each step, and back-propagating a gradient
        into all of it, costs a network's parameters K times over; frozen anchors do not
        change while a task trains, so their rows are built once and rebuilt only when one
        of them is replaced or written to (its tensor or its version counter changes)."""
        older = [p for i in range(len(anchors[0]) - 1) for p in (a[i] for a in anchors)]
        if any(p.requires_grad for p in older) or not all(a[-1].requires_grad for a in anchors):
            return None
        cached = self._frozen_cache
        if cached is not None and len(cached[0]) == len(older):
            params, versions, rows = cached
            if all(
                p is q and p._version == v for p, q, v in zip(older, params, versions, strict=True)
            ):
                return rows
        with torch.no_grad():
            rows = torch.cat([p.reshape(-1) for p in older]).view(len(anchors[0]) - 1, -1)
        self._frozen_cache = (older, [p._version for p in older], rows)
        return rows

    def _apply(self, fn, recurse=True):
        self._frozen_cache = None  # a move or cast gives the anchors new storage
        return super()._apply(fn, recurse)

    @property
    def n_anchors(self) -> int:
        return next(subspace_layers(self)).n_anchors

    def add_anchor(self, init: AnchorInit = "mean") -> None:
        for layer in subspace_layers(self):
            layer.add_anchor(init)

    def remove_last_anchor(self) -> None:
        for layer in subspace_layers(self):
            layer.remove_last_anchor()

    def set_n_anchors(self, k: int) -> None:
        for layer in subspace_layers(self):
            layer.set_n_anchors(k)

    @torch.no_grad()
    def load_residual_mlp(self, plain: ResidualMLP, anchor: int = 0) -> None:
        """Copy a plain ``ResidualMLP``'s parameters into one anchor (e.g. a pretrained start)."""
        pairs: list[tuple[SubspaceLayer, nn.Module]] = [
            (self.inp_linear, plain.inp[0]),
            (self.inp_norm, plain.inp[1]),
            (self.block_linear1, plain.block[0]),
            (self.block_norm1, plain.block[1]),
            (self.block_linear2, plain.block[4]),
            (self.block_norm2, plain.block[5]),
            (self.head, plain.head),
        ]
        for layer, src in pairs:
            first, second = layer._lists()
            first[anchor].copy_(src.weight)
            second[anchor].copy_(src.bias)


def cosine_similarity_penalty(module: nn.Module) -> Tensor:
    """Mean over subspace layers of the mean squared cosine similarity between anchor pairs.

    Pushes anchors towards orthogonal directions so the subspace spans distinct behaviours;
    in [0, 1], and 0 when no layer has two anchors.
    """
    per_layer = []
    device = None
    for layer in subspace_layers(module):
        device = layer._lists()[0][0].device
        k = layer.n_anchors
        if k < 2:
            continue
        unit = F.normalize(layer.anchor_vectors(), dim=1)
        cos = unit @ unit.T
        i, j = torch.triu_indices(k, k, offset=1, device=cos.device)
        per_layer.append(cos[i, j].pow(2).mean())
    if not per_layer:
        return torch.zeros((), device=device)
    return torch.stack(per_layer).mean()
