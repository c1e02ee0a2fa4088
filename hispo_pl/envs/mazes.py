"""Maze geometry shared by the expert and the evaluator: free cells, cell centres, BFS."""

from __future__ import annotations

from collections import deque

import numpy as np

WALL = 1


def maze_array(env) -> np.ndarray:
    """The maze map of a gymnasium-robotics maze env as an int array (1 = wall)."""
    grid = env.unwrapped.maze.maze_map
    return np.array([[1 if c == WALL else 0 for c in row] for row in grid], dtype=np.int8)


def free_cells(grid: np.ndarray) -> np.ndarray:
    """(row, col) of every free cell, shape [n, 2], in row-major order."""
    return np.argwhere(grid == 0)


def bfs_next_cell(grid: np.ndarray, goal: tuple[int, int]) -> np.ndarray:
    """For every free cell, the neighbouring cell one step closer to ``goal`` (goal maps to
    itself; unreachable and wall cells to -1). Shape [rows, cols, 2]."""
    rows, cols = grid.shape
    nxt = np.full((rows, cols, 2), -1, dtype=np.int64)
    nxt[goal] = goal
    queue = deque([goal])
    while queue:
        r, c = queue.popleft()
        for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            rr, cc = r + dr, c + dc
            if 0 <= rr < rows and 0 <= cc < cols and grid[rr, cc] == 0 and nxt[rr, cc, 0] < 0:
                nxt[rr, cc] = (r, c)
                queue.append((rr, cc))
    return nxt


def cell_to_xy(env, cells: np.ndarray) -> np.ndarray:
    """Centres of (row, col) cells in maze coordinates, vectorised over the leading axis."""
    maze = env.unwrapped.maze
    cells = np.asarray(cells, dtype=np.float64)
    x = (cells[..., 1] + 0.5) * maze.maze_size_scaling - maze.x_map_center
    y = maze.y_map_center - (cells[..., 0] + 0.5) * maze.maze_size_scaling
    return np.stack([x, y], axis=-1)


def xy_to_cell(env, xy: np.ndarray) -> np.ndarray:
    """(row, col) of the cell containing each point, vectorised over the leading axis."""
    maze = env.unwrapped.maze
    xy = np.asarray(xy, dtype=np.float64)
    col = np.floor((xy[..., 0] + maze.x_map_center) / maze.maze_size_scaling)
    row = np.floor((maze.y_map_center - xy[..., 1]) / maze.maze_size_scaling)
    return np.stack([row, col], axis=-1).astype(np.int64)
