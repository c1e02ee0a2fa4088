"""Searching a subspace for its best weight vector: a two-stage race over candidates.

Scoring every candidate on every batch costs S × B full forwards; on a CPU that work is
compute-bound, so vectorising it cannot make it much cheaper. Racing spends it where it
matters: every candidate is ranked on a small probe (part of the first batch), and only the
``survivors`` best of them are scored on all B batches. The winner's loss is its mean over all
B batches, exactly what exhaustive scoring gives for it; only a candidate that ranks poorly on
the probe yet is best on average can be missed, and since every candidate sees the same probe
(common random numbers), their ranking there tracks the ranking on all batches closely.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal, TypeVar

import torch
from torch import Tensor

Batch = TypeVar("Batch")


@dataclass(frozen=True)
class RaceOutcome:
    survivors: Tensor  # [k] indices of the candidates scored on every batch, probe order
    losses: Tensor  # [k] their mean loss over all batches
    probe_losses: Tensor | None  # [S] every candidate's loss on the probe (None: exhaustive)

    @property
    def best(self) -> int:
        """Index (into the candidates) of the lowest mean loss."""
        return int(self.survivors[self.losses.argmin()])

    @property
    def best_loss(self) -> float:
        return float(self.losses.min())


def race_candidates(
    score: Callable[[Tensor, Batch], Tensor],
    candidates: Tensor,
    batches: Sequence[Batch],
    probe: Batch | None = None,
    survivors: int | None = 64,
    tick: Callable[[], None] | None = None,
    seeded: int = 0,
) -> RaceOutcome:
    """Rank ``candidates`` [S, K] by ``score(candidates, probe)`` (losses [S]), then score the
    ``survivors`` lowest on every batch and average.

    ``survivors=None`` (or ≥ S), or no probe, scores every candidate on every batch: the
    exhaustive search. The first ``seeded`` candidates are scored on every batch whatever
    their probe rank (points known in advance, not to be lost to a probe's noise), besides the
    ``survivors`` best of the others. ``tick`` is called after the probe and after each batch
    (progress).
    """
    tick = tick or (lambda: None)
    if not batches:
        raise ValueError("need at least one batch to score the candidates on")
    if survivors is not None and survivors < 1:
        raise ValueError(f"survivors must be positive (or None for all), got {survivors}")
    n = len(candidates)
    if probe is None or survivors is None or survivors >= n - seeded:
        order, probe_losses = torch.arange(n, device=candidates.device), None
    else:
        probe_losses = score(candidates, probe)
        drawn = probe_losses[seeded:].argsort()[:survivors] + seeded
        order = torch.cat([torch.arange(seeded, device=drawn.device), drawn])
        tick()
    kept = candidates[order]
    total = 0
    for b in batches:
        total = total + score(kept, b)
        tick()
    return RaceOutcome(order, total / len(batches), probe_losses)


def resolve_precision(precision: str, device: torch.device) -> Literal["32", "bf16"]:
    """``auto`` → bf16 where the device computes it natively (CUDA with bf16, or a CPU with
    AVX-512 bf16 / AMX units), else float32; other values pass through."""
    if precision != "auto":
        return precision
    if device.type == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "32"
    cpu = torch.cpu
    native = (
        getattr(cpu, "_is_avx512_bf16_supported", lambda: False)()
        or getattr(cpu, "_is_amx_tile_supported", lambda: False)()
    )
    return "bf16" if native else "32"


def race_subspace(
    module,
    subspace: str,
    candidates: Tensor,
    batches: Sequence[dict[str, Tensor]],
    probe: dict[str, Tensor] | None = None,
    survivors: int | None = None,
    loss: Literal["mse", "nll"] = "mse",
    precision: Literal["32", "bf16"] = "32",
    tick: Callable[[], None] | None = None,
    seeded: int = 0,
) -> RaceOutcome:
    """:func:`race_candidates` over weight vectors of one subspace of ``module`` (its
    :class:`~hispo_pl.callbacks.protocols.SearchableSubspaces`), scored by its
    ``score_alphas``."""

    def score(alphas: Tensor, batch: dict[str, Tensor]) -> Tensor:
        return module.score_alphas(subspace, alphas, batch, loss=loss, precision=precision)

    return race_candidates(score, candidates, batches, probe, survivors, tick, seeded)
