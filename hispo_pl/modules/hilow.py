"""HiLOW: HiSPO with low-rank (LoRA) anchors (the paper's section 5.5; "for i ≥ 2,
θ_i = A_i B_i", here as an offset of the first anchor).

Both subspaces keep HiSPO's structure, search and pruning; only what an anchor costs changes.
Every linear weight of an anchor k ≥ 2 is ``W_k = W_1 + A_k B_k``
(:class:`~hispo_pl.nn.lowrank.LowRankSubspaceLinear`), so a kept anchor stores
``r·(in + out)`` values per layer instead of ``in·out``, and MEM grows more slowly.
"""

from __future__ import annotations

from typing import Literal

from ..nn.lowrank import low_rank_
from .hispo import HiSPO


class HiLOW(HiSPO):
    """HiSPO whose anchors k ≥ 2 of every linear weight are low-rank offsets of the first.

    Per linear layer, ``W_k = W_1 + A_k B_k`` with ``A_k`` [out, r] and ``B_k`` [r, in], so the
    mixed weight is ``θ(α) = W_1 + Σ_{k≥2} α_k A_k B_k`` (Σα = 1), built before one plain
    matmul: a forward costs about what HiSPO's does. Biases and LayerNorm affines keep one full
    vector per anchor: they are small (a few hundred values per layer against ``in·out`` for a
    weight), and a low-rank vector would save nothing. On the first task (one anchor) HiLOW is
    HiSPO exactly: same parameters from the same seed, same outputs. Only the newest anchor
    trains (its ``A``, ``B``, biases and affines); ``W_1`` trains on the first task only.

    A new anchor starts at θ_1, not at the mean of the anchors: as in LoRA, ``A = 0`` and ``B``
    is random, so ``A B = 0`` and ``A`` gets the first gradient. The mean of earlier offsets
    has rank up to (K-1)·r, which a rank-r offset cannot hold, so ``anchor_init: mean`` is
    refused; ``first`` (the default) also copies the first anchor's biases and affines, so the
    whole new anchor is θ_1, and ``random`` starts those afresh (biases 0, LayerNorm γ=1, β=0).

    Args:
        rank: rank r of each offset, capped per layer at min(in, out) (a head of 2 outputs
            gets rank 2).
        anchor_init: ``first`` or ``random``, see above.
        cosine_weight: as in HiSPO, on the full anchors θ_k; these are θ_1 plus small offsets,
            nearly parallel, so the penalty says little here: keep it 0.
        The others: as in :class:`HiSPO`.

    Example:
        >>> m = HiLOW(obs_dim=4, action_dim=2, rank=4)
        >>> m.add_anchor("low")
        >>> layer = m.policies["low"].net.block_linear1
        >>> tuple(layer.lora_a[0].shape), tuple(layer.lora_b[0].shape)
        ((256, 4), (4, 256))
    """

    def __init__(
        self,
        *args,
        rank: int = 8,
        anchor_init: Literal["first", "random"] = "first",
        **kwargs,
    ):
        if rank < 1:
            raise ValueError(f"HiLOW: rank must be >= 1, got {rank}")
        if anchor_init not in ("first", "random"):
            raise ValueError(
                f"HiLOW: anchor_init must be 'first' or 'random', got {anchor_init!r}: a new "
                "low-rank anchor starts at the first anchor (A B = 0); the mean of the earlier "
                "offsets is not rank r"
            )
        super().__init__(*args, anchor_init=anchor_init, **kwargs)
        for policy in self.policies.heads().values():  # θ_1 as HiSPO draws it, then low-rank
            low_rank_(policy.net, rank)
