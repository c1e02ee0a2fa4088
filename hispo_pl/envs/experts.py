"""Scripted PointMaze expert: shortest path over maze cells, PD control toward the next
waypoint, as D4RL's maze2d data was collected."""

from __future__ import annotations

import numpy as np

from .mazes import bfs_next_cell, cell_to_xy, maze_array, xy_to_cell


class PointMazeExpert:
    """Waypoint controller for PointMaze (works on the base, normal-variant env).

    The waypoint is the centre of the next cell on a BFS shortest path to the goal's cell, or
    the goal itself once in that cell. The action is ``kp * (waypoint - pos) - kd * vel``,
    clipped to the action box. BFS tables are cached per goal cell.
    """

    name = "pointmaze-bfs-pd"

    def __init__(self, env, kp: float = 10.0, kd: float = 1.0):
        self.env = env
        self.kp, self.kd = kp, kd
        self.grid = maze_array(env)
        self._next: dict[tuple[int, int], np.ndarray] = {}

    def waypoint(self, pos: np.ndarray, goal: np.ndarray) -> np.ndarray:
        goal_cell = tuple(int(v) for v in xy_to_cell(self.env, goal))
        if goal_cell not in self._next:
            self._next[goal_cell] = bfs_next_cell(self.grid, goal_cell)
        cell = tuple(int(v) for v in xy_to_cell(self.env, pos))
        if cell == goal_cell:
            return goal
        nxt = self._next[goal_cell][cell]
        if nxt[0] < 0:  # inside a wall cell after a collision: head for the goal directly
            return goal
        return cell_to_xy(self.env, nxt)

    def act(self, obs: dict) -> np.ndarray:
        pos, vel = obs["observation"][:2], obs["observation"][2:4]
        target = self.waypoint(pos, obs["desired_goal"])
        return np.clip(self.kp * (target - pos) - self.kd * vel, -1.0, 1.0)
