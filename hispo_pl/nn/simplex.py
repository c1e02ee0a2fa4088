"""Points of a subspace's simplex: the weights α over K anchors that the search samples and
every subspace layer checks."""

from __future__ import annotations

import torch
from torch import Tensor


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


def check_alpha(alpha: Tensor, n_anchors: int) -> None:
    """Refuse an α that is not one point [K] or a batch of points [M, K] of ``n_anchors``."""
    if alpha.dim() not in (1, 2) or alpha.shape[-1] != n_anchors:
        raise ValueError(
            f"alpha must have shape [{n_anchors}] or [M, {n_anchors}], got {tuple(alpha.shape)}"
        )
