"""Experts that collect our datasets, as D4RL collected its maze data: a shortest path over
maze cells gives waypoints, and a controller drives the agent to the next one.

- :class:`PointMazeExpert`: PD control of the ball (D4RL's maze2d).
- :class:`AntMazeExpert`: D4RL's pretrained goal-reaching ant policy (weights not shipped:
  see :func:`ant_expert_weights_path`), steered at the next cell centre (D4RL's antmaze).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import UserError
from .mazes import bfs_next_cell, cell_to_xy, maze_array, xy_to_cell

# An expert's arithmetic must give the same bits on every processor, or a dataset made again on
# another machine holds other episodes (the ant's small differences grow into other paths).
# BLAS does not: the kernel OpenBLAS picks for the processor sums a matrix product in its own
# order. Elementwise products and numpy's own sums over a row do, so the experts use them.


def _dense(weight: np.ndarray, bias: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``weight @ x + bias``, summed in numpy's order rather than the BLAS kernel's."""
    return (weight * x).sum(axis=1) + bias


def _length(v: np.ndarray) -> float:
    """``np.linalg.norm(v)`` without BLAS (which computes it as a dot product)."""
    return float(np.sqrt((v * v).sum()))


class WaypointPlanner:
    """Waypoints toward a goal: the centres of the cells on a BFS shortest path, then the goal
    itself once in its cell. BFS tables are cached per goal cell.

    ``switch_radius`` > 0 holds each waypoint until the agent is that close to it (paths turn
    at cell centres instead of cutting corners); ``None`` re-plans from the current cell at
    every step (the next cell's centre), as D4RL's ant collection did.
    """

    def __init__(self, env, switch_radius: float | None = None):
        self.env = env
        self.switch_radius = switch_radius
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
        if self.switch_radius is None:
            target = tuple(int(v) for v in nxt[cell])
            return goal if target == goal_cell else cell_to_xy(self.env, np.array(target))
        if (
            self._target is None
            or abs(self._target[0] - cell[0]) + abs(self._target[1] - cell[1]) > 1
        ):
            self._target = tuple(int(v) for v in nxt[cell])  # (re)plan from the current cell
        centre = cell_to_xy(self.env, np.array(self._target))
        if _length(centre - pos) < self.switch_radius:
            if self._target == goal_cell:
                return goal
            self._target = tuple(int(v) for v in nxt[self._target])
            centre = cell_to_xy(self.env, np.array(self._target))
        return goal if self._target == goal_cell else centre


class PointMazeExpert:
    """Waypoint controller for PointMaze (acts on the base, normal-variant env).

    The action is ``kp * (waypoint - pos) - kd * vel``, clipped to the action box; waypoints
    are held until within ``switch_radius`` (a policy imitating corner-cutting data gets stuck
    on wall corners). Call :meth:`reset` at the start of each episode.
    """

    name = "pointmaze-bfs-pd"
    description = "BFS over maze cells + PD to the next waypoint"
    action_noise = 0.2  # Gaussian std in env action units while collecting

    def __init__(self, env, kp: float = 10.0, kd: float = 1.0, switch_radius: float = 0.3):
        self.kp, self.kd = kp, kd
        self.planner = WaypointPlanner(env, switch_radius)

    def reset(self) -> None:
        self.planner.reset()

    def act(self, obs: dict) -> np.ndarray:
        pos, vel = obs["observation"][:2], obs["observation"][2:4]
        target = self.planner.waypoint(pos, obs["desired_goal"])
        return np.clip(self.kp * (target - pos) - self.kd * vel, -1.0, 1.0)


# --- AntMaze ---------------------------------------------------------------------------------

ANT_EXPERT_ENV = "HISPO_ANT_EXPERT"
ANT_EXPERT_FILE = "d4rl_antmaze_goal_policy.npz"
ANT_ACTION_SCALE = 0.2  # D4RL's ant: torque 30 at 0.1 s steps; gymnasium's: 150 at 0.05 s
ANT_WEIGHT_KEYS = (
    "fc0_weight",
    "fc0_bias",
    "fc1_weight",
    "fc1_bias",
    "last_fc_weight",
    "last_fc_bias",
)


class ExpertWeightsNotFoundError(UserError, FileNotFoundError):
    """The ant expert's weights file is missing; the message says where to get it."""


def ant_expert_weights_path(path: str | os.PathLike | None = None) -> Path:
    """Where the ant expert's weights are: ``path``, else ``$HISPO_ANT_EXPERT``, else
    ``../shared/experts/d4rl_antmaze_goal_policy.npz`` beside the working directory or beside
    this checkout. Raises :class:`ExpertWeightsNotFoundError` (saying how to get them) when
    the file does not exist; the weights are never shipped with hispo-pl."""
    if path is None:
        path = os.environ.get(ANT_EXPERT_ENV)
    if path is not None:
        candidates = [Path(path).expanduser()]
    else:
        repo = Path(__file__).resolve().parents[2]
        candidates = [
            base / ".." / "shared" / "experts" / ANT_EXPERT_FILE for base in (Path.cwd(), repo)
        ]
    for candidate in candidates:
        if candidate.is_file():
            return candidate.resolve()
    tried = "\n".join(f"  {c}" for c in candidates)
    raise ExpertWeightsNotFoundError(
        f"AntMaze expert weights not found; looked at:\n{tried}\n"
        "They are the goal-reaching ant policy D4RL collected its AntMaze datasets with (rlkit "
        "TanhGaussianPolicy, 29 inputs, two hidden layers of 256, 8 actions), saved as an .npz "
        f"of the arrays {', '.join(ANT_WEIGHT_KEYS)}. Get them from D4RL's AntMaze data "
        "collection (github.com/Farama-Foundation/D4RL, scripts/generation) and point at the "
        f"file with {ANT_EXPERT_ENV}=/path/to/{ANT_EXPERT_FILE} (or --expert-weights)."
    )


class AntGoalPolicy:
    """D4RL's goal-reaching ant policy in numpy: x (27-value body observation + the direction
    to the waypoint, scaled to length 10) → tanh of the Gaussian mean (8 actions in [-1, 1])."""

    def __init__(self, weights: dict[str, np.ndarray]):
        missing = [k for k in ANT_WEIGHT_KEYS if k not in weights]
        if missing:
            raise ValueError(f"ant expert weights lack {', '.join(missing)}")
        self.w = {k: np.asarray(weights[k], dtype=np.float64) for k in ANT_WEIGHT_KEYS}

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> AntGoalPolicy:
        with np.load(ant_expert_weights_path(path)) as f:
            return cls({k: f[k] for k in f.files})

    def __call__(self, x: np.ndarray) -> np.ndarray:
        w = self.w
        h = np.maximum(_dense(w["fc0_weight"], w["fc0_bias"], x), 0.0)
        h = np.maximum(_dense(w["fc1_weight"], w["fc1_bias"], h), 0.0)
        return np.tanh(_dense(w["last_fc_weight"], w["last_fc_bias"], h))


class AntMazeExpert:
    """D4RL's ant policy steered at the next cell centre of a BFS path (the goal in its cell);
    actions scaled by 0.2 for gymnasium's ant."""

    name = "antmaze-bfs-d4rl-policy"
    description = "BFS over maze cells, D4RL's goal-reaching ant policy to the next cell centre"
    action_noise = 0.04  # D4RL's 0.2 in policy units, times ANT_ACTION_SCALE

    def __init__(self, env, weights: str | os.PathLike | None = None, direction_scale=10.0):
        self.policy = AntGoalPolicy.load(weights)
        self.planner = WaypointPlanner(env, switch_radius=None)
        self.direction_scale = direction_scale

    def reset(self) -> None:
        self.planner.reset()

    def policy_input(self, obs: dict) -> np.ndarray:
        pos = obs["achieved_goal"]
        direction = self.planner.waypoint(pos, obs["desired_goal"]) - pos
        norm = _length(direction)
        if norm > 1e-8:
            direction = direction * (self.direction_scale / norm)
        return np.concatenate([obs["observation"], direction])

    def act(self, obs: dict) -> np.ndarray:
        return ANT_ACTION_SCALE * self.policy(self.policy_input(obs))
