"""Low-rank subspaces (the paper's HiLOW): every anchor after the first is a low-rank offset
of it, so a kept anchor stores ``r · (in + out)`` numbers per layer instead of ``in · out``."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .mlp import _init_linear
from .simplex import check_alpha
from .subspace import AnchorInit, SubspaceLayer, SubspaceLinear, batched_affine


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

    mixes_as_rows = False

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
        check_alpha(alpha, self.n_anchors)
        if alpha.dim() == 1:
            return F.linear(x, *self.mixed(alpha))
        bias = alpha @ torch.stack(list(self.biases))
        # the K-1 offsets once, then one mix per row as SubspaceLinear does: W_1 weighs Σα
        offsets = [a @ b for a, b in zip(self.lora_a, self.lora_b, strict=True)]
        stacked = torch.stack([self.weight, *offsets])  # [K, out, in]
        coef = torch.cat([alpha.sum(-1, keepdim=True), alpha[:, 1:]], dim=1)
        weight_t = torch.einsum("mk,koi->mio", coef, stacked)  # [M, in, out]
        return batched_affine(x, weight_t, bias)

    def mixed(self, alpha: Tensor) -> tuple[Tensor, Tensor]:
        """The weight [out, in] and bias [out] of one point ``alpha`` [K] of the subspace."""
        check_alpha(alpha, self.n_anchors)
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
