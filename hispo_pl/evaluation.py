"""Deterministic rollout evaluation, vectorised over episodes: one policy call per step."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from tqdm.auto import tqdm

from .data.sampler import position_velocity
from .data.tasks import Task, parse_task
from .envs import agent_flipped, make_env
from .envs.mazes import free_cells, maze_array
from .nn import eval_mode

PolicyFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]
"""(observation [B, obs], position [B, 2], goal [B, 2], velocity [B, 2]) -> action [B, act],
deterministic. ``velocity`` is the last position step over the family's step time (0 on an
episode's first step), as :class:`~hispo_pl.data.sampler.HERSampler` computes it from data."""


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


def start_goal_cells(grid: np.ndarray, episodes: int, seed: int) -> np.ndarray:
    """Seeded random (start, goal) pairs of distinct free cells, shape [episodes, 2, 2]."""
    cells = free_cells(grid)
    rng = np.random.default_rng(seed)
    pick = np.stack([rng.choice(len(cells), 2, replace=False) for _ in range(episodes)])
    return cells[pick]


def reset_options(env, episodes: int, seed: int) -> list[dict]:
    """Seeded start and goal of each evaluation episode as ``env.reset`` options: distinct free
    cells of a gymnasium-robotics maze, or a video-game layout's start and goal points."""
    from .envs.videogame import GameNavEnv

    if isinstance(env.unwrapped, GameNavEnv):
        rng = np.random.default_rng(seed)
        draws = [env.unwrapped.layout.sample_start_goal(rng) for _ in range(episodes)]
        return [{"start": start, "goal": goal} for start, goal in draws]
    cells = start_goal_cells(maze_array(env), episodes, seed)
    return [{"reset_cell": start, "goal_cell": goal} for start, goal in cells]


class RolloutEvaluator:
    """Runs a policy on a task for ``episodes`` seeded episodes.

    Environments are built once (``min(episodes, max_envs)`` of them) and reused across calls,
    so periodic evaluation during training costs no env construction.
    """

    def __init__(
        self,
        task: str | Task,
        episodes: int = 100,
        seed: int = 0,
        max_envs: int = 100,
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
        self.options = reset_options(self.envs[0], episodes, seed)

    def run(self, policy: PolicyFn, progress: bool = False, record: bool = False) -> RolloutResult:
        """Success, lengths and flips of every episode; ``record`` also keeps each episode's
        positions (for pictures)."""
        successes = np.zeros(self.episodes, dtype=bool)
        flips = np.zeros(self.episodes, dtype=bool)
        lengths = np.zeros(self.episodes, dtype=np.int64)
        paths: list[np.ndarray] = [np.zeros((0, 0))] * self.episodes
        n_envs = len(self.envs)
        for wave in tqdm(
            range(0, self.episodes, n_envs), desc=f"eval {self.task}", disable=not progress
        ):
            ids = list(range(wave, min(wave + n_envs, self.episodes)))
            successes[ids], lengths[ids], flips[ids], wave_paths = self._run_wave(policy, ids)
            for k, path in zip(ids, wave_paths, strict=True):
                paths[k] = path
        return RolloutResult(
            float(successes.mean()),
            float(lengths.mean()),
            self.episodes,
            successes,
            lengths,
            flips,
            paths if record else None,
        )

    def _run_wave(self, policy: PolicyFn, ids: list[int]) -> tuple:
        """Successes, lengths, flips and position paths of the episodes ``ids``; a flipped
        episode ends."""
        envs = self.envs[: len(ids)]
        obs = [
            env.reset(seed=self.seed * 100_003 + k, options=self.options[k])[0]
            for env, k in zip(envs, ids, strict=True)
        ]
        paths = [[o["achieved_goal"]] for o in obs]
        active = np.ones(len(ids), dtype=bool)
        success = np.zeros(len(ids), dtype=bool)
        flipped = np.zeros(len(ids), dtype=bool)
        length = np.zeros(len(ids), dtype=np.int64)
        for _ in range(self.max_steps):
            idx = np.flatnonzero(active)
            if len(idx) == 0:
                break
            batch = {
                k: torch.as_tensor(np.stack([obs[i][k] for i in idx]), dtype=torch.float32)
                for k in ("observation", "achieved_goal", "desired_goal")
            }
            previous = torch.as_tensor(
                np.stack([paths[i][-2 if len(paths[i]) > 1 else -1] for i in idx]),
                dtype=torch.float32,
            )
            velocity = position_velocity(batch["achieved_goal"], previous, self.step_seconds)
            actions = policy(
                batch["observation"], batch["achieved_goal"], batch["desired_goal"], velocity
            )
            actions = actions.detach().cpu().numpy()
            for a, i in zip(actions, idx, strict=True):
                obs[i], _, terminated, truncated, info = envs[i].step(a)
                paths[i].append(obs[i]["achieved_goal"])
                length[i] += 1
                if info.get("success", False):
                    success[i] = True
                elif agent_flipped(envs[i]):
                    flipped[i] = True
                if terminated or truncated or success[i] or flipped[i]:
                    active[i] = False
        return success, length, flipped, [np.asarray(p) for p in paths]

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
