"""The video-game maze families (AmazeVille, SimpleTown, :mod:`hispo_pl.envs.videogame`):
episodes from a layout's start point to its goal point, ending when the goal is touched.
Env code is imported only when used, so registering the tasks loads no simulator."""

from __future__ import annotations

import json

import numpy as np

from ..tasks import Task
from .family import episode_arrays


class GameMazes:
    """:class:`~hispo_pl.envs.family.FamilyBehaviour` of the video-game mazes."""

    entry_point = "hispo_pl.envs.videogame.env:GameNavEnv"

    def env_kwargs(self, task: Task) -> dict:
        return {"game": task.family, "maze": task.maze}

    def make_collection_env(self, task: Task):
        """The evaluation env itself: each episode ends at its goal."""
        from . import make_env

        return make_env(task)

    def reset_options(self, env, episodes: int, seed: int) -> list[dict]:
        """The layout's start and goal points (or points drawn on its segments)."""
        rng = np.random.default_rng(seed)
        draws = [env.unwrapped.layout.sample_start_goal(rng) for _ in range(episodes)]
        return [{"start": start, "goal": goal} for start, goal in draws]

    def collect_episode(
        self, env, expert, rng: np.random.Generator, seed: int, noise: float, steps: int
    ) -> dict:
        """One episode from a drawn start point to a drawn goal point, ending when the goal
        is touched (the env terminates) or after ``steps`` steps; ``reached`` marks the step
        that touched the goal. The planner plays without ``noise``: its own randomness comes
        from ``rng``."""
        start, goal = env.unwrapped.layout.sample_start_goal(rng)
        obs, _ = env.reset(seed=seed, options={"start": start, "goal": goal})
        expert.reset(rng)
        keys = ("observation", "achieved_goal", "desired_goal")
        record = {k: [obs[k]] for k in keys}
        actions, rewards, success = [], [], []
        for _ in range(steps):
            action = expert.act(obs)
            obs, reward, terminated, truncated, info = env.step(action)
            for k in keys:
                record[k].append(obs[k])
            actions.append(action)
            rewards.append(reward)
            success.append(bool(info["success"]))
            if terminated or truncated:
                break
        return episode_arrays(record, actions, rewards, success, flipped=False)

    def episode_ended(self, episode: dict) -> bool:
        """An episode ends by touching its goal."""
        return bool(episode["reached"][-1])

    def describe_dataset(self, task: Task, expert, settings: dict, stats: dict) -> str:
        ok, failed = stats["goals_reached"], stats["goals_failed"]
        return (
            f"{settings['episodes']} episodes on {task.env_id}, each from a start point to a "
            f"goal point of the layout, ending when the goal is touched or after "
            f"{task.defaults.max_episode_steps} steps; seed {settings['seed']}. "
            f"Planner-generated, not human play (the paper's data was played by people): the "
            f"expert '{expert.name}' ({expert.description}). Expert success: {ok}/{ok + failed}"
            f" = {stats['goal_success']:.4f}. Stats: {json.dumps(stats)}"
        )

    def draw_maze(self, ax, task: Task) -> None:
        """Walls, doors and blocks of the layout, and its start and goal points (markers) or
        segments (lines)."""
        from .drawing import GOAL, START, draw_cells, game_cell_kinds
        from .videogame.layouts import layout

        lay = layout(task.family, task.maze)
        half = lay.cell / 2

        def corner(r: int, c: int) -> tuple[float, float]:
            x, y = lay.cell_centre(r, c)
            return x - half, y - half

        for kind, mask in game_cell_kinds(task.family, lay).items():
            draw_cells(ax, mask, corner, lay.cell, kind)
        starts, goals = np.asarray(lay.starts), np.asarray(lay.goals)
        if lay.segments:  # points are drawn uniformly along these segments
            for pts, colour, gid in (
                (starts, START, "start-segment"),
                (goals, GOAL, "goal-segment"),
            ):
                (line,) = ax.plot(pts[:, 0], pts[:, 1], color=colour, lw=3, alpha=0.8, zorder=3)
                line.set_gid(gid)
        else:
            for pts, colour, marker, gid in (
                (starts, START, "^", "starts"),
                (goals, GOAL, "*", "goals"),
            ):
                (line,) = ax.plot(
                    pts[:, 0],
                    pts[:, 1],
                    ls="none",
                    marker=marker,
                    ms=9,
                    mfc=colour,
                    mec="white",
                    mew=0.8,
                    zorder=4,
                )
                line.set_gid(gid)
        width, depth = lay.size
        ax.set_xlim(0, width)
        ax.set_ylim(0, depth)
