"""The PointMaze expert: reaches goals, turns at cell centres, replans when the goal changes."""

from __future__ import annotations

import numpy as np
import pytest

from hispo_pl.envs import make_env
from hispo_pl.envs.experts import PointMazeExpert
from hispo_pl.envs.mazes import bfs_next_cell, cell_to_xy, free_cells, maze_array, xy_to_cell
from hispo_pl.envs.robotics import start_goal_cells


def run_expert(env, expert, start, goal, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed, options={"reset_cell": start, "goal_cell": goal})
    expert.reset()
    path = [obs["achieved_goal"]]
    for _ in range(env.spec.max_episode_steps):
        action = np.clip(expert.act(obs) + noise * rng.standard_normal(2), -1, 1)
        obs, _, terminated, truncated, info = env.step(action)
        path.append(obs["achieved_goal"])
        if terminated or truncated:
            break
    return bool(info["success"]), np.array(path)


@pytest.mark.parametrize("maze", ["umaze", "medium", "large"])
def test_expert_reaches_random_goals_with_noise(maze):
    env = make_env(f"pointmaze-{maze}")
    expert = PointMazeExpert(env)
    pairs = start_goal_cells(maze_array(env), 8, seed=3)
    results = [
        run_expert(env, expert, s, g, noise=0.2, seed=k)[0] for k, (s, g) in enumerate(pairs)
    ]
    assert all(results)


def test_bfs_next_cell_follows_a_shortest_path():
    grid = maze_array(make_env("pointmaze-medium"))
    goal = (6, 6)
    nxt = bfs_next_cell(grid, goal)
    for cell in map(tuple, free_cells(grid)):
        steps, cur = 0, cell
        while cur != goal:
            new = tuple(nxt[cur])
            assert abs(new[0] - cur[0]) + abs(new[1] - cur[1]) == 1  # one move between neighbours
            assert grid[new] == 0
            cur, steps = new, steps + 1
            assert steps < grid.size
    assert tuple(nxt[goal]) == goal
    assert (nxt[grid == 1] == -1).all()


def test_expert_turns_near_cell_centres():
    """Without noise, each change of cell happens close to the corridor's centre line: the
    expert reaches a waypoint (within its switch radius) before heading for the next one."""
    env = make_env("pointmaze-large")
    expert = PointMazeExpert(env)
    ok, path = run_expert(env, expert, np.array([1, 1]), np.array([7, 10]))
    assert ok
    cells = xy_to_cell(env, path)
    crossings = np.flatnonzero(np.any(cells[1:] != cells[:-1], axis=1))
    for i in crossings:
        a, b = cells[i], cells[i + 1]
        centre_a, centre_b = cell_to_xy(env, a), cell_to_xy(env, b)
        axis = 1 if a[0] == b[0] else 0  # a move along x keeps y on the centre line, and vice versa
        assert abs(path[i + 1][axis] - centre_b[axis]) < 0.35
        assert abs(path[i][axis] - centre_a[axis]) < 0.35


def test_expert_replans_when_the_goal_changes():
    env = make_env("pointmaze-umaze", continuing_task=True, reset_target=True)
    expert = PointMazeExpert(env)
    obs, _ = env.reset(
        seed=0, options={"reset_cell": np.array([1, 1]), "goal_cell": np.array([3, 1])}
    )
    expert.reset()
    goals = {tuple(obs["desired_goal"])}
    reached = 0
    for _ in range(env.spec.max_episode_steps):
        before = obs["desired_goal"]
        obs, *_ = env.step(expert.act(obs))
        reached += bool(np.linalg.norm(obs["achieved_goal"] - before) <= 0.45)
        goals.add(tuple(obs["desired_goal"]))
    assert reached >= 2 and len(goals) >= 3  # it keeps reaching the new goals the env draws
