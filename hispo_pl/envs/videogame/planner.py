"""Route planning over a video-game maze: a fine cost grid, A* and path simplification.

The demonstration expert (:mod:`.expert`) drives the gamepad along these routes. Everything
here is pure (a :class:`Layout` in, arrays and points out) so it can be tested without
MuJoCo, and cheap: a grid is built once per maze and an A* search takes tens of milliseconds.

Levels: the agent is either on the floor (level 0) or standing on a low block (level 1). A
fine cell's class says which level it belongs to: floor cells are level 0, cells inside a
low block's footprint are level 1 (the agent can only be there on top of it), walls and high
blocks are never passable. Entering a low block from the floor needs a jump, so that move
costs extra; dropping off a block is free.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np

from .layouts import Layout

FLOOR, LOW, WALL = 0, 1, 2
AGENT_RADIUS = 0.4  # the env's capsule radius
JUMPABLE_HEIGHT = 1.2  # the env's jump rises ~1.5 m: 1 m blocks yes, 3 m walls no
MAX_CLEARANCE = 3.0  # clearances are computed (and capped) within this distance
SQRT2 = float(np.sqrt(2.0))
# 8-connected moves (d_row, d_col) with their lengths in cells; rows grow with y here
MOVES = tuple(
    (dr, dc, SQRT2 if dr and dc else 1.0) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc
)


@dataclass(frozen=True)
class PlannerConfig:
    """Tunables of the cost grid and the simplification, in metres.

    ``hard_clearance``: a cell whose centre is closer than this to a wall is impassable
    (the capsule could not be there). ``soft_clearance`` / ``soft_weight``: cells closer
    than ``soft_clearance`` cost up to ``1 + soft_weight`` times more, so routes keep off
    walls where there is room. ``edge_clearance`` / ``edge_weight``: the same for the edges
    of a block top (falling off means jumping up again), ``low_clearance`` / ``low_weight``
    for floor cells beside a low block. ``jump_cost``: the extra cost of a jump, so blocks
    are crossed only when that is clearly shorter. ``los_clearance`` / ``los_low`` /
    ``los_edge``: how far a shortcut must stay from walls / (on the floor) from low blocks /
    (on a block top) inside its edge. ``approach``: the straight run kept before and after a
    jump, so the agent meets the block edge head-on instead of sliding along it.
    """

    resolution: float = 0.5
    hard_clearance: float = AGENT_RADIUS + 0.1
    soft_clearance: float = 1.6
    soft_weight: float = 1.5
    edge_clearance: float = 1.0
    edge_weight: float = 1.0
    low_clearance: float = AGENT_RADIUS + 0.5  # floor cells this close to a low block...
    low_weight: float = 2.0  # ...cost more: the capsule would rub (or, within 0.4 m, be on) it
    jump_cost: float = 3.0
    los_clearance: float = AGENT_RADIUS + 0.45
    los_low: float = AGENT_RADIUS + 0.25
    los_edge: float = 0.5
    approach: float = 1.5


@dataclass
class Route:
    """A planned route: world points (N, 2), the level of each point (0 floor, 1 block top)
    and the indices ``i`` where the segment ``points[i] -> points[i + 1]`` is a jump up."""

    points: np.ndarray
    levels: np.ndarray
    jumps: tuple[int, ...] = ()
    cost: float = 0.0
    lengths: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        self.lengths = np.concatenate([[0.0], np.cumsum(seg)])

    @property
    def length(self) -> float:
        return float(self.lengths[-1])

    def point_at(self, s: float) -> np.ndarray:
        """The point at arc length ``s`` (clamped to the ends)."""
        s = float(np.clip(s, 0.0, self.length))
        i = int(
            np.clip(np.searchsorted(self.lengths, s, side="right") - 1, 0, len(self.points) - 2)
        )
        if len(self.points) == 1:
            return self.points[0].copy()
        seg = self.lengths[i + 1] - self.lengths[i]
        t = 0.0 if seg <= 0 else (s - self.lengths[i]) / seg
        return self.points[i] + t * (self.points[i + 1] - self.points[i])

    def project(
        self, p: np.ndarray, lo: int = 0, hi: int | None = None
    ) -> tuple[float, float, int]:
        """(arc length, distance, segment) of the closest point of segments ``lo..hi-1`` to
        ``p``: the expert searches a window ahead of its last segment so that a route that
        passes near itself (a U-turn) does not make it jump back or ahead."""
        if len(self.points) == 1:
            return 0.0, float(np.linalg.norm(p - self.points[0])), 0
        hi = len(self.points) - 1 if hi is None else min(hi, len(self.points) - 1)
        lo = min(lo, hi - 1)
        a, b = self.points[lo:hi], self.points[lo + 1 : hi + 1]
        ab = b - a
        denom = np.maximum((ab**2).sum(1), 1e-12)
        t = np.clip(((p - a) * ab).sum(1) / denom, 0.0, 1.0)
        closest = a + t[:, None] * ab
        d = np.linalg.norm(closest - p, axis=1)
        k = int(np.argmin(d))
        s = self.lengths[lo + k] + t[k] * np.sqrt(denom[k])
        return float(s), float(d[k]), lo + k


class CostGrid:
    """The maze at ``resolution`` metres: cell classes, clearances and step costs.

    Row ``r`` / column ``c`` of the grid is the cell whose centre is
    ``((c + 0.5) * res, (r + 0.5) * res)`` (rows grow with y, unlike the layout's rows).
    Clearances are exact distances from cell centres to the nearest wall / low block / floor
    cell (walls tile whole fine cells because the layout's cell is a multiple of the
    resolution). A distance is 1-Lipschitz, so a point ``p`` in cell ``c`` is within
    ``|p - centre(c)|`` of ``clear[c]``: the shortcut checks compute exact distances only for
    points whose cell is near their threshold.
    """

    def __init__(self, layout: Layout, config: PlannerConfig | None = None):
        self.layout = layout
        self.config = cfg = config or PlannerConfig()
        res = cfg.resolution
        ratio = layout.cell / res
        if abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"layout cell {layout.cell} m is not a multiple of {res} m")
        k = int(round(ratio))
        heights = layout.heights()[::-1]  # layout row 0 is the top; ours is the bottom
        h = np.kron(heights, np.ones((k, k)))
        self.res = res
        self.shape = h.shape
        cls = np.full(h.shape, FLOOR, dtype=np.int8)
        cls[(h > 0) & (h <= JUMPABLE_HEIGHT)] = LOW
        cls[h > JUMPABLE_HEIGHT] = WALL
        self.cls = cls
        self.wall_clear = _clearance(cls == WALL, res, outside=True)
        self.low_clear = _clearance(cls == LOW, res, outside=False)
        self.edge_clear = _clearance(cls == FLOOR, res, outside=False)  # inside blocks
        self.passable = (cls != WALL) & (self.wall_clear >= cfg.hard_clearance)
        soft = cfg.soft_weight * np.clip(
            (cfg.soft_clearance - self.wall_clear) / cfg.soft_clearance, 0.0, 1.0
        )
        on_low = cls == LOW
        edge = cfg.edge_weight * np.clip(
            (cfg.edge_clearance - self.edge_clear) / cfg.edge_clearance, 0.0, 1.0
        )
        near_low = cfg.low_weight * np.clip(
            (cfg.low_clearance - self.low_clear) / cfg.low_clearance, 0.0, 1.0
        )
        self.base_cost = 1.0 + soft + np.where(on_low, edge, near_low)
        self._k = int(np.ceil(max(cfg.los_clearance, cfg.los_low, cfg.los_edge) / res)) + 1
        self._pads = {
            name: np.pad(cls == value, self._k, constant_values=value == WALL)
            for name, value in (("wall", WALL), ("low", LOW), ("floor", FLOOR))
        }

    # --- coordinates ----------------------------------------------------------------------
    def cell(self, p: np.ndarray) -> tuple[int, int]:
        """The (row, col) of the fine cell holding world point ``p`` (clamped to the map)."""
        r = int(np.clip(np.floor(p[1] / self.res), 0, self.shape[0] - 1))
        c = int(np.clip(np.floor(p[0] / self.res), 0, self.shape[1] - 1))
        return r, c

    def centre(self, rc: tuple[int, int]) -> np.ndarray:
        return np.array([(rc[1] + 0.5) * self.res, (rc[0] + 0.5) * self.res])

    def nearest(self, p: np.ndarray, level: int) -> tuple[int, int]:
        """The passable cell of ``level`` whose centre is closest to ``p``: where a search
        starts when the agent's own cell is not one (pressed against a wall, or standing on
        a block's rim with its centre beyond the edge)."""
        rc = self.cell(p)
        if self.passable[rc] and self.cls[rc] == level:
            return rc
        ok = self.passable & (self.cls == level)
        if not ok.any():
            raise ValueError(f"no passable cell of level {level} in {self.layout.name}")
        rows, cols = np.nonzero(ok)
        d = ((cols + 0.5) * self.res - p[0]) ** 2 + ((rows + 0.5) * self.res - p[1]) ** 2
        i = int(np.argmin(d))
        return int(rows[i]), int(cols[i])

    def level_at(self, p: np.ndarray) -> int:
        """The class of the cell holding ``p`` (0 floor, 1 low block, 2 wall)."""
        return int(self.cls[self.cell(p)])

    # --- costs ----------------------------------------------------------------------------
    def route_noise(self, rng: np.random.Generator, scale: float, blob: float = 4.0) -> np.ndarray:
        """A smooth random cost multiplier >= 1 (bilinear over blobs of ``blob`` metres): a
        per-episode preference that makes A* pick among nearly equally short routes (which
        door, which side of a block) without zig-zags, as different players would. It never
        goes below 1, so the straight-line heuristic stays admissible."""
        if scale <= 0:
            return np.ones(self.shape)
        rows, cols = self.shape
        n_r = int(np.ceil(rows * self.res / blob)) + 2
        n_c = int(np.ceil(cols * self.res / blob)) + 2
        coarse = rng.random((n_r, n_c))
        y = (np.arange(rows) + 0.5) * self.res / blob
        x = (np.arange(cols) + 0.5) * self.res / blob
        y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
        ty, tx = (y - y0)[:, None], (x - x0)[None, :]
        a = coarse[np.ix_(y0, x0)]
        b = coarse[np.ix_(y0, x0 + 1)]
        c = coarse[np.ix_(y0 + 1, x0)]
        d = coarse[np.ix_(y0 + 1, x0 + 1)]
        smooth = (a * (1 - tx) + b * tx) * (1 - ty) + (c * (1 - tx) + d * tx) * ty
        return 1.0 + scale * smooth

    # --- search ---------------------------------------------------------------------------
    def astar(
        self,
        start: tuple[int, int],
        goal: tuple[int, int],
        noise: np.ndarray | None = None,
    ) -> tuple[list[tuple[int, int]], float] | None:
        """Cheapest 8-connected cell path from ``start`` to ``goal`` (both included) and its
        cost, or None when the goal cannot be reached.

        A move costs its length (metres) times the entered cell's cost (and ``noise``), plus
        ``jump_cost`` when it goes from the floor onto a low block. Diagonal moves need both
        cells they brush past to be passable (no cutting a wall corner), and a diagonal move
        never changes level (jumps meet a block edge square-on). The heuristic is the octile
        distance, a lower bound since every cost factor is >= 1.
        """
        rows, cols = self.shape
        cost = self.base_cost if noise is None else self.base_cost * noise
        w = cols + 2  # padded, so neighbours never leave the array
        passable = np.zeros((rows + 2, w), dtype=bool)
        passable[1:-1, 1:-1] = self.passable
        cls = np.full((rows + 2, w), WALL, dtype=np.int8)
        cls[1:-1, 1:-1] = self.cls
        cost_p = np.ones((rows + 2, w))
        cost_p[1:-1, 1:-1] = cost * self.res
        s = (start[0] + 1) * w + start[1] + 1
        g = (goal[0] + 1) * w + goal[1] + 1
        if not passable[goal[0] + 1, goal[1] + 1]:
            return None
        # the heuristic of every cell at once; plain lists are much faster than numpy
        # scalars in the Python loop below
        rr, cc = np.indices(passable.shape)
        dr, dc = np.abs(rr - (goal[0] + 1)), np.abs(cc - (goal[1] + 1))
        hs = (self.res * (np.maximum(dr, dc) + (SQRT2 - 1.0) * np.minimum(dr, dc))).ravel()
        hs = hs.tolist()
        passable_f = passable.ravel().tolist()
        cls_f = cls.ravel().tolist()
        cost_f = cost_p.ravel().tolist()
        jump = self.config.jump_cost
        moves = [(dr * w + dc, dr * w, dc, length) for dr, dc, length in MOVES]
        inf = float("inf")
        best = [inf] * len(passable_f)
        parent = [-1] * len(passable_f)
        closed = bytearray(len(passable_f))
        best[s] = 0.0
        heap = [(hs[s], 0.0, s)]
        push, pop = heapq.heappush, heapq.heappop
        while heap:
            _, gs, n = pop(heap)
            if closed[n]:
                continue
            if n == g:
                break
            closed[n] = 1
            n_cls = cls_f[n]
            for off, off_r, off_c, length in moves:
                m = n + off
                if closed[m] or not passable_f[m]:
                    continue
                m_cls = cls_f[m]
                if off_r and off_c:
                    if m_cls != n_cls:
                        continue
                    if not (passable_f[n + off_r] and passable_f[n + off_c]):
                        continue
                gm = gs + length * cost_f[m]
                if m_cls == LOW and n_cls == FLOOR:
                    gm += jump
                if gm < best[m]:
                    best[m] = gm
                    parent[m] = n
                    push(heap, (gm + hs[m], gm, m))
        if best[g] == inf:
            return None
        path = []
        n = g
        while n != s:
            r, c = divmod(n, w)
            path.append((r - 1, c - 1))
            n = parent[n]
        path.append((start[0], start[1]))
        return path[::-1], best[g]

    # --- simplification -------------------------------------------------------------------
    def clearance_at(self, pts: np.ndarray, mask: str) -> np.ndarray:
        """Exact distance from each point (S, 2) to the nearest cell of ``mask`` (``"wall"``,
        with the outside of the map; ``"low"``; ``"floor"``), capped just above the largest
        shortcut clearance: what the shortcut checks need, exact near wall corners where a
        bound from cell-centre clearances would be too pessimistic."""
        k, res = self._k, self.res
        pad = self._pads[mask]
        r = np.clip(np.floor(pts[:, 1] / res).astype(int), 0, self.shape[0] - 1)
        c = np.clip(np.floor(pts[:, 0] / res).astype(int), 0, self.shape[1] - 1)
        off = np.arange(-k, k + 1)
        rr = r[:, None, None] + off[None, :, None]
        cc = c[:, None, None] + off[None, None, :]
        hit = pad[rr + k, cc + k]
        dx = np.maximum(np.maximum(cc * res - pts[:, 0, None, None], 0.0),
                        pts[:, 0, None, None] - (cc + 1) * res)  # fmt: skip
        dy = np.maximum(np.maximum(rr * res - pts[:, 1, None, None], 0.0),
                        pts[:, 1, None, None] - (rr + 1) * res)  # fmt: skip
        d = np.where(hit, np.hypot(dx, dy), np.inf)
        return np.minimum(d.min(axis=(1, 2)), (k - 0.5) * res)

    def segment_clear(
        self, a: np.ndarray, b: np.ndarray, level: int | None, clearance: float | None = None
    ) -> bool:
        """Whether the agent can go straight from ``a`` to ``b`` on ``level``: every sample
        (every quarter of a cell) keeps ``los_clearance`` from walls and stays on the level (on
        the floor, ``los_low`` clear of low blocks; on a block top, ``los_edge`` inside its
        edge). ``level=None`` checks walls only (the jump itself crosses a block edge);
        ``clearance`` overrides ``los_clearance``."""
        cfg = self.config
        clearance = cfg.los_clearance if clearance is None else clearance
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / (self.res / 4))) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        pts = a + t * (b - a)
        r = np.clip(np.floor(pts[:, 1] / self.res).astype(int), 0, self.shape[0] - 1)
        c = np.clip(np.floor(pts[:, 0] / self.res).astype(int), 0, self.shape[1] - 1)
        if not self._clear(pts, self.wall_clear[r, c], "wall", clearance):
            return False
        if level is None:
            return True
        if np.any(self.cls[r, c] != level):
            return False
        if level == FLOOR:
            return self._clear(pts, self.low_clear[r, c], "low", cfg.los_low)
        return self._clear(pts, self.edge_clear[r, c], "floor", cfg.los_edge)

    def _clear(self, pts: np.ndarray, centre_clear: np.ndarray, mask: str, need: float) -> bool:
        """Whether every point is ``need`` away from ``mask``. A point lies within half a
        cell diagonal of its cell's centre, whose clearance is known, so only points in cells
        near the threshold need the exact (slower) window computation."""
        half = self.res / SQRT2
        if np.any(centre_clear + half < need):
            return False
        unsure = centre_clear - half < need
        if not unsure.any():
            return True
        return bool(np.all(self.clearance_at(pts[unsure], mask) >= need))

    def simplify(self, cells: list[tuple[int, int]], goal: np.ndarray, start: np.ndarray) -> Route:
        """Turn a cell path into a route of few straight segments.

        The points are the cell centres with the real start and goal at the ends. They are
        split at level changes; around each jump up the points ``approach`` metres before and
        after the block edge are kept (the run-up and the landing), and within a stretch on
        one level a point is dropped when the segment over it stays clear
        (:meth:`segment_clear`): shortcuts never cross a wall, never clip a block on the
        floor, never leave a block top, and never skip the run-up to a jump.
        """
        pts = np.array([self.centre(rc) for rc in cells], dtype=np.float64)
        levels = np.array([self.cls[rc] for rc in cells], dtype=np.int8)
        pts[0] = start
        if len(pts) > 1:
            pts[-1] = goal
        else:
            pts = np.vstack([start, goal])
            levels = np.array([levels[0], levels[0]], dtype=np.int8)
        n = len(pts)
        k = max(1, int(round(self.config.approach / self.res)))
        keep = np.zeros(n, dtype=bool)
        keep[[0, n - 1]] = True
        ups = [i for i in range(n - 1) if levels[i] == FLOOR and levels[i + 1] == LOW]
        downs = [i for i in range(n - 1) if levels[i] != levels[i + 1] and i not in ups]
        for i in downs:  # the last block point and the first floor point after a drop
            keep[[i, i + 1]] = True
        jump_pairs = []
        for i in ups:
            lo = i
            while lo > 0 and i - lo < k and levels[lo - 1] == FLOOR and not keep[lo]:
                lo -= 1
            hi = i + 1
            while hi < n - 1 and hi - (i + 1) < k and levels[hi + 1] == LOW:
                hi += 1
            keep[[lo, i, i + 1, hi]] = True
            jump_pairs.append((lo, hi))
        # the run-up / landing stretches are straightened only if the straight line is clear
        straight = set()
        for lo, hi in jump_pairs:
            if self.segment_clear(pts[lo], pts[hi], None):
                straight.add(lo)
                keep[lo + 1 : hi] = False
                keep[[lo, hi]] = True
        anchors = list(np.nonzero(keep)[0])
        out = [0]
        for a, b in zip(anchors[:-1], anchors[1:], strict=True):
            if a in straight:
                out.append(b)
                continue
            level = int(levels[a]) if levels[a] == levels[b] else None
            i = a
            while i < b:
                i = self._reach(pts, i, b, level)
                out.append(i)
        out_idx = np.array(out)
        fixed = np.isin(out_idx, np.nonzero(keep)[0])
        route_pts, route_lv = self.tighten(pts[out_idx], levels[out_idx], fixed)
        jumps = tuple(
            i for i in range(len(route_lv) - 1) if route_lv[i] == FLOOR and route_lv[i + 1] == LOW
        )
        return Route(route_pts, route_lv, jumps)

    def _reach(self, pts: np.ndarray, i: int, b: int, level: int | None) -> int:
        """The furthest point in ``i + 1 .. b`` seen straight from point ``i`` (galloping then
        bisecting: far fewer segment checks than trying every point, and any point it returns
        is truly visible, which is all the shortcut needs)."""
        good, step = i + 1, 1
        while good < b:
            cand = min(good + step, b)
            if self.segment_clear(pts[i], pts[cand], level):
                good, step = cand, step * 2
                continue
            bad = cand
            while bad - good > 1:
                mid = (good + bad) // 2
                if self.segment_clear(pts[i], pts[mid], level):
                    good = mid
                else:
                    bad = mid
            break
        return good

    def tighten(
        self, pts: np.ndarray, levels: np.ndarray, fixed: np.ndarray, passes: int = 12
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pull the free corners of a route toward the straight line between their neighbours
        for as long as both segments stay clear, dropping corners that become unnecessary.

        A* on a grid with clearance costs goes through the middle of doors and turns at cell
        centres; the taut string around the same obstacles is what a player runs, and in
        SimpleTown's 100-step episodes the difference (a few metres) matters. Corners next
        to a level change (the run-up and landing of a jump, a drop) stay where they are.
        """
        pts, levels, fixed = pts.copy(), levels.copy(), fixed.copy()
        for _ in range(passes):
            moved = False
            i = 1
            while i < len(pts) - 1:
                lv = int(levels[i])
                if fixed[i] or levels[i - 1] != lv or levels[i + 1] != lv:
                    i += 1
                    continue
                a, p, b = pts[i - 1], pts[i], pts[i + 1]
                if self.segment_clear(a, b, lv):
                    pts = np.delete(pts, i, axis=0)
                    levels, fixed = np.delete(levels, i), np.delete(fixed, i)
                    moved = True
                    continue
                # shorten |a - p| + |p - b|: step against its gradient while both stay clear
                grad = (p - a) / max(np.linalg.norm(p - a), 1e-9)
                grad += (p - b) / max(np.linalg.norm(p - b), 1e-9)
                norm = np.linalg.norm(grad)
                if norm > 1e-6:
                    for step in (0.4, 0.2, 0.1, 0.05):
                        q = p - step * grad / norm
                        if self.segment_clear(a, q, lv) and self.segment_clear(q, b, lv):
                            pts[i] = q
                            moved = True
                            break
                i += 1
            if not moved:
                break
        return pts, levels

    def plan(
        self,
        start: np.ndarray,
        goal: np.ndarray,
        start_level: int = FLOOR,
        noise: np.ndarray | None = None,
    ) -> Route | None:
        """A simplified route from world point ``start`` (on ``start_level``) to ``goal`` (on
        the floor), or None when there is none."""
        start, goal = np.asarray(start, float)[:2], np.asarray(goal, float)[:2]
        s = self.nearest(start, start_level)
        g = self.nearest(goal, FLOOR)
        found = self.astar(s, g, noise)
        if found is None:
            return None
        cells, cost = found
        route = self.simplify(cells, goal, start)
        route.cost = cost
        return route


def _clearance(mask: np.ndarray, res: float, outside: bool) -> np.ndarray:
    """Distance (metres, capped at ``MAX_CLEARANCE``) from every cell centre to the nearest
    cell of ``mask`` (0 in it); ``outside=True`` counts everything beyond the map as part of
    the mask (the perimeter walls). A windowed minimum over cell offsets: the distance from a
    centre to a square cell ``(dr, dc)`` cells away is that of the offset minus half a cell
    on each axis, so the result is exact within the window."""
    k = int(np.ceil(MAX_CLEARANCE / res)) + 1
    rows, cols = mask.shape
    padded = np.full((rows + 2 * k, cols + 2 * k), outside, dtype=bool)
    padded[k:-k, k:-k] = mask
    out = np.where(mask, 0.0, MAX_CLEARANCE)
    for dr in range(-k, k + 1):
        for dc in range(-k, k + 1):
            if dr == 0 and dc == 0:
                continue
            d = res * np.hypot(max(abs(dr) - 0.5, 0.0), max(abs(dc) - 0.5, 0.0))
            if d >= MAX_CLEARANCE:
                continue
            hit = padded[k + dr : k + dr + rows, k + dc : k + dc + cols]
            out = np.where(hit & (out > d), d, out)
    return out


_GRIDS: dict[tuple[str, tuple[str, ...], float, PlannerConfig], CostGrid] = {}


def cost_grid(layout: Layout, config: PlannerConfig | None = None) -> CostGrid:
    """The (cached) cost grid of ``layout``: built once per maze and configuration, since
    every episode of a collection plans on the same map."""
    config = config or PlannerConfig()
    key = (layout.name, layout.grid, layout.block_height, config)
    if key not in _GRIDS:
        _GRIDS[key] = CostGrid(layout, config)
    return _GRIDS[key]
