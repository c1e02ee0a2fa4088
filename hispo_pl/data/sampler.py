"""Goal-relabelling (HER) sampler: batches for hierarchical BC by index arithmetic alone."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from .datasets import EpisodeArrays

Strategy = Literal["exponential", "uniform", "geometric"]
Horizon = Literal["episode", "segment"]


@dataclass(frozen=True)
class HERConfig:
    """How goals and subgoals are relabelled."""

    waysteps: int = 50
    """Subgoal distance k: the subgoal is the position k steps ahead (±``jitter``)."""
    temperature: float = 100.0
    """Mean of the exponential goal offset (steps) for the ``exponential`` strategy."""
    strategy: Strategy = "exponential"
    """exponential: offset ~ Exp(temperature); uniform: U{i..end}; geometric: Geom(1/temp)."""
    jitter: int = 2
    """Subgoal index jitter, uniform in {-jitter..jitter}."""
    goal_horizon: Horizon = "episode"
    """Where goals are clipped: at the episode end (the reference), or at the end of the goal
    segment (the expert's path to the goal it was heading for), which keeps relabelled goals
    off the detours that goal switches put in continuing episodes."""


def relabel_indices(
    index: np.ndarray,
    episode_end: np.ndarray,
    cfg: HERConfig,
    rng: np.random.Generator,
    segment_end: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Goal and subgoal row for each sampled row ``index``, clipped to its episode.

    goal j = clip(i + offset, i, end) with the offset drawn by ``cfg.strategy`` and ``end`` the
    episode's or, with ``goal_horizon="segment"``, the goal segment's last row;
    subgoal j' = clip(i + waysteps + U{-jitter..jitter}, i, episode end).
    """
    episode = episode_end[index]
    if cfg.goal_horizon == "segment":
        if segment_end is None:
            raise ValueError("goal_horizon='segment' needs the data's segment_end")
        end = segment_end[index]
    else:
        end = episode
    n = len(index)
    if cfg.strategy == "exponential":
        offset = np.rint(rng.exponential(cfg.temperature, n)).astype(np.int64)
    elif cfg.strategy == "geometric":
        offset = rng.geometric(1.0 / max(cfg.temperature, 1.0), n).astype(np.int64)
    elif cfg.strategy == "uniform":
        offset = (rng.random(n) * (end - index + 1)).astype(np.int64)
    else:
        raise ValueError(f"unknown HER strategy {cfg.strategy!r}")
    goal = np.minimum(index + offset, end)
    jitter = rng.integers(-cfg.jitter, cfg.jitter + 1, n)
    subgoal = np.clip(index + cfg.waysteps + jitter, index, episode)
    return goal, subgoal


class HERSampler:
    """Draws relabelled batches from one task's episodes.

    Each batch is a dict of float32 tensors: ``observation`` [B, obs], ``position`` [B, 2],
    ``goal`` [B, 2] (a future achieved position), ``subgoal`` [B, 2] (``waysteps`` ahead),
    ``agent_position`` [B, 2] (the position as the agent senses it, the policies' input:
    ``position`` itself unless the family's observation holds it, see
    :func:`~hispo_pl.tasks.agent_position`), ``velocity`` [B, 2] (the last step of the sensed
    position over ``step_seconds``, 0 at an episode's first row: what a rollout can compute
    from the positions it has sensed, see :func:`position_velocity`) and ``action`` [B, act].
    Positions, goals and subgoals are in maze coordinates: the targets. With
    ``transitions=True`` (opt-in, for critics) also ``next_observation`` and
    ``next_position``: row i + 1 of the same episode (a sampled row always has one, since the
    final row of an episode carries no action). The option draws nothing more, so the other
    keys are the same batch for batch either way.
    """

    def __init__(
        self,
        data: EpisodeArrays,
        cfg: HERConfig,
        batch_size: int = 1024,
        seed: int = 0,
        step_seconds: float = 1.0,
        transitions: bool = False,
    ):
        self.cfg = cfg
        self.transitions = transitions
        self.batch_size = batch_size
        self.rng = np.random.default_rng(seed)
        self._obs = torch.from_numpy(np.ascontiguousarray(data.observations, dtype=np.float32))
        self._pos = torch.from_numpy(np.ascontiguousarray(data.positions, dtype=np.float32))
        sensed = data.positions if data.agent_positions is None else data.agent_positions
        self._agent_pos = torch.from_numpy(np.ascontiguousarray(sensed, dtype=np.float32))
        self._act = torch.from_numpy(np.ascontiguousarray(data.actions, dtype=np.float32))
        self._end = data.episode_end
        self._segment_end = data.segment_end
        self._index = data.sample_index
        first = np.ones(len(data.episode_end), dtype=bool)  # an episode's first row
        first[1:] = data.episode_end[1:] != data.episode_end[:-1]
        self._previous = torch.from_numpy(np.arange(len(first)) - (~first))
        self._step_seconds = step_seconds

    def sample(self, batch_size: int | None = None) -> dict[str, torch.Tensor]:
        n = batch_size or self.batch_size
        i = self._index[self.rng.integers(0, len(self._index), n)]
        goal, subgoal = relabel_indices(i, self._end, self.cfg, self.rng, self._segment_end)
        i, goal, subgoal = (torch.from_numpy(x) for x in (i, goal, subgoal))
        sensed = self._agent_pos[i]
        batch = {
            "observation": self._obs[i],
            "position": self._pos[i],
            "agent_position": sensed,
            "velocity": position_velocity(
                sensed, self._agent_pos[self._previous[i]], self._step_seconds
            ),
            "goal": self._pos[goal],
            "subgoal": self._pos[subgoal],
            "action": self._act[i],
        }
        if self.transitions:
            batch["next_observation"] = self._obs[i + 1]
            batch["next_position"] = self._pos[i + 1]
        return batch

    def sample_group(self, count: int) -> dict[str, torch.Tensor]:
        """``count`` batches drawn one after the other, stacked: ``[count, B, ...]`` tensors,
        the batches ``count`` calls of :meth:`sample` give."""
        return stack_batches([self.sample() for _ in range(count)])


class DeviceHERSampler:
    """:class:`HERSampler`'s batches drawn on a torch device: the episodes live there, and the
    rows, the relabelling offsets and jitters are drawn there by torch, from a generator of
    its own seeded with ``seed`` (as the host sampler's numpy generator is), so a step copies
    nothing from the host.

    Same keys, shapes and distributions as :class:`HERSampler` (``tests/data/test_sampler.py``
    compares the two), but another random stream: a run that samples on the device draws
    other batches than one that samples on the host.
    """

    def __init__(
        self,
        data: EpisodeArrays,
        cfg: HERConfig,
        batch_size: int = 1024,
        seed: int = 0,
        step_seconds: float = 1.0,
        transitions: bool = False,
        device: torch.device | str = "cpu",
    ):
        if cfg.strategy not in ("exponential", "uniform", "geometric"):
            raise ValueError(f"unknown HER strategy {cfg.strategy!r}")
        if cfg.goal_horizon == "segment" and data.segment_end is None:
            raise ValueError("goal_horizon='segment' needs the data's segment_end")
        self.cfg, self.batch_size, self.transitions = cfg, batch_size, transitions
        self.device = torch.device(device)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed)

        def put(array, dtype: torch.dtype) -> torch.Tensor:
            return torch.as_tensor(np.ascontiguousarray(array)).to(self.device, dtype)

        self._obs = put(data.observations, torch.float32)
        self._pos = put(data.positions, torch.float32)
        sensed = data.positions if data.agent_positions is None else data.agent_positions
        self._agent_pos = put(sensed, torch.float32)
        self._act = put(data.actions, torch.float32)
        self._end = put(data.episode_end, torch.int64)
        horizon = data.segment_end if cfg.goal_horizon == "segment" else data.episode_end
        self._goal_end = put(horizon, torch.int64)
        self._index = put(data.sample_index, torch.int64)
        first = np.ones(len(data.episode_end), dtype=bool)
        first[1:] = data.episode_end[1:] != data.episode_end[:-1]
        self._previous = put(np.arange(len(first)) - (~first), torch.int64)
        self._step_seconds = step_seconds

    def _draw(self, n: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
        return torch.empty(n, dtype=dtype, device=self.device)

    def relabel(self, i: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Goal and subgoal rows of the rows ``i``, as :func:`relabel_indices` draws them."""
        cfg, g, n = self.cfg, self.generator, len(i)
        end = _rows(self._goal_end, i)
        if cfg.strategy == "exponential":
            offset = self._draw(n).exponential_(1.0 / cfg.temperature, generator=g).round_()
        elif cfg.strategy == "geometric":
            offset = self._draw(n).geometric_(1.0 / max(cfg.temperature, 1.0), generator=g)
        else:  # uniform in {i..end}; float64 as numpy draws it
            offset = self._draw(n, torch.float64).uniform_(generator=g) * (end - i + 1)
        goal = torch.minimum(i + offset.long(), end)
        jitter = torch.randint(-cfg.jitter, cfg.jitter + 1, (n,), generator=g, device=self.device)
        subgoal = torch.clamp(i + cfg.waysteps + jitter, min=i, max=_rows(self._end, i))
        return goal, subgoal

    def sample(self, batch_size: int | None = None) -> dict[str, torch.Tensor]:
        n = batch_size or self.batch_size
        k = torch.randint(0, len(self._index), (n,), generator=self.generator, device=self.device)
        i = _rows(self._index, k)
        goal, subgoal = self.relabel(i)
        sensed = _rows(self._agent_pos, i)
        previous = _rows(self._agent_pos, _rows(self._previous, i))
        batch = {
            "observation": _rows(self._obs, i),
            "position": _rows(self._pos, i),
            "agent_position": sensed,
            "velocity": position_velocity(sensed, previous, self._step_seconds),
            "goal": _rows(self._pos, goal),
            "subgoal": _rows(self._pos, subgoal),
            "action": _rows(self._act, i),
        }
        if self.transitions:
            batch["next_observation"] = _rows(self._obs, i + 1)
            batch["next_position"] = _rows(self._pos, i + 1)
        return batch

    def sample_group(self, count: int) -> dict[str, torch.Tensor]:
        """``count`` batches in one draw: ``[count, B, ...]`` tensors."""
        batch = self.sample(count * self.batch_size)
        return {k: v.view(count, self.batch_size, *v.shape[1:]) for k, v in batch.items()}


def _rows(table: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``table[index]`` as one gather (``index_select``), which never waits for the host."""
    return torch.index_select(table, 0, index)


def stack_batches(batches: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    """Batches of equal shapes as one group: ``[len(batches), B, ...]`` tensors."""
    return {k: torch.stack([b[k] for b in batches]) for k in batches[0]}


def position_velocity(position, previous, step_seconds: float):
    """Velocity in goal space from two consecutive sensed positions, the same in the data and
    in a rollout."""
    return (position - previous) / step_seconds


def split_evenly(total: int, parts: int) -> list[int]:
    """``total`` samples in ``parts`` shares that differ by at most one (earlier shares larger)."""
    if parts < 1:
        raise ValueError(f"need at least one share, got {parts}")
    base, extra = divmod(total, parts)
    return [base + (k < extra) for k in range(parts)]


class MixedSampler:
    """Batches made of equal shares from several samplers (replay of earlier tasks' data)."""

    def __init__(self, samplers: list[HERSampler | DeviceHERSampler], batch_size: int = 1024):
        if not samplers:
            raise ValueError("MixedSampler needs at least one sampler")
        self.samplers, self.batch_size = samplers, batch_size

    def sample(self, batch_size: int | None = None) -> dict[str, torch.Tensor]:
        shares = split_evenly(batch_size or self.batch_size, len(self.samplers))
        parts = [s.sample(n) for s, n in zip(self.samplers, shares, strict=True) if n]
        return {k: torch.cat([part[k] for part in parts]) for k in parts[0]}

    def sample_group(self, count: int) -> dict[str, torch.Tensor]:
        """``count`` batches drawn one after the other, stacked: ``[count, B, ...]``."""
        return stack_batches([self.sample() for _ in range(count)])
