"""The backbone's wiring, written once: high policy → subgoal offset → low policy → action.

Every method uses :class:`HierarchicalPolicy` for its losses and its actions; a method only
chooses the head class (a plain Gaussian policy, a subspace of anchors, progressive columns)
and, through ``forward``, the extra argument its heads take (anchor weights, a column).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import torch
from torch import Tensor, nn

from ..config import BackboneConfig
from .mlp import GaussianPolicy, feature_dim, goal_features

Forward = Callable[[str, Tensor], tuple[Tensor, Tensor]]
"""``forward(name, x) -> (mean, log_std)``: how a method runs its head ``name`` on ``x``."""


def high_input(
    observation: Tensor, position: Tensor, goal: Tensor, velocity: Tensor | None = None
) -> Tensor:
    """The high (and flat) policy's input: [features(goal − pos), obs, pos, goal], or, given
    ``velocity`` (a goal-space high policy), the velocity in the observation's place."""
    middle = observation if velocity is None else velocity
    return torch.cat([goal_features(goal - position), middle, position, goal], dim=-1)


def high_input_dim(obs_dim: int, goal_dim: int, high_obs: bool = True) -> int:
    """Width of :func:`high_input`."""
    return feature_dim(goal_dim) + (obs_dim if high_obs else goal_dim) + 2 * goal_dim


def low_input(
    observation: Tensor,
    subgoal_offset: Tensor,
    with_obs: bool = True,
    velocity: Tensor | None = None,
) -> Tensor:
    """The low policy's input: [features(subgoal − pos), observation if ``with_obs``,
    ``velocity`` if given]; never the absolute goal."""
    parts = [goal_features(subgoal_offset)]
    if with_obs:
        parts.append(observation)
    if velocity is not None:
        parts.append(velocity)
    return torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]


def low_input_dim(obs_dim: int, goal_dim: int, low_obs: bool, low_velocity: bool = False) -> int:
    """Width of :func:`low_input`."""
    return feature_dim(goal_dim) + (obs_dim if low_obs else 0) + (goal_dim if low_velocity else 0)


def velocity_input(wanted: bool, velocity: Tensor | None, level: str = "low") -> Tensor | None:
    """The velocity a level that reads it gets (None for one that does not)."""
    if not wanted:
        return None
    if velocity is None:
        raise ValueError(
            f"this policy's {level} level reads the goal-space velocity: pass velocity= to act() "
            "(RolloutEvaluator and module_policy do)"
        )
    return velocity


class HierarchicalPolicy(nn.Module):
    """The heads of one backbone (``high`` and ``low``, or one flat ``policy``) and how they
    are fed, trained and acted with.

    The high policy predicts a Gaussian over the subgoal offset (subgoal − pos); the low one,
    given the true subgoal while training and the high policy's mean while acting, a Gaussian
    over the action (Bernoulli over its first ``binary_actions`` entries). Acting re-plans
    every step. ``head`` builds every head: :class:`~hispo_pl.nn.mlp.GaussianPolicy` or a
    subclass whose network is a subspace or progressive columns.

    Example:
        >>> policy = HierarchicalPolicy(BackboneConfig(high_hidden=8, low_hidden=16), 4, 2)
        >>> policy.names, policy.act(torch.zeros(3, 4), torch.zeros(3, 2), torch.ones(3, 2)).shape
        (('high', 'low'), torch.Size([3, 2]))
    """

    def __init__(
        self,
        config: BackboneConfig,
        obs_dim: int,
        action_dim: int,
        goal_dim: int = 2,
        head: type[GaussianPolicy] = GaussianPolicy,
    ):
        super().__init__()
        self.config = config
        high_dim = high_input_dim(obs_dim, goal_dim, config.high_obs)
        if config.kind == "hbc":
            self.high = head(
                high_dim,
                config.high_hidden,
                goal_dim,
                config.dropout,
                fixed_log_std=config.high_log_std,
            )
            self.low = head(
                low_input_dim(obs_dim, goal_dim, config.low_obs, config.low_velocity),
                config.low_hidden,
                action_dim,
                config.dropout,
                fixed_log_std=config.low_log_std,
                binary=config.binary_actions,
            )
            self.names: tuple[str, ...] = ("high", "low")
        else:
            self.policy = head(
                high_dim,
                config.low_hidden,
                action_dim,
                config.dropout,
                binary=config.binary_actions,
            )
            self.names = ("policy",)

    def __getitem__(self, name: str) -> GaussianPolicy:
        return getattr(self, name)

    def heads(self) -> dict[str, GaussianPolicy]:
        return {name: self[name] for name in self.names}

    def inputs(self, name: str, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """Input and target of head ``name`` on a training batch (the true subgoal feeds low).
        The high input reads the position as the agent senses it (``agent_position``, else
        ``position``); subgoal offsets, targets and the low policy's input, are in maze
        coordinates, as the high policy predicts them."""
        obs, pos = batch["observation"], batch["position"]
        if name == "low":
            velocity = batch["velocity"] if self.config.low_velocity else None
            x = low_input(obs, batch["subgoal"] - pos, self.config.low_obs, velocity)
            return x, batch["action"]
        target = batch["subgoal"] - pos if name == "high" else batch["action"]
        velocity = None if self.config.high_obs else batch["velocity"]
        sensed = batch.get("agent_position", pos)
        return high_input(obs, sensed, batch["goal"], velocity), target

    def _forward(self, forward: Forward | None) -> Forward:
        return forward or (lambda name, x: self[name](x))

    def losses(
        self,
        batch: dict[str, Tensor],
        forward: Forward | None = None,
        names: Iterable[str] | None = None,
    ) -> dict[str, Tensor]:
        """Each head's NLL of its target (``loss_high``, ``loss_low``) and their sum
        (``loss``); ``names`` limits the heads trained (a method may fix some)."""
        forward = self._forward(forward)
        out: dict[str, Tensor] = {}
        for name in self.names if names is None else names:
            x, target = self.inputs(name, batch)
            mean, log_std = forward(name, x)
            out[f"loss_{name}"] = self[name].loss(mean, log_std, target)
        parts = list(out.values())
        total = parts[0]
        for part in parts[1:]:
            total = total + part
        if self.config.kind == "bc":
            return {"loss": total}
        return {"loss": total, **out}

    def act(
        self,
        observation: Tensor,
        position: Tensor,
        goal: Tensor,
        velocity: Tensor | None = None,
        forward: Forward | None = None,
    ) -> Tensor:
        """The deterministic action, ``position`` and ``velocity`` as the agent senses them
        (:func:`~hispo_pl.tasks.agent_position`). A ``forward`` that mixes M anchor-weight
        vectors at once
        gives actions [M, B, A]: the low policy's other inputs are broadcast to them."""
        forward = self._forward(forward)
        high_velocity = velocity_input(not self.config.high_obs, velocity, "high")
        x = high_input(observation, position, goal, high_velocity)
        if self.config.kind == "bc":
            return self.policy.act(forward("policy", x)[0])
        offset, _ = forward("high", x)
        velocity = velocity_input(self.config.low_velocity, velocity)
        if offset.dim() > observation.dim():
            observation = observation.expand(*offset.shape[:-1], observation.shape[-1])
            if velocity is not None:
                velocity = velocity.expand(*offset.shape[:-1], velocity.shape[-1])
        mean, _ = forward("low", low_input(observation, offset, self.config.low_obs, velocity))
        return self.low.act(mean)
