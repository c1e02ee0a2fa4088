"""Deterministic rollout evaluation, vectorised over episodes: one policy call per step."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from .data.sampler import position_velocity
from .envs import agent_flipped, make_env
from .envs.family import family_behaviour
from .nn import eval_mode
from .progress import ProgressPrinter
from .tasks import Task, agent_position, parse_task

PolicyFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]
"""(observation [B, obs], position [B, 2], goal [B, 2], velocity [B, 2]) -> action [B, act],
deterministic. ``position`` is as the agent senses it (:func:`~hispo_pl.tasks.agent_position`)
and ``velocity`` its last step over the family's step time (0 on an episode's first step), as
:class:`~hispo_pl.data.sampler.HERSampler` computes them from data."""


@dataclass(frozen=True)
class RolloutResult:
    success: float
    episode_length: float
    episodes: int
    successes: np.ndarray  # [episodes] bool
    lengths: np.ndarray  # [episodes] int
    flips: np.ndarray  # [episodes] bool: ended by the agent flipping over (the ant)
    trajectories: list[np.ndarray] | None = None  # per episode [length + 1, goal_dim] positions

    @property
    def flip_rate(self) -> float:
        return float(self.flips.mean())


def reset_options(task: Task, env, episodes: int, seed: int) -> list[dict]:
    """Seeded start and goal of each evaluation episode of ``task`` as ``env.reset`` options,
    drawn as ``task``'s family draws them."""
    return family_behaviour(task).reset_options(env, episodes, seed)


class RolloutEvaluator:
    """Runs a policy on a task for ``episodes`` seeded episodes.

    ``min(episodes, max_envs)`` environments are built once and reused across calls, so
    periodic evaluation during training costs no env construction; an env whose episode ends
    starts the next waiting one at once, so a few envs serve many episodes without waiting
    for the slowest of a batch. Episodes are seeded by their index, so which env runs one
    changes nothing.
    """

    def __init__(
        self,
        task: str | Task,
        episodes: int = 100,
        seed: int = 0,
        max_envs: int = 50,
        max_episode_steps: int | None = None,
    ):
        self.task = parse_task(task)
        self.episodes, self.seed = episodes, seed
        steps = max_episode_steps or self.task.defaults.max_episode_steps
        self.envs = [
            make_env(self.task, max_episode_steps=steps) for _ in range(min(episodes, max_envs))
        ]
        self.max_steps = steps
        self.step_seconds = self.task.env_family.step_seconds
        self.options = reset_options(self.task, self.envs[0], episodes, seed)

    def run(
        self, policy: PolicyFn, progress: bool | ProgressPrinter = False, record: bool = False
    ) -> RolloutResult:
        """Success, lengths and flips of every episode; ``record`` also keeps each episode's
        positions (for pictures). One policy call per step for all running episodes.
        ``progress``: show it (:class:`~hispo_pl.progress.ProgressPrinter`), or count the episodes
        into a given one (several evaluations under one count)."""
        successes = np.zeros(self.episodes, dtype=bool)
        flips = np.zeros(self.episodes, dtype=bool)
        lengths = np.zeros(self.episodes, dtype=np.int64)
        paths: list[list[np.ndarray]] = [[] for _ in range(self.episodes)]
        sensed: list[list[np.ndarray]] = [[] for _ in range(self.episodes)]  # agent_position

        def observe(k: int, o: dict) -> None:
            paths[k].append(o["achieved_goal"])
            sensed[k].append(agent_position(self.task, o["observation"], o["achieved_goal"]))

        waiting = iter(range(self.episodes))
        running: list[int | None] = [None] * len(self.envs)  # episode of each env
        obs: list[dict] = [{}] * len(self.envs)
        own = not isinstance(progress, ProgressPrinter)
        bar = (
            ProgressPrinter(f"eval {self.task}", self.episodes, "episodes", progress)
            if own
            else progress
        )

        def start_next(slot: int) -> None:
            k = running[slot] = next(waiting, None)
            if k is not None:
                options = self.options[k]
                obs[slot] = self.envs[slot].reset(seed=self.seed * 100_003 + k, options=options)[0]
                observe(k, obs[slot])

        for slot in range(len(self.envs)):
            start_next(slot)
        while any(k is not None for k in running):
            slots = [s for s, k in enumerate(running) if k is not None]
            batch = {
                key: torch.as_tensor(np.stack([obs[s][key] for s in slots]), dtype=torch.float32)
                for key in ("observation", "desired_goal")
            }
            here = [sensed[running[s]] for s in slots]
            position = torch.as_tensor(np.stack([p[-1] for p in here]), dtype=torch.float32)
            previous = torch.as_tensor(
                np.stack([p[-2 if len(p) > 1 else -1] for p in here]), dtype=torch.float32
            )
            velocity = position_velocity(position, previous, self.step_seconds)
            actions = policy(batch["observation"], position, batch["desired_goal"], velocity)
            for a, s in zip(actions.detach().cpu().numpy(), slots, strict=True):
                k = running[s]
                obs[s], _, terminated, truncated, info = self.envs[s].step(a)
                observe(k, obs[s])
                lengths[k] += 1
                if info.get("success", False):
                    successes[k] = True
                elif agent_flipped(self.envs[s]):
                    flips[k] = True
                ended = terminated or truncated or successes[k] or flips[k]
                if ended or lengths[k] >= self.max_steps:
                    bar.update(1)
                    start_next(s)
        if own:
            bar.close()
        return RolloutResult(
            float(successes.mean()),
            float(lengths.mean()),
            self.episodes,
            successes,
            lengths,
            flips,
            [np.asarray(p) for p in paths] if record else None,
        )

    def close(self) -> None:
        for env in self.envs:
            env.close()


def module_policy(module, task: int | None = None) -> PolicyFn:
    """A deterministic policy function from a module's ``act(obs, pos, goal, task)``, run in
    eval mode; ``task`` picks the task's policy for methods that keep one per task."""

    def policy(observation, position, goal, velocity):
        with eval_mode(module):
            device = next(module.parameters()).device
            obs, pos, goal = observation.to(device), position.to(device), goal.to(device)
            return module.act(obs, pos, goal, task=task, velocity=velocity.to(device))

    return policy
