"""CSP's subspace critic: an IQL value ``V(s, g, α)`` and twin ``Q(s, g, a, α)``, with target
copies of the Q networks, on the residual MLP backbone."""

from __future__ import annotations

import copy
from dataclasses import dataclass, fields

import torch
from torch import Tensor, nn

from ..iql import expectile_loss, goal_reward, polyak_update, td_loss, td_target
from .mlp import ResidualMLP


@dataclass(frozen=True)
class CriticConfig:
    """How CSP's critic is built and trained (``CSP(critic={...})`` overrides any field)."""

    hidden: int = 256
    """Width of the V and Q networks (residual MLPs, no dropout)."""
    expectile: float = 0.7
    """IQL's expectile τ of V over the data's actions (0.5: the mean; → 1: the best)."""
    discount: float = 0.99
    """Discount γ of the sparse goal reward."""
    lr: float = 3e-4
    """Adam learning rate of the critic (constant: the critic has no cosine schedule)."""
    polyak: float = 0.005
    """Rate at which the target Q networks follow the trained ones after every step."""
    success_radius: float = 0.45
    """A transition reaches its goal (reward 1, done) when the next position lies this close
    to it: gymnasium-robotics' maze success distance, the one rollouts are judged by."""

    @classmethod
    def from_dict(cls, values: dict | None) -> CriticConfig:
        """The defaults overridden by ``values``; an unknown key is an error naming the known."""
        values = dict(values or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(
                f"unknown critic setting(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )
        for f in fields(cls):  # a YAML or CLI parser may hand integers over as floats
            value = values.get(f.name)
            if f.type == "int" and isinstance(value, float):
                if not value.is_integer():
                    raise ValueError(f"critic setting {f.name} must be an integer, got {value}")
                values[f.name] = int(value)
        return cls(**values)


class SubspaceCritic(nn.Module):
    """``V(x, α)`` and twin ``Q(x, a, α)`` on state features ``x`` (the high policy's inputs:
    observation, position, goal and goal features), an action ``a`` and anchor weights ``α``
    [alpha_dim]; inputs are concatenated. Leading batch axes broadcast: ``x`` [..., B, d] with
    ``a`` [..., B, A] and ``α`` [..., B, K]. The target Q networks are frozen copies that
    :meth:`update_targets` moves towards the trained ones.

    Example:
        >>> critic = SubspaceCritic(state_dim=3, action_dim=2, alpha_dim=2, hidden=8)
        >>> x, a, alpha = torch.zeros(5, 3), torch.zeros(5, 2), torch.full((5, 2), 0.5)
        >>> critic.q(x, a, alpha).shape, critic.value(x, alpha).shape
        (torch.Size([5]), torch.Size([5]))
    """

    def __init__(self, state_dim: int, action_dim: int, alpha_dim: int, hidden: int = 256):
        super().__init__()
        self.state_dim, self.action_dim, self.alpha_dim = state_dim, action_dim, alpha_dim
        q_in = state_dim + action_dim + alpha_dim
        self.q1 = ResidualMLP(q_in, hidden, 1, dropout=0.0)
        self.q2 = ResidualMLP(q_in, hidden, 1, dropout=0.0)
        self.v = ResidualMLP(state_dim + alpha_dim, hidden, 1, dropout=0.0)
        self.q1_target = copy.deepcopy(self.q1).requires_grad_(False)
        self.q2_target = copy.deepcopy(self.q2).requires_grad_(False)

    @staticmethod
    def alpha_dim_in(state_dict: dict[str, Tensor], prefix: str, state_dim: int) -> int:
        """The anchor-weight width of a critic saved under ``prefix`` (read off V's input)."""
        return state_dict[f"{prefix}v.inp.0.weight"].shape[1] - state_dim

    def twin_q(self, x: Tensor, a: Tensor, alpha: Tensor, target: bool = False) -> Tensor:
        """Both Q estimates stacked on the last axis, [..., B, 2]."""
        inp = torch.cat([x, a, alpha], dim=-1)
        q1, q2 = (self.q1_target, self.q2_target) if target else (self.q1, self.q2)
        return torch.cat([q1(inp), q2(inp)], dim=-1)

    def q(self, x: Tensor, a: Tensor, alpha: Tensor, target: bool = False) -> Tensor:
        """The pessimistic Q: the smaller of the twins, [..., B]."""
        return self.twin_q(x, a, alpha, target).min(dim=-1).values

    def value(self, x: Tensor, alpha: Tensor) -> Tensor:
        """``V(x, α)``, [..., B]."""
        return self.v(torch.cat([x, alpha], dim=-1)).squeeze(-1)

    def losses(
        self,
        x: Tensor,
        action: Tensor,
        alpha: Tensor,
        next_x: Tensor,
        reward: Tensor,
        done: Tensor,
        discount: float,
        expectile: float,
    ) -> dict[str, Tensor]:
        """IQL's two regressions on a batch of transitions: V towards the expectile of the
        target Q on the data's action, each Q towards ``r + γ (1 − done) V(s')``."""
        with torch.no_grad():
            q_target = self.q(x, action, alpha, target=True)
            target = td_target(reward, done, self.value(next_x, alpha), discount)
        value = self.value(x, alpha)
        loss_v = expectile_loss(q_target - value, expectile)
        loss_q = td_loss(self.twin_q(x, action, alpha), target)
        return {"loss_v": loss_v, "loss_q": loss_q, "value": value.detach().mean()}

    def goal_losses(
        self,
        x: Tensor,
        action: Tensor,
        alpha: Tensor,
        next_x: Tensor,
        next_position: Tensor,
        goal: Tensor,
        cfg: CriticConfig,
    ) -> dict[str, Tensor]:
        """:meth:`losses` with the sparse goal reward of :func:`~hispo_pl.iql.goal_reward`."""
        reward, done = goal_reward(next_position, goal, cfg.success_radius)
        out = self.losses(x, action, alpha, next_x, reward, done, cfg.discount, cfg.expectile)
        out["reward"] = reward.mean()
        return out

    def update_targets(self, rate: float) -> None:
        polyak_update(self.q1_target, self.q1, rate)
        polyak_update(self.q2_target, self.q2, rate)
