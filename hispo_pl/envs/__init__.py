"""Environments: gymnasium-robotics mazes in every task variant, and the video-game mazes."""

from __future__ import annotations

import contextlib
import os

import gymnasium as gym

from ..task_families import FAMILIES
from ..tasks import Task, parse_task
from .family import family_behaviour
from .wrappers import VariantWrapper

_robotics_registered = False


def _drop_adroit_notice() -> None:
    """gymnasium-robotics prints a notice on import about its Adroit hands' rewards, which no
    hispo-pl task uses; it would stand in every run's output and above every error."""
    with contextlib.suppress(ImportError):
        from farama_notifications import notifications

        notifications.pop("gymnasium_robotics", None)


_drop_adroit_notice()


def register_tasks() -> None:
    """Register every task with Gymnasium under :attr:`Task.gym_id`: each maze of PointMaze and
    AntMaze in each of its variants (``hispo_pl/AntMaze_Medium-IA-v5``) and each game maze
    (``hispo_pl/AmazeVille_HOOO-v0``), with its family's entry point (:mod:`.family`). Entry
    points are named by string, so registering imports no simulator. Runs on ``import
    hispo_pl.envs``; a second call changes nothing."""
    for family, fam in FAMILIES.items():
        behaviour = family_behaviour(fam)
        for maze, defaults in fam.mazes.items():
            for variant in fam.variants:
                task = Task(family, maze, variant)
                if task.gym_id in gym.registry:
                    continue
                gym.register(
                    id=task.gym_id,
                    entry_point=behaviour.entry_point,
                    kwargs=behaviour.env_kwargs(task),
                    max_episode_steps=defaults.max_episode_steps,
                    disable_env_checker=True,
                )


def task_env(task: str | Task, **kwargs) -> gym.Env:
    """The entry point of a maze task's Gymnasium id: gymnasium-robotics' maze env, built
    without its own wrappers (``gym.make`` of the task id adds the step limit), seen through
    the task's variant. The maze XML that gymnasium-robotics writes into the temp dir on every
    construction is deleted once the model is loaded."""
    global _robotics_registered
    task = parse_task(task)
    if not _robotics_registered:
        import gymnasium_robotics

        gym.register_envs(gymnasium_robotics)
        _robotics_registered = True
    base = gym.spec(task.env_id)
    creator = gym.envs.registration.load_env_creator(base.entry_point)
    env = creator(**{**base.kwargs, **task.env_family.env_kwargs, **kwargs})
    tmp_xml = getattr(env, "tmp_xml_file_path", None)
    if tmp_xml and os.path.exists(tmp_xml):
        os.remove(tmp_xml)
    return VariantWrapper(env, task) if task.variant != "N" else env


def make_env(task: str | Task, *, continuing_task: bool = False, **kwargs) -> gym.Env:
    """``gym.make`` of ``task``'s registered id (its variant applied, its step limit set).

    ``continuing_task=False`` (our default, unlike gymnasium-robotics') ends an episode on
    success, as evaluation needs; data collection passes ``True``. Extra kwargs go to
    ``gym.make`` (e.g. ``max_episode_steps``).
    """
    return gym.make(parse_task(task).gym_id, continuing_task=continuing_task, **kwargs)


register_tasks()


def agent_flipped(env: gym.Env) -> bool:
    """Whether the agent has failed irrecoverably: the ant on its back (torso up axis below
    the horizon, read from the simulator, so any variant's view of it is irrelevant). The
    point mass cannot fail this way."""
    ant = getattr(env.unwrapped, "ant_env", None)
    if ant is None:
        return False
    _, qx, qy, _ = ant.data.qpos[3:7]
    return bool(1.0 - 2.0 * (qx * qx + qy * qy) < 0.0)


__all__ = ["make_env", "register_tasks", "task_env", "agent_flipped", "VariantWrapper"]
