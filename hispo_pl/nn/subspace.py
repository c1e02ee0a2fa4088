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
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from hispo_pl.nn import fast
from hispo_pl.nn.mlp import FastDropout, ResidualMLP, _init_linear

AnchorInit = Literal["mean", "random", "first"]


def sample_dirichlet(
    n: int,
    k: int,
    generator: torch.Generator | None = None,
    *,
    device: torch.device | str | None = None,
) -> Tensor:
    """``n`` exact draws from Dirichlet(1, …, 1) over ``k`` anchors, shape [n, k], float32.

    Stick breaking on sorted uniforms: the gaps between k-1 sorted U[0, 1] points are uniform
    on the simplex, with no Gamma sampling and a deterministic result given ``generator``.
    """
    if k < 1:
        raise ValueError(f"need at least one anchor, got k={k}")
    if device is None and generator is not None:
        device = generator.device
    if k == 1:
        return torch.ones(n, 1, device=device)
    cuts = torch.rand(n, k - 1, generator=generator, device=device).sort(dim=1).values
    zeros = torch.zeros(n, 1, device=cuts.device)
    ones = torch.ones(n, 1, device=cuts.device)
    return torch.diff(torch.cat([zeros, cuts, ones], dim=1), dim=1)


def _check_alpha(alpha: Tensor, n_anchors: int) -> None:
    if alpha.dim() not in (1, 2) or alpha.shape[-1] != n_anchors:
        raise ValueError(
            f"alpha must have shape [{n_anchors}] or [M, {n_anchors}], got {tuple(alpha.shape)}"
        )


class SubspaceLayer(nn.Module):
    """Anchor bookkeeping shared by the subspace layers.

    A subclass lists the names of its ``nn.ParameterList`` attributes in ``anchor_lists`` (one
    Parameter per anchor in each, so older anchors can be frozen one by one) and says how to
    initialise a fresh anchor in ``_fresh_anchor``.
    """

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
        _check_alpha(alpha, self.n_anchors)
        if alpha.dim() == 1:
            return F.linear(x, *self.mixed(alpha))
        weights, biases = torch.stack(list(self.weights)), torch.stack(list(self.biases))
        weight_t = torch.einsum("mk,koi->mio", alpha, weights)  # [M, in, out]
        return _batched_affine(x, weight_t, alpha @ biases)

    def mixed(self, alpha: Tensor) -> tuple[Tensor, Tensor]:
        """The weight [out, in] and bias [out] of one point ``alpha`` [K] of the subspace."""
        _check_alpha(alpha, self.n_anchors)
        k = self._used(alpha)
        weights = torch.stack(list(self.weights)[:k])
        bias = alpha[:k] @ torch.stack(list(self.biases)[:k])
        return torch.einsum("k,koi->oi", alpha[:k], weights), bias

    def extra_repr(self) -> str:
        return (
            f"in_features={self.in_features}, out_features={self.out_features}, "
            f"n_anchors={self.n_anchors}"
        )


def _batched_affine(x: Tensor, weight_t: Tensor, bias: Tensor) -> Tensor:
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


class LowRankSubspaceLinear(SubspaceLayer):
    """A subspace linear layer whose anchors k ≥ 2 are low-rank offsets of the first (LoRA):
    ``W_k = W_1 + A_k B_k`` with ``A_k`` [out, r] and ``B_k`` [r, in] (the paper's HiLOW,
    "for i ≥ 2, θ_i = A_i B_i" as an update of θ_1). Biases keep one full vector per anchor:
    they are small, and a rank-r bias would save nothing.

    The mixed weight is exactly ``Σ_k α_k W_k = (Σ_k α_k) W_1 + Σ_{k≥2} α_k A_k B_k``, built
    with one ``addmm`` (the factors side by side, ``A`` scaled by α) before one plain matmul,
    so a forward costs about what a plain layer's does. A batch of M weight vectors forms the
    K-1 offsets ``A_k B_k`` once, mixes them with ``W_1`` per row and runs one ``baddbmm``, as
    :class:`SubspaceLinear` does (forming ``A diag(α) B`` per row would cost r times more).

    A new anchor starts at ``W_1`` as in LoRA: ``A = 0`` and ``B`` uniform in ±1/√in (the
    Kaiming init LoRA uses), so the product is 0 and ``A`` gets the first gradient. ``mean``
    is not available for the weight: the mean of earlier offsets is not rank r in general;
    ``init`` applies to the biases only. The rank is capped at min(in, out).
    Memory per layer: out·in + K·out + (K-1)·r·(in + out) values, against K·(out·in + out).
    """

    anchor_lists = ("biases",)

    def __init__(self, in_features: int, out_features: int, rank: int, n_anchors: int = 1):
        super().__init__()
        if rank < 1:
            raise ValueError(f"rank must be >= 1, got {rank}")
        self.in_features, self.out_features = in_features, out_features
        self.rank = min(rank, in_features, out_features)
        layer = nn.Linear(in_features, out_features)
        _init_linear(layer)
        self.weight = nn.Parameter(layer.weight.detach())  # W_1, the first anchor's weight
        self.biases = nn.ParameterList([nn.Parameter(layer.bias.detach())])
        self.lora_a = nn.ParameterList()  # A_k of anchors 2..K, [out, r]
        self.lora_b = nn.ParameterList()  # B_k of anchors 2..K, [r, in]
        for _ in range(n_anchors - 1):
            self.add_anchor("first")
        self._set_trainable_last()

    @classmethod
    @torch.no_grad()
    def from_linear(cls, layer: SubspaceLinear, rank: int) -> LowRankSubspaceLinear:
        """The one-anchor ``layer`` as a low-rank subspace layer: the same θ_1, same outputs."""
        if layer.n_anchors != 1:
            raise ValueError(f"convert a layer with one anchor, not {layer.n_anchors}")
        new = cls(layer.in_features, layer.out_features, rank)
        new.weight.copy_(layer.weights[0])
        new.biases[0].copy_(layer.biases[0])
        return new.to(layer.weights[0])

    def _fresh_anchor(self) -> tuple[Tensor, ...]:
        return (torch.zeros(self.out_features),)

    def _zero_factors(self) -> tuple[Tensor, Tensor]:
        """``A`` [out, r] and ``B`` [r, in] filled with zeros, like the layer's weight."""
        a = self.weight.new_zeros(self.out_features, self.rank)
        return a, self.weight.new_zeros(self.rank, self.in_features)

    def _fresh_factors(self) -> tuple[Tensor, Tensor]:
        """LoRA's start: ``A = 0``, ``B`` uniform in ±1/√in, so that ``A B = 0``."""
        a, b = self._zero_factors()
        bound = 1.0 / math.sqrt(self.in_features)
        return a, b.uniform_(-bound, bound)

    def _factor_lists(self) -> list[nn.ParameterList]:
        return [self.lora_a, self.lora_b]

    def _set_trainable_last(self) -> None:
        super()._set_trainable_last()
        last = self.n_anchors - 1
        self.weight.requires_grad_(last == 0)
        for plist in self._factor_lists():
            for j, p in enumerate(plist):  # entry j holds anchor j + 1 (0-based)
                p.requires_grad_(j + 1 == last)

    @torch.no_grad()
    def add_anchor(self, init: AnchorInit = "first") -> None:
        """Append an anchor: its bias as ``init`` says, its weight at ``W_1`` (product 0);
        only the new anchor trains."""
        biases = self._new_anchor(init)  # first: an unknown init changes nothing
        for plist, tensor in zip(self._factor_lists(), self._fresh_factors(), strict=True):
            plist.append(nn.Parameter(tensor))
        for plist, tensor in zip(self._lists(), biases, strict=True):
            plist.append(nn.Parameter(tensor.clone()))
        self._set_trainable_last()

    def remove_last_anchor(self) -> None:
        super().remove_last_anchor()
        for p in self.parameters():
            p.requires_grad_(False)

    def _truncate(self, k: int) -> None:
        super()._truncate(k)
        self.lora_a = nn.ParameterList(list(self.lora_a)[: k - 1])
        self.lora_b = nn.ParameterList(list(self.lora_b)[: k - 1])

    @torch.no_grad()
    def set_n_anchors(self, k: int) -> None:
        if k < 1:
            raise ValueError(f"need at least one anchor, got {k}")
        for plist, zero in zip(self._factor_lists(), self._zero_factors(), strict=True):
            while len(plist) < k - 1:
                plist.append(nn.Parameter(zero.clone()))
        super().set_n_anchors(k)

    def factors(self) -> tuple[Tensor, Tensor]:
        """All offsets side by side: A [out, (K-1)·r] and B [(K-1)·r, in], so that
        ``A diag(a) B = Σ_k a_k A_k B_k`` for ``a`` each α_k repeated r times."""
        return torch.cat(list(self.lora_a), dim=1), torch.cat(list(self.lora_b), dim=0)

    def anchor_weights(self) -> Tensor:
        """Every anchor's full weight ``W_k``, [K, out, in] (materialised: for tests and the
        cosine penalty, not for the forward)."""
        offsets = [a @ b for a, b in zip(self.lora_a, self.lora_b, strict=True)]
        return torch.stack([self.weight] + [self.weight + d for d in offsets])

    def anchor_vectors(self) -> Tensor:
        weights = self.anchor_weights().flatten(1)
        return torch.cat([weights, torch.stack(list(self.biases))], dim=1)

    def forward(self, x: Tensor, alpha: Tensor) -> Tensor:
        """alpha [K]: x [..., in] → [..., out]. alpha [M, K]: x [B, in] (shared by all M) or
        [M, ..., in] → [M, ..., out], one batched matmul for the M mixed weights."""
        _check_alpha(alpha, self.n_anchors)
        if alpha.dim() == 1:
            return F.linear(x, *self.mixed(alpha))
        bias = alpha @ torch.stack(list(self.biases))
        # the K-1 offsets once, then one mix per row as SubspaceLinear does: W_1 weighs Σα
        offsets = [a @ b for a, b in zip(self.lora_a, self.lora_b, strict=True)]
        stacked = torch.stack([self.weight, *offsets])  # [K, out, in]
        coef = torch.cat([alpha.sum(-1, keepdim=True), alpha[:, 1:]], dim=1)
        weight_t = torch.einsum("mk,koi->mio", coef, stacked)  # [M, in, out]
        return _batched_affine(x, weight_t, bias)

    def mixed(self, alpha: Tensor) -> tuple[Tensor, Tensor]:
        """The weight [out, in] and bias [out] of one point ``alpha`` [K] of the subspace."""
        _check_alpha(alpha, self.n_anchors)
        k = self._used(alpha)
        alpha = alpha[:k]
        bias = alpha @ torch.stack(list(self.biases)[:k])
        weight = alpha.sum() * self.weight
        if k > 1:
            a = torch.cat(list(self.lora_a)[: k - 1], dim=1)
            b = torch.cat(list(self.lora_b)[: k - 1], dim=0)
            weight = torch.addmm(weight, a * alpha[1:].repeat_interleave(self.rank), b)
        return weight, bias

    def extra_repr(self) -> str:
        return (
            f"in_features={self.in_features}, out_features={self.out_features}, "
            f"rank={self.rank}, n_anchors={self.n_anchors}"
        )


def low_rank_(module: nn.Module, rank: int) -> nn.Module:
    """Replace, in place, every one-anchor :class:`SubspaceLinear` inside ``module`` by a
    :class:`LowRankSubspaceLinear` of the same first anchor (same outputs); returns ``module``."""
    for parent in list(module.modules()):
        for name, child in list(parent.named_children()):
            if type(child) is SubspaceLinear:
                setattr(parent, name, LowRankSubspaceLinear.from_linear(child, rank))
    return module


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
        _check_alpha(alpha, self.n_anchors)
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
        _check_alpha(alpha, self.n_anchors)
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
        self.act = nn.GELU()
        self.drop_inp = FastDropout(dropout)
        self.drop_block = FastDropout(dropout)
        self.drop_out = FastDropout(dropout)

    def forward(self, x: Tensor, alpha: Tensor) -> Tensor:
        """alpha [K]: x [B, in] → [B, out]. alpha [M, K]: x [B, in] or [M, B, in] → [M, B, out].

        Training on one point (alpha [K], gradients on) mixes each layer's parameters once and
        runs the plain network's fast path (:func:`~hispo_pl.nn.fast.residual_mlp`)."""
        if alpha.dim() == 1 and self.training and torch.is_grad_enabled() and fast.enabled():
            params = self._mixed_parameters(alpha)
            shape = (*x.shape[:-1], self.inp_norm.dim)
            masks = self.drop_inp.masks(3, shape, x)
            eps = (self.inp_norm.eps, self.block_norm1.eps, self.block_norm2.eps)
            return fast.residual_mlp(x, params, masks, eps)
        h = self.drop_inp(self.act(self.inp_norm(self.inp_linear(x, alpha), alpha)))
        b = self.drop_block(self.act(self.block_norm1(self.block_linear1(h, alpha), alpha)))
        b = self.block_norm2(self.block_linear2(b, alpha), alpha)
        h = self.drop_out(self.act(h + b))
        return self.head(h, alpha)

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
        ops instead of a few per layer). Otherwise each layer mixes its own (which also
        leaves out trailing zero-weighted anchors, see :meth:`SubspaceLayer._used`)."""
        layers = self._layers()
        if not alpha.requires_grad or any(isinstance(x, LowRankSubspaceLinear) for x in layers):
            return [t for layer in layers for t in layer.mixed(alpha)]
        _check_alpha(alpha, self.n_anchors)
        lists = [plist for layer in layers for plist in layer._lists()]
        rows = torch.cat([plist[k].reshape(-1) for k in range(len(alpha)) for plist in lists])
        mixed = alpha @ rows.view(len(alpha), -1)
        shapes = [plist[0].shape for plist in lists]
        parts = mixed.split([math.prod(shape) for shape in shapes])
        return [part.view(shape) for part, shape in zip(parts, shapes, strict=True)]

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
