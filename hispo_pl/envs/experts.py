"""Scripted PointMaze expert: shortest path over maze cells, PD control toward the next
waypoint, as D4RL's maze2d data was collected."""

from __future__ import annotations

import numpy as np

from .mazes import bfs_next_cell, cell_to_xy, maze_array, xy_to_cell


class PointMazeExpert:
    """Waypoint controller for PointMaze (acts on the base, normal-variant env).

    Waypoints are the centres of the cells on a BFS shortest path to the goal's cell, then the
    goal itself. The controller advances to the next waypoint only once within
    ``switch_radius`` of the current one, so paths turn at cell centres instead of cutting
    corners (a policy imitating corner-cutting data gets stuck on wall corners). The action is
    ``kp * (waypoint - pos) - kd * vel``, clipped to the action box. BFS tables are cached per
    goal cell; call :meth:`reset` at the start of each episode.
    """

    name = "pointmaze-bfs-pd"

    def __init__(self, env, kp: float = 10.0, kd: float = 1.0, switch_radius: float = 0.3):
        self.env = env
        self.kp, self.kd, self.switch_radius = kp, kd, switch_radius
        self.grid = maze_array(env)
        self._next: dict[tuple[int, int], np.ndarray] = {}
        self._target: tuple[int, int] | None = None

    def reset(self) -> None:
        self._target = None

    def _next_table(self, goal_cell: tuple[int, int]) -> np.ndarray:
        if goal_cell not in self._next:
            self._next[goal_cell] = bfs_next_cell(self.grid, goal_cell)
        return self._next[goal_cell]

    def waypoint(self, pos: np.ndarray, goal: np.ndarray) -> np.ndarray:
        goal_cell = tuple(int(v) for v in xy_to_cell(self.env, goal))
        cell = tuple(int(v) for v in xy_to_cell(self.env, pos))
        nxt = self._next_table(goal_cell)
        if cell == goal_cell or nxt[cell][0] < 0:  # in the goal cell, or pushed into a wall cell
            self._target = None
            return goal
        if (
            self._target is None
            or abs(self._target[0] - cell[0]) + abs(self._target[1] - cell[1]) > 1
        ):
            self._target = tuple(int(v) for v in nxt[cell])  # (re)plan from the current cell
        centre = cell_to_xy(self.env, np.array(self._target))
        if np.linalg.norm(centre - pos) < self.switch_radius:
            if self._target == goal_cell:
                return goal
            self._target = tuple(int(v) for v in nxt[self._target])
            centre = cell_to_xy(self.env, np.array(self._target))
        return goal if self._target == goal_cell else centre

    def act(self, obs: dict) -> np.ndarray:
        pos, vel = obs["observation"][:2], obs["observation"][2:4]
        target = self.waypoint(pos, obs["desired_goal"])
        return np.clip(self.kp * (target - pos) - self.kd * vel, -1.0, 1.0)
