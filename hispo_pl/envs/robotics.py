"""The gymnasium-robotics maze families (PointMaze, AntMaze): continuing episodes from free
cells, new goal cells drawn by the env, every task variant under its own Gymnasium id."""

from __future__ import annotations

import json

import numpy as np

from ..tasks import Task
from .family import episode_arrays
from .mazes import cell_to_xy, free_cells, maze_array


def start_goal_cells(grid: np.ndarray, episodes: int, seed: int) -> np.ndarray:
    """Seeded random (start, goal) pairs of distinct free cells, shape [episodes, 2, 2]."""
    cells = free_cells(grid)
    rng = np.random.default_rng(seed)
    pick = np.stack([rng.choice(len(cells), 2, replace=False) for _ in range(episodes)])
    return cells[pick]


class RoboticsMazes:
    """:class:`~hispo_pl.envs.family.FamilyBehaviour` of the gymnasium-robotics mazes."""

    entry_point = "hispo_pl.envs:task_env"

    def env_kwargs(self, task: Task) -> dict:
        return {"task": f"{task.family}-{task.maze}-{task.variant}"}

    def make_collection_env(self, task: Task):
        """A continuing env that draws a new goal cell whenever the current one is reached."""
        from . import make_env

        return make_env(task, continuing_task=True, reset_target=True)

    def reset_options(self, env, episodes: int, seed: int) -> list[dict]:
        """Distinct free cells of the maze as start and goal."""
        cells = start_goal_cells(maze_array(env), episodes, seed)
        return [{"reset_cell": start, "goal_cell": goal} for start, goal in cells]

    def collect_episode(
        self, env, expert, rng: np.random.Generator, seed: int, noise: float, steps: int
    ) -> dict:
        """One continuing episode of ``steps`` steps from a random start cell; new goal cells
        are drawn by the env whenever the current one is reached. An episode in which the
        agent flips over (:func:`~hispo_pl.envs.agent_flipped`, the check evaluation uses) is
        cut at that step: its clean prefix is kept and ``flipped`` is set."""
        from . import agent_flipped

        cells = free_cells(maze_array(env))
        i, j = rng.choice(len(cells), size=2, replace=False)
        obs, _ = env.reset(seed=seed, options={"reset_cell": cells[i], "goal_cell": cells[j]})
        expert.reset()
        keys = ("observation", "achieved_goal", "desired_goal")
        record = {k: [obs[k]] for k in keys}
        actions, rewards, success = [], [], []
        low, high = env.action_space.low, env.action_space.high
        flipped = False
        for _ in range(steps):
            action = expert.act(obs)
            action = np.clip(action + noise * rng.standard_normal(action.shape), low, high)
            goal_before = obs["desired_goal"]
            obs, reward, _, _, info = env.step(action)
            if agent_flipped(env):  # the transition into the flip is not kept
                flipped = True
                break
            reached = bool(np.linalg.norm(obs["achieved_goal"] - goal_before) <= 0.45)
            for k in keys:
                record[k].append(obs[k])
            actions.append(action)
            rewards.append(reward)
            success.append(reached)
        return episode_arrays(record, actions, rewards, success, flipped)

    def episode_ended(self, episode: dict) -> bool:
        """Never: an episode is cut after its steps (or at a flip), the env goes on."""
        return False

    def describe_dataset(self, task: Task, expert, settings: dict, stats: dict) -> str:
        episodes, steps = settings["episodes"], task.defaults.max_episode_steps
        ok, failed, flips = (
            stats["goals_reached"],
            stats["goals_failed"],
            stats["episodes_cut_at_flip"],
        )
        cut = (
            f" {flips} of {episodes} episodes ended early because the agent flipped over: the "
            f"clean prefix is kept, {stats['steps']} of {episodes * steps} steps."
            if flips
            else ""
        )
        return (
            f"{episodes} continuing episodes of {steps} steps on {task.env_id}, collected by the "
            f"expert '{expert.name}' ({expert.description}) with Gaussian action noise std "
            f"{settings['noise']:g}, seed {settings['seed']}; a new goal cell is drawn each time "
            f"the goal is reached. Expert goal success: {ok}/{ok + failed} = "
            f"{stats['goal_success']:.4f} (a goal fails if not reached within {steps} steps)."
            f"{cut} Stats: {json.dumps(stats)}"
        )

    def draw_maze(self, ax, task: Task) -> None:
        """Its wall cells, in the env's own maze coordinates (starts and goals are random free
        cells, so none are marked)."""
        from . import make_env
        from .drawing import draw_cells

        env = make_env(task)
        try:
            grid = maze_array(env)
            size = float(env.unwrapped.maze.maze_size_scaling)

            def corner(r: int, c: int) -> tuple[float, float]:
                x, y = cell_to_xy(env, np.array([r, c]))
                return x - size / 2, y - size / 2

            draw_cells(ax, grid == 1, corner, size, "wall")
            rows, cols = grid.shape
            left, top = cell_to_xy(env, np.array([0, 0])) + [-size / 2, size / 2]
            right, bottom = cell_to_xy(env, np.array([rows - 1, cols - 1])) + [size / 2, -size / 2]
        finally:
            env.close()
        ax.set_xlim(left, right)
        ax.set_ylim(bottom, top)
