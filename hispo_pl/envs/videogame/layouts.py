"""The video-game mazes as data: character maps, heights, start and goal points.

AmazeVille and SimpleTown are the paper's Godot mazes (appendix A.1.2), redrawn from the
authors' top-down renders. A layout is a character grid (row 0 = the top, i.e. the far
side from the starts) with a cell size in metres; world coordinates put the map's
bottom-left corner at the origin, x to the right, y up the map, z up:
``x = (col + 0.5) * cell``, ``y = (rows - row - 0.5) * cell``.

Characters: ``.`` floor, ``#`` wall, ``G`` block (high or low), ``a`` / ``b`` / ``c`` doors
(wall when closed, floor when open). Resolved layouts hold only ``.``, ``#`` and ``G``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ...task_families import FAMILIES

WALL_HEIGHT = 3.0
HIGH_BLOCK = 3.0  # H mazes: not jumpable
LOW_BLOCK = 1.0  # L mazes: jumpable

# fmt: off
AMAZEVILLE_MAP = (
    "..............................",
    "..............................",
    "..............................",
    "..............................",
    "....G.......#GGGGGGGGG........",
    "....G.......#.................",
    "....G.......#.................",
    "....G.......#.................",
    "....G.......#.................",
    "....G...##..##########...#....",
    "....G...##..##########...#....",
    "....G...##.......#####...#....",
    "....G...##.......#####...#....",
    "....G...##.......#####...#....",
    "#####aaa#####....#####bbb#####",
    "#####aaa#####....#####bbb#####",
    "............#.................",
    "............#.................",
    "............#.................",
    "............#.................",
    "............#.................",
    "....GGGGGGGGGGGGG#GGGGGGGGG...",
    "....GGGGGGGGGGGGG#GGGGGGGGG...",
    "....GGGGGGGGGGGGG#GGGGGGGGG...",
    "....GGGGGGGGGGGGG#GGGGGGGGG...",
    "....GGGGGGGGGGGGG#GGGGGGGGG...",
    "..............................",
    "..............................",
    "..............................",
    "..............................",
)
# fmt: on
AMAZEVILLE_CELL = 2.0
# (row, col) cells whose centres are the start / goal points
AMAZEVILLE_STARTS = ((28, 2), (28, 15), (28, 27))  # bottom edge: left, centre, right
AMAZEVILLE_GOALS = (
    (9, 2),  # left of the left block column
    (9, 6),  # right of the left block column
    (2, 17),  # above the top block bar
    (6, 17),  # below the top block bar
    (11, 23),  # left of the right wall
    (11, 27),  # right of the right wall
)

SIMPLETOWN_SIZE = 30  # metres, one character per metre
SIMPLETOWN_WALL_ROWS = (14, 15)  # a 2 m thick wall across the middle
SIMPLETOWN_DOORS = ((3, 7), (13, 17), (23, 27))  # left, middle, right door columns [start, end)
SIMPLETOWN_MARGIN = 1.5  # starts and goals lie this far inside the bottom / top side


@dataclass(frozen=True)
class Layout:
    """A resolved maze: grid of ``.``/``#``/``G``, cell size, block height, starts and goals.

    ``starts`` / ``goals`` are fixed points (AmazeVille) or, when ``start_segment`` /
    ``goal_segment`` are set, the end points of the horizontal segments along which points
    are drawn uniformly (SimpleTown). All points are (x, y) in metres.
    """

    name: str
    grid: tuple[str, ...]
    cell: float
    block_height: float
    step_limit: int
    starts: tuple[tuple[float, float], ...]
    goals: tuple[tuple[float, float], ...]
    segments: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.grid), len(self.grid[0])

    @property
    def size(self) -> tuple[float, float]:
        """(width, depth) in metres."""
        rows, cols = self.shape
        return cols * self.cell, rows * self.cell

    def array(self) -> np.ndarray:
        """The grid as a [rows, cols] array of characters."""
        return np.array([list(row) for row in self.grid])

    def heights(self) -> np.ndarray:
        """Obstacle height of every cell in metres (0 = floor), shape [rows, cols]."""
        grid = self.array()
        h = np.zeros(grid.shape)
        h[grid == "#"] = WALL_HEIGHT
        h[grid == "G"] = self.block_height
        return h

    def cell_centre(self, row: float, col: float) -> tuple[float, float]:
        rows = self.shape[0]
        return ((col + 0.5) * self.cell, (rows - row - 0.5) * self.cell)

    def cell_of(self, x: float, y: float) -> tuple[int, int]:
        rows = self.shape[0]
        return int(rows - 1 - np.floor(y / self.cell)), int(np.floor(x / self.cell))

    def sample_start_goal(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One episode's start and goal (x, y): a pair of the fixed points, or points drawn
        uniformly on the start / goal segments."""
        if self.segments:
            (sx0, sy), (sx1, _) = self.starts
            (gx0, gy), (gx1, _) = self.goals
            return (
                np.array([rng.uniform(sx0, sx1), sy]),
                np.array([rng.uniform(gx0, gx1), gy]),
            )
        start = self.starts[rng.integers(len(self.starts))]
        goal = self.goals[rng.integers(len(self.goals))]
        return np.asarray(start, dtype=np.float64), np.asarray(goal, dtype=np.float64)


class LayoutNameError(ValueError):
    """A maze name that is not one of the sixteen video-game mazes."""


AMAZEVILLE_NAMES = tuple(FAMILIES["amazeville"].mazes)  # HOOO HOOX HXOO HXOX LOOO ... LXOX
SIMPLETOWN_NAMES = tuple(FAMILIES["simpletown"].mazes)  # BASE OOO OOX OXO XOO XXO XOX OXX

_AMAZEVILLE_RE = re.compile(r"^(?P<blocks>[HL])(?P<left>[OX])O(?P<right>[OX])$")


def amazeville(name: str) -> Layout:
    """AmazeVille maze ``name`` = ``<H|L><left door><O><right door>`` (O open, X closed).

    L mazes have low (jumpable) blocks and two small differences read off the renders: a
    2 m gap between the bottom-right block and the central wall, and the left block column
    ending 2 m higher.
    """
    m = _AMAZEVILLE_RE.match(name)
    if m is None:
        raise LayoutNameError(
            f"unknown AmazeVille maze {name!r}; known: {', '.join(AMAZEVILLE_NAMES)}"
        )
    grid = [list(row) for row in AMAZEVILLE_MAP]
    for door, state in (("a", m["left"]), ("b", m["right"])):
        fill = "." if state == "O" else "#"
        grid = [[fill if c == door else c for c in row] for row in grid]
    low = m["blocks"] == "L"
    if low:
        for row in range(21, 26):
            grid[row][18] = "."  # gap between the bottom-right block and the central wall
        grid[13][4] = "."  # the left block column ends one cell higher
    layout_grid = tuple("".join(row) for row in grid)
    ref = Layout(name, layout_grid, AMAZEVILLE_CELL, 0.0, 300, (), ())
    return Layout(
        name=name,
        grid=layout_grid,
        cell=AMAZEVILLE_CELL,
        block_height=LOW_BLOCK if low else HIGH_BLOCK,
        step_limit=300,
        starts=tuple(ref.cell_centre(*rc) for rc in AMAZEVILLE_STARTS),
        goals=tuple(ref.cell_centre(*rc) for rc in AMAZEVILLE_GOALS),
    )


def simpletown(name: str) -> Layout:
    """SimpleTown maze ``name``: ``BASE`` (an empty 30 × 30 m square) or three door states
    (left, middle, right; O open, X closed) of a wall across the middle."""
    if name not in SIMPLETOWN_NAMES:
        raise LayoutNameError(
            f"unknown SimpleTown maze {name!r}; known: {', '.join(SIMPLETOWN_NAMES)}"
        )
    n = SIMPLETOWN_SIZE
    grid = [["."] * n for _ in range(n)]
    if name != "BASE":
        for row in SIMPLETOWN_WALL_ROWS:
            grid[row] = ["#"] * n
            for (c0, c1), state in zip(SIMPLETOWN_DOORS, name, strict=True):
                if state == "O":
                    grid[row][c0:c1] = ["."] * (c1 - c0)
    lo, hi = SIMPLETOWN_MARGIN, n - SIMPLETOWN_MARGIN
    return Layout(
        name=name,
        grid=tuple("".join(row) for row in grid),
        cell=1.0,
        block_height=HIGH_BLOCK,
        step_limit=100,
        starts=((lo, lo), (hi, lo)),
        goals=((lo, hi), (hi, hi)),
        segments=True,
    )


GAMES = {"amazeville": amazeville, "simpletown": simpletown}
GAME_MAZES = {"amazeville": AMAZEVILLE_NAMES, "simpletown": SIMPLETOWN_NAMES}


def layout(game: str, name: str) -> Layout:
    """The layout of maze ``name`` of ``game`` (``amazeville`` or ``simpletown``)."""
    if game not in GAMES:
        raise LayoutNameError(f"unknown game {game!r}; known: {', '.join(GAMES)}")
    return GAMES[game](name)
