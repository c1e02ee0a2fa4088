"""Environments: gymnasium-robotics mazes in every task variant, and the video-game mazes."""

from __future__ import annotations

import os

import gymnasium as gym

from ..data.tasks import FAMILIES, GAME_FAMILIES, Task, parse_task
from .wrappers import VariantWrapper

_registered = False


def _register() -> None:
    global _registered
    if not _registered:
        import gymnasium_robotics

        gym.register_envs(gymnasium_robotics)
        for family in GAME_FAMILIES:
            fam = FAMILIES[family]
            for maze, defaults in fam.mazes.items():
                gym.register(
                    id=fam.env_id.format(defaults.env_name),
                    entry_point="hispo_pl.envs.videogame.env:GameNavEnv",
                    kwargs={"game": family, "maze": maze},
                    max_episode_steps=defaults.max_episode_steps,
                )
        _registered = True


def make_env(task: str | Task, *, continuing_task: bool = False, **kwargs) -> gym.Env:
    """Build the gymnasium env of ``task`` (variant applied by a wrapper).

    ``continuing_task=False`` (our default, unlike gymnasium-robotics') ends an episode on
    success, as evaluation needs; data collection passes ``True``. Extra kwargs go to
    ``gym.make`` (e.g. ``max_episode_steps``). The maze XML that gymnasium-robotics writes
    into the temp dir on every construction is deleted once the model is loaded.
    """
    task = parse_task(task)
    _register()
    env_kwargs = {**task.env_family.env_kwargs, "continuing_task": continuing_task, **kwargs}
    env_kwargs.setdefault("max_episode_steps", task.defaults.max_episode_steps)
    env = gym.make(task.env_id, **env_kwargs)
    tmp_xml = getattr(env.unwrapped, "tmp_xml_file_path", None)
    if tmp_xml and os.path.exists(tmp_xml):
        os.remove(tmp_xml)
    if task.variant != "N":
        env = VariantWrapper(env, task)
    return env


def agent_flipped(env: gym.Env) -> bool:
    """Whether the agent has failed irrecoverably: the ant on its back (torso up axis below
    the horizon, read from the simulator, so any variant's view of it is irrelevant). The
    point mass cannot fail this way."""
    ant = getattr(env.unwrapped, "ant_env", None)
    if ant is None:
        return False
    _, qx, qy, _ = ant.data.qpos[3:7]
    return bool(1.0 - 2.0 * (qx * qx + qy * qy) < 0.0)


__all__ = ["make_env", "agent_flipped", "VariantWrapper"]
