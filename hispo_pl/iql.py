"""Implicit Q-Learning's losses (Kostrikov et al., 2022), as pure functions of tensors.

IQL never queries the critic on actions outside the data: ``Q(s, a)`` regresses on
``r + γ (1 − done) V(s')`` for the dataset's action ``a``, and ``V(s)`` is an upper expectile
of ``Q(s, a)`` over the dataset's actions (the expectile ``τ`` → 1 approaches the best action
the data show). CSP's subspace critic (:class:`~hispo_pl.nn.subspace_critic.SubspaceCritic`)
is trained with these on each task's relabelled goals.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


def expectile_loss(diff: Tensor, expectile: float) -> Tensor:
    """Asymmetric squared loss ``mean(|τ − 1[u < 0]| · u²)`` of the residuals ``u = Q − V``:
    positive residuals weigh ``τ``, negative ones ``1 − τ``, so the minimising ``V`` is the
    ``τ``-expectile of ``Q`` (``τ = 0.5``: half the mean squared error).

    Example:
        >>> expectile_loss(torch.tensor([2.0, -2.0]), 0.9)  # (0.9 * 4 + 0.1 * 4) / 2
        tensor(2.)
    """
    if not 0.0 < expectile < 1.0:
        raise ValueError(f"the expectile must be in (0, 1), got {expectile}")
    weight = torch.where(diff < 0, 1.0 - expectile, expectile)
    return (weight * diff.pow(2)).mean()


def td_target(reward: Tensor, done: Tensor, next_value: Tensor, discount: float) -> Tensor:
    """The one-step target ``r + γ (1 − done) V(s')``, with no gradient into ``V``."""
    if not 0.0 <= discount <= 1.0:
        raise ValueError(f"the discount must be in [0, 1], got {discount}")
    return reward + discount * (1.0 - done) * next_value.detach()


def td_loss(q_values: Tensor, target: Tensor) -> Tensor:
    """Mean squared TD error of one or several Q estimates (``q_values`` [..., n] stacked on
    the last axis for twin critics, ``target`` [...]), summed over the estimates."""
    if q_values.dim() == target.dim():
        q_values = q_values.unsqueeze(-1)
    return (
        (q_values - target.detach().unsqueeze(-1)).pow(2).mean(dim=tuple(range(target.dim()))).sum()
    )


def goal_reward(next_position: Tensor, goal: Tensor, radius: float) -> tuple[Tensor, Tensor]:
    """Sparse goal reward of a transition and its end: 1 and done iff the position reached
    (``next_position``) lies within ``radius`` of the (relabelled) goal, else 0 and not done.
    Both as float tensors of the batch's shape."""
    reached = (next_position - goal).norm(dim=-1) <= radius
    return reached.float(), reached.float()


@torch.no_grad()
def polyak_update(target: nn.Module, source: nn.Module, rate: float) -> None:
    """``θ_target ← (1 − rate) θ_target + rate θ_source`` for every parameter (in place)."""
    if not 0.0 < rate <= 1.0:
        raise ValueError(f"the Polyak rate must be in (0, 1], got {rate}")
    for t, s in zip(target.parameters(), source.parameters(), strict=True):
        t.lerp_(s, rate)
