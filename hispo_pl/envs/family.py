"""What differs between environment families beyond data (:class:`~hispo_pl.tasks.Family`):
how a task's env is registered and made for collection, how an episode is collected and
described, where evaluation episodes start, how a maze is drawn. Each family names its
implementation as a ``"module:Class"`` string, so :mod:`hispo_pl.tasks` imports no env code
and no caller tests which family it holds."""

from __future__ import annotations

import importlib
from functools import cache
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from ..task_families import Family
from ..tasks import Task

if TYPE_CHECKING:
    import gymnasium as gym
    from matplotlib.axes import Axes


@runtime_checkable
class FamilyBehaviour(Protocol):
    """The behaviour of one environment family, implemented once beside its env code."""

    entry_point: str  # "module:callable" that Gymnasium builds the family's tasks with

    def env_kwargs(self, task: Task) -> dict:
        """The keyword arguments the entry point builds ``task`` with."""

    def make_collection_env(self, task: Task) -> gym.Env:
        """The env the expert collects ``task``'s dataset in."""

    def reset_options(self, env: gym.Env, episodes: int, seed: int) -> list[dict]:
        """Seeded start and goal of each evaluation episode as ``env.reset`` options."""

    def collect_episode(
        self, env: gym.Env, expert, rng: np.random.Generator, seed: int, noise: float, steps: int
    ) -> dict:
        """One expert episode as the arrays staged to disk (see :func:`episode_arrays`)."""

    def episode_ended(self, episode: dict) -> bool:
        """Whether a collected episode ended in the env (terminated) rather than was cut."""

    def describe_dataset(self, task: Task, expert, settings: dict, stats: dict) -> str:
        """The Minari description of a dataset collected with ``settings`` (episodes, seed,
        noise) that came out with ``stats`` (goals reached and failed, flips, steps kept)."""

    def draw_maze(self, ax: Axes, task: Task) -> None:
        """``task``'s maze from above on ``ax``, in world coordinates."""


@cache
def _behaviour(path: str) -> FamilyBehaviour:
    module, _, cls = path.partition(":")
    return getattr(importlib.import_module(module), cls)()


def family_behaviour(family: Family | Task) -> FamilyBehaviour:
    """The behaviour :attr:`Family.behaviour` names (imported on first use)."""
    if isinstance(family, Task):
        family = family.env_family
    return _behaviour(family.behaviour)


def episode_arrays(record: dict, actions, rewards, reached, flipped: bool) -> dict:
    """One collected episode as the arrays staged to disk (observation keys, actions, rewards,
    per-step goal reached, whether it was cut at a flip)."""
    out = {k: np.asarray(v) for k, v in record.items()}
    out["actions"] = np.asarray(actions, dtype=np.float32)
    out["rewards"] = np.asarray(rewards, dtype=np.float64)
    out["reached"] = np.asarray(reached, dtype=bool)
    out["flipped"] = np.asarray(flipped)
    return out
