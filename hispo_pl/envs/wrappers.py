"""Gymnasium wrapper that shows an environment as a task's policy sees it (variants IA, IO,
PA, PO; position features dropped)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from ..data.tasks import Task, transform_observation, untransform_action


class VariantWrapper(gym.Wrapper):
    """Puts an env into a task's view: the agent sees the observation features of
    :func:`transform_observation` (position features dropped, variant applied) and its actions
    are mapped back to the base env's. Goals stay in maze coordinates."""

    def __init__(self, env: gym.Env, task: Task):
        super().__init__(env)
        self.task = task
        spaces = dict(env.observation_space.spaces)
        box = spaces["observation"]
        low = transform_observation(task, box.low)
        high = transform_observation(task, box.high)
        spaces["observation"] = gym.spaces.Box(
            np.minimum(low, high), np.maximum(low, high), dtype=box.dtype
        )
        self.observation_space = gym.spaces.Dict(spaces)

    def _observe(self, obs: dict) -> dict:
        return {**obs, "observation": transform_observation(self.task, obs["observation"])}

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        return self._observe(obs), info

    def step(self, action):
        base_action = untransform_action(self.task, np.asarray(action))
        obs, reward, terminated, truncated, info = self.env.step(base_action)
        return self._observe(obs), reward, terminated, truncated, info
