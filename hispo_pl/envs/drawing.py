"""How a maze is drawn: the palette, the styles of its cells and the cell geometry both env
families draw with (:meth:`~hispo_pl.envs.family.FamilyBehaviour.draw_maze`). The figures
themselves are :mod:`hispo_pl.render`'s; this module sits with the envs so that the families
draw without importing the layer above them."""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.patches import Rectangle

from .videogame.layouts import (
    AMAZEVILLE_MAP,
    HIGH_BLOCK,
    SIMPLETOWN_DOORS,
    SIMPLETOWN_WALL_ROWS,
    Layout,
)

FLOOR = "#d9d9cf"  # the env's floor colour (0.8 0.8 0.75)
WALL = "#555560"
DOOR_CLOSED = "#8c5a2b"  # a wall that is open in a sibling maze: brown, hatched
DOOR_OPEN = "#c07a30"
BLOCK_HIGH = "#2e6b2e"  # 3 m: a wall to the agent
BLOCK_LOW = "#9ed49e"  # 1 m: jumpable
START = "#1f4fd1"
GOAL = "#d62020"
FAILURE = "#d62020"

STYLES: dict[str, dict] = {
    "wall": {"facecolor": WALL, "edgecolor": "none"},
    "door-closed": {"facecolor": WALL, "edgecolor": DOOR_CLOSED, "hatch": "xxx", "lw": 1.0},
    "door-open": {"facecolor": "none", "edgecolor": DOOR_OPEN, "linestyle": "--", "lw": 1.2},
    "block-high": {"facecolor": BLOCK_HIGH, "edgecolor": "#1c431c", "hatch": "///", "lw": 0.5},
    "block-low": {"facecolor": BLOCK_LOW, "edgecolor": "#5f9f5f", "lw": 0.5},
}
LABELS = {
    "wall": "wall",
    "door-closed": "closed door",
    "door-open": "open door",
    "block-high": "high block (3 m)",
    "block-low": "low block (1 m, jumpable)",
}


# --- maze geometry -------------------------------------------------------------------------


def cell_rectangles(mask: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Rectangles (first row, end row, first col, end col; ends exclusive) that cover the True
    cells of ``mask`` exactly, without overlap: horizontal runs merged with the same run in
    the rows below. A maze becomes tens of patches rather than hundreds, and a block reads
    as one block rather than as stripes."""
    rects, open_runs = [], {}  # (c0, c1) -> first row of the run's rectangle
    mask = np.asarray(mask, dtype=bool)
    for r, row in enumerate(mask):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row.astype(np.int8), [0]])))
        runs = {(int(c0), int(c1)) for c0, c1 in zip(edges[::2], edges[1::2], strict=True)}
        for run in set(open_runs) - runs:
            rects.append((open_runs.pop(run), r, *run))
        for run in runs - set(open_runs):
            open_runs[run] = r
    rects.extend((r0, len(mask), *run) for run, r0 in open_runs.items())
    return sorted(rects)


def door_mask(game: str, lay: Layout) -> np.ndarray:
    """Cells that are doors in ``game``'s raw map, whatever their state in this maze: the
    resolved layout only holds ``#`` or ``.`` there, so doors are found by comparing with
    the map the mazes are resolved from."""
    mask = np.zeros(lay.shape, dtype=bool)
    if game == "amazeville":
        mask = np.isin(np.array([list(row) for row in AMAZEVILLE_MAP]), list("abc"))
    elif game == "simpletown" and lay.name != "BASE":
        for row in SIMPLETOWN_WALL_ROWS:
            for c0, c1 in SIMPLETOWN_DOORS:
                mask[row, c0:c1] = True
    return mask


def game_cell_kinds(game: str, lay: Layout) -> dict[str, np.ndarray]:
    """Boolean [rows, cols] masks of what each cell of a game maze is drawn as."""
    grid = lay.array()
    doors = door_mask(game, lay)
    block = "block-high" if lay.block_height >= HIGH_BLOCK else "block-low"
    return {
        "wall": (grid == "#") & ~doors,
        "door-closed": (grid == "#") & doors,
        "door-open": (grid == ".") & doors,
        block: grid == "G",
    }


def draw_cells(ax: Axes, mask: np.ndarray, corner, size: float, kind: str) -> None:
    """The cells of ``mask`` as rectangles of style ``kind``; ``corner(row, col)`` is a
    cell's lower-left (x, y) in world coordinates (rows run down the map) and ``size`` its
    side."""
    for r0, r1, c0, c1 in cell_rectangles(mask):
        x, y = corner(r1 - 1, c0)
        rect = Rectangle((x, y), (c1 - c0) * size, (r1 - r0) * size, **STYLES[kind], zorder=1)
        rect.set_gid(kind)
        ax.add_patch(rect)
