"""Gymnasium wrapper that puts an environment into a task variant (IA, IO, PA, PO)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from ..tasks import Task, transform_observation, untransform_action


class VariantWrapper(gym.Wrapper):
    """Applies a task's variant: the agent sees transformed observation features and its
    actions are mapped back to the base env's. Goals stay in maze coordinates."""

    def __init__(self, env: gym.Env, task: Task):
        super().__init__(env)
        self.task = task

    def _observe(self, obs: dict) -> dict:
        return {**obs, "observation": transform_observation(self.task, obs["observation"])}

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        return self._observe(obs), info

    def step(self, action):
        base_action = untransform_action(self.task, np.asarray(action))
        obs, reward, terminated, truncated, info = self.env.step(base_action)
        return self._observe(obs), reward, terminated, truncated, info
