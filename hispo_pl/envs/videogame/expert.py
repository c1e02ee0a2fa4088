"""The demonstration expert of the video-game mazes: a route planner driving the gamepad.

The paper's AmazeVille / SimpleTown data are human play; ours is generated. An A* route over
the map (:mod:`.planner`, jumps over low blocks allowed) is followed with the same eight
gamepad inputs a player has (move buttons relative to the heading, run, jump, a rotation
target), with the habits that make human data what it is: a smoothed, lagging heading that
overshoots corners, strafing while turning, walking spells, short pauses that look around,
small detours, idle hops, jumps timed a little differently each time, and a different route
when several are nearly as short. Each episode draws its own "personality" (how much of each)
from the collector's generator, so a collection is reproducible. Every imperfection is
budgeted: it happens only when the time left, at a run, still covers the rest of the route
with room to spare, so the expert still reaches its goal within the step limit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .env import DT, FRAME_SKIP, GOAL_RADIUS, RADIUS, RUN_SPEED, STAND_Z, WALK_SPEED, wrap_angle
from .planner import FLOOR, JUMPABLE_HEIGHT, LOW, CostGrid, PlannerConfig, Route, cost_grid

STEP_S = DT * FRAME_SKIP  # seconds per decision
RUN_STEP = RUN_SPEED * STEP_S  # metres per step at a run
HOP_CLEAR_OF_GOAL = 8.0  # a hop lasts ~1.1 s (6.6 m at a run); one over the goal misses it
EVENTS = ("pause", "walk", "detour", "overshoot", "hop", "jump", "unstick")


@dataclass(frozen=True)
class Personality:
    """One episode's player: how it steers and which imperfections it shows (rates are per
    decision step; lengths in steps). Drawn by :meth:`draw`; :meth:`perfect` has none."""

    route_noise: float = 0.0  # scale of the smooth random route-cost field (route choice)
    lookahead: float = 1.6  # metres ahead on the route that the heading aims at
    smoothing: float = 1.0  # fraction of the aim's change the rotation target follows per step
    jitter: float = 0.0  # std (rad) of the thumb's error on the rotation target
    strafe: bool = False  # presses the side button toward a turn while turning
    turn_in_place: float = np.deg2rad(110.0)  # releases forward when the aim is this far off
    pause_rate: float = 0.0
    pause_len: tuple[int, int] = (2, 6)
    walk_rate: float = 0.0
    walk_len: tuple[int, int] = (4, 15)
    detour_rate: float = 0.0
    detour_len: tuple[int, int] = (6, 14)
    detour_offset: tuple[float, float] = (0.8, 2.0)
    overshoot_prob: float = 0.0  # chance of running past a sharp corner before turning
    overshoot_len: tuple[int, int] = (1, 3)
    hop_rate: float = 0.0  # idle jumps on open floor
    jump_distance: float = 1.4  # how far before a block edge (centre to edge) it jumps

    @classmethod
    def perfect(cls) -> Personality:
        return cls()

    @classmethod
    def draw(cls, rng: np.random.Generator) -> Personality:
        """A random player; every draw comes from ``rng`` in a fixed order."""
        u = rng.uniform
        return cls(
            route_noise=float(u(0.0, 0.4)),
            lookahead=float(u(1.2, 2.4)),
            smoothing=float(u(0.45, 0.95)),
            jitter=float(np.deg2rad(u(0.0, 4.0))),
            strafe=bool(rng.random() < 0.4),
            turn_in_place=float(np.deg2rad(u(90.0, 130.0))),
            pause_rate=float(u(0.0, 0.02)),
            walk_rate=float(u(0.0, 0.02)),
            detour_rate=float(u(0.0, 0.015)),
            overshoot_prob=float(u(0.0, 0.5)),
            hop_rate=float(u(0.0, 0.01)),
            jump_distance=float(u(0.9, 2.0)),
        )


def _step_limit(env) -> int:
    """The episode's step limit: the TimeLimit wrapper's if there is one (the collector's
    make_env), else the layout's."""
    limits = []
    e = env
    while e is not None:
        n = getattr(e, "_max_episode_steps", None)
        if n is not None:
            limits.append(int(n))
        e = getattr(e, "env", None)
    spec = getattr(env, "spec", None)
    if spec is not None and spec.max_episode_steps:
        limits.append(int(spec.max_episode_steps))
    return min(limits) if limits else int(env.unwrapped.layout.step_limit)


class GameExpert:
    """Planner-driven gamepad player of a video-game maze (:class:`GameNavEnv`).

    ``reset(rng)`` after each env reset draws the episode's :class:`Personality` and plans a
    route from the agent to the goal; ``act(obs)`` returns the 8 gamepad values (6 buttons
    exactly 0 or 1, then a unit rotation target). It re-plans when it strays from the route
    (pushed by a wall, a detour gone wide, fallen off a block) or stops making progress.
    """

    name = "videogame-astar-gamepad"
    description = (
        "planner-generated, not human play: A* over the map (jumps over low blocks) driving "
        "the gamepad with human-like imperfections (smoothed heading, overshoot, pauses, "
        "detours, varied routes)"
    )
    action_noise = 0.0

    def __init__(self, env, config: PlannerConfig | None = None, perfect: bool = False):
        self.env = env
        base = env.unwrapped
        self.layout = base.layout
        self.grid: CostGrid = cost_grid(self.layout, config)
        self.step_limit = _step_limit(env)
        self.perfect = perfect  # no imperfections (tests, and a reference in benchmarks)
        self.block_top = STAND_Z + self.layout.block_height
        self.persona = Personality.perfect()
        self.rng = np.random.default_rng(0)
        self.route: Route | None = None
        self.edges: dict[int, float] = {}  # jump segment -> arc length of its block edge
        self.goal = np.zeros(2)
        self.plan_seconds = 0.0  # time spent planning this episode (benchmarks report it)
        self.replans = 0
        self.events: dict[str, int] = {}  # this episode's imperfections and jumps, by kind
        self._reset_state()

    # --- episode ----------------------------------------------------------------------------
    def _reset_state(self) -> None:
        self.t = 0
        self.seg = 0
        self.cmd: float | None = None  # the smoothed rotation-target angle
        self.pause_left = self.walk_left = self.detour_left = self.overshoot_left = 0
        self.detour_total, self.detour_offset = 1, 0.0
        self.look_angle = 0.0
        self.overshoot_angle = 0.0
        self.corner_seen = -1
        self.noise: np.ndarray | None = None
        self.history: list[np.ndarray] = []
        self.stuck_count = 0
        self.unstick_left = 0
        self.unstick_side = 1.0
        self.replan_cooldown = 0

    def reset(self, rng: np.random.Generator) -> None:
        """Start an episode: draw the personality (and this episode's route preferences) from
        ``rng`` and plan from the agent's position to the goal (the env must be reset)."""
        self.rng = rng
        self.persona = Personality.perfect() if self.perfect else Personality.draw(rng)
        self._reset_state()
        self.plan_seconds = 0.0
        self.replans = 0
        self.events = dict.fromkeys(EVENTS, 0)
        self.noise = self.grid.route_noise(rng, self.persona.route_noise)
        base = self.env.unwrapped
        self.goal = np.asarray(base.goal[:2], dtype=np.float64).copy()
        self._plan(np.asarray(base.position, dtype=np.float64), first=True)

    def _level(self, pos: np.ndarray) -> int:
        """On a block top (centre well above standing height, only where blocks are low
        enough to climb) or on the floor."""
        climbable = self.layout.block_height <= JUMPABLE_HEIGHT
        return LOW if climbable and pos[2] > (STAND_Z + self.block_top) / 2 else FLOOR

    def _plan(self, pos: np.ndarray, first: bool = False) -> None:
        """Plan from ``pos`` on its level to the goal with this episode's route noise; fall
        back to the plain shortest route when the noisy one would not fit in the time left."""
        t0 = time.perf_counter()
        level = self._level(pos)
        route = self.grid.plan(pos[:2], self.goal, level, self.noise)
        steps_left = self.step_limit - self.t
        too_long = route is not None and (
            self._steps_needed(route.length) > steps_left - self._reserve()
        )
        if too_long and self.persona.route_noise > 0:
            route = self.grid.plan(pos[:2], self.goal, level, None) or route
        if route is None and level == LOW:  # cannot happen on these maps; be safe anyway
            route = self.grid.plan(pos[:2], self.goal, FLOOR, None)
        if route is None:
            raise RuntimeError(
                f"no route in {self.layout.name} from {pos[:2].round(2)} to {self.goal.round(2)}"
            )
        self.route = route
        self.edges = {j: self._edge_s(j) for j in route.jumps}
        self.seg = 0
        self.corner_seen = -1
        self.history.clear()
        self.replan_cooldown = 5
        if not first:
            self.replans += 1
        self.plan_seconds += time.perf_counter() - t0

    # --- budget -----------------------------------------------------------------------------
    @staticmethod
    def _steps_needed(length: float) -> float:
        """Steps to run ``length`` metres and touch the goal, with a little for the turns."""
        return max(length - GOAL_RADIUS, 0.0) / RUN_STEP * 1.04 + 4.0

    def _reserve(self) -> float:
        return max(8.0, 0.06 * self.step_limit)

    def _slack(self, remaining: float) -> float:
        """Steps to spare at a run for the rest of the route, less a reserve."""
        return self.step_limit - self.t - self._steps_needed(remaining) - self._reserve()

    # --- acting -----------------------------------------------------------------------------
    def act(self, obs: dict) -> np.ndarray:
        """The gamepad for this step: buttons (right, left, forward, backward, run, jump) and
        the rotation target (cos, sin)."""
        pos = np.asarray(obs["achieved_goal"], dtype=np.float64)
        goal = np.asarray(obs["desired_goal"], dtype=np.float64)[:2]
        ob = np.asarray(obs["observation"], dtype=np.float64)
        yaw = float(np.arctan2(ob[1], ob[0]))
        vel = ob[3:6]
        if self.cmd is None:
            self.cmd = yaw
        if self.route is None or not np.allclose(goal, self.goal):
            self.goal = goal.copy()
            self._plan(pos)
        airborne = (
            abs(vel[2]) > 0.3 or min(abs(pos[2] - STAND_Z), abs(pos[2] - self.block_top)) > 0.08
        )
        level = self._level(pos)
        p = pos[:2]
        self.replan_cooldown = max(0, self.replan_cooldown - 1)

        route = self.route
        s, dist, seg = route.project(p, self.seg, self.seg + 4)
        self.seg = seg
        remaining = route.length - s + dist
        to_goal = float(np.linalg.norm(goal - p))
        if not airborne and self.replan_cooldown == 0 and self._strayed(dist, level, seg, s):
            self._plan(pos)
            route = self.route
            s, dist, seg = route.project(p, 0, 4)
            self.seg = seg
            remaining = route.length - s + dist
        self.history.append(p.copy())
        slack = self._slack(remaining)
        free = not self.perfect and to_goal > 4.0 and not airborne
        buttons = np.zeros(6)
        persona, rng = self.persona, self.rng

        # stuck against something: back off a little to the side, then re-plan
        if self.unstick_left > 0:
            self.unstick_left -= 1
            buttons[3] = 1.0
            buttons[0 if self.unstick_side > 0 else 1] = 1.0
            return self._action(buttons, self.cmd)
        if self._stuck():
            self.stuck_count += 1
            self.history.clear()
            if self.stuck_count >= 2:
                self.unstick_left = 3
                self._event("unstick")
                self.unstick_side = 1.0 if rng.random() < 0.5 else -1.0
            self._plan(pos)
            return self._action(buttons, self.cmd)

        # a pause: no buttons, looking around a little
        if self.pause_left > 0:
            self.pause_left -= 1
            self.history.clear()
            self.cmd = self._smooth(self.look_angle, 0.5)
            return self._action(buttons, self.cmd)
        jump_gap = self._next_jump_gap(s, seg)
        calm = free and jump_gap > 5.0 and self.detour_left == 0 and self.overshoot_left == 0
        if calm and rng.random() < persona.pause_rate:
            n = int(rng.integers(persona.pause_len[0], persona.pause_len[1] + 1))
            if slack > n + 2:
                self.pause_left = n - 1
                self._event("pause")
                self.look_angle = yaw + rng.uniform(-1.0, 1.0)
                self.history.clear()
                return self._action(buttons, self.cmd)

        # where to aim: a lookahead point on the route, shortened until the way there is clear
        target = self._lookahead(p, s, level)
        if remaining < persona.lookahead:
            target = goal
        if calm and self.walk_left == 0 and rng.random() < persona.detour_rate:
            n = int(rng.integers(persona.detour_len[0], persona.detour_len[1] + 1))
            if slack > 0.6 * n + 4:
                self.detour_left, self.detour_total = n, n
                self._event("detour")
                side = 1.0 if rng.random() < 0.5 else -1.0
                self.detour_offset = side * rng.uniform(*persona.detour_offset)
        if self.detour_left > 0:
            target = self._detour_target(p, s, target, level)
        aim = float(np.arctan2(target[1] - p[1], target[0] - p[0]))
        aim = self._maybe_overshoot(p, s, seg, aim, level, free, slack)
        if free:
            aim += persona.jitter * rng.standard_normal()
        near_goal = to_goal < 2.5
        alpha = 1.0 if near_goal else persona.smoothing
        self.cmd = self._smooth(aim, alpha)
        err = float(wrap_angle(aim - yaw))

        # move: forward unless turning hard; strafe into the turn; run unless walking
        turning_hard = abs(err) > (np.deg2rad(70.0) if near_goal else persona.turn_in_place)
        buttons[2] = 0.0 if turning_hard and not airborne else 1.0
        if persona.strafe and free and np.deg2rad(35.0) < abs(err) < np.deg2rad(100.0):
            buttons[1 if err > 0 else 0] = 1.0
        if self.walk_left > 0:
            self.walk_left -= 1
        elif calm and rng.random() < persona.walk_rate:
            n = int(rng.integers(persona.walk_len[0], persona.walk_len[1] + 1))
            if slack > n * (RUN_SPEED / WALK_SPEED - 1.0) + 2:
                self.walk_left = n
                self._event("walk")
        walking = self.walk_left > 0 or (near_goal and abs(err) > np.deg2rad(30.0))
        buttons[4] = 0.0 if walking else 1.0

        # jump: onto a low block just ahead, or an idle hop on open floor
        if not airborne and level == FLOOR and self._should_jump(p, yaw, vel, jump_gap):
            buttons[5] = 1.0
            self._event("jump")
        elif (
            calm
            and level == FLOOR
            and min(to_goal, remaining) > HOP_CLEAR_OF_GOAL  # success is checked in 3-D
            and self.grid.low_clear[self.grid.cell(p)] >= 2.5
            and rng.random() < persona.hop_rate
        ):
            buttons[5] = 1.0
            self._event("hop")
        return self._action(buttons, self.cmd)

    def _event(self, kind: str) -> None:
        self.events[kind] = self.events.get(kind, 0) + 1

    def _action(self, buttons: np.ndarray, angle: float) -> np.ndarray:
        self.t += 1
        return np.concatenate([buttons, [np.cos(angle), np.sin(angle)]])

    def _smooth(self, aim: float, alpha: float) -> float:
        """The rotation target follows the aim with lag ``1 - alpha`` (a thumb, not a servo)."""
        return float(wrap_angle(self.cmd + alpha * wrap_angle(aim - self.cmd)))

    # --- route following --------------------------------------------------------------------
    def _lookahead(self, p: np.ndarray, s: float, level: int) -> np.ndarray:
        """The route point ``lookahead`` metres ahead, brought closer until the straight line
        to it is clear of walls (around a wall end the chord to a far point would cut
        through it). Past a jump the aim stays on the route (the jump crosses the edge)."""
        look = self.persona.lookahead
        route = self.route
        for frac in (1.0, 0.7, 0.45):
            q = route.point_at(s + look * frac)
            if self.grid.segment_clear(p, q, None, RADIUS + 0.05):
                return q
        return route.point_at(s + look * 0.25)

    def _detour_target(self, p: np.ndarray, s: float, target: np.ndarray, level: int) -> np.ndarray:
        """The aim pushed sideways (a sine bump over the detour's steps), kept only while the
        way there is clear on the agent's level."""
        k = self.detour_total - self.detour_left
        self.detour_left -= 1
        bump = np.sin(np.pi * (k + 0.5) / self.detour_total)
        ahead = self.route.point_at(s + 2.0) - self.route.point_at(s)
        n = np.linalg.norm(ahead)
        if n < 1e-6:
            return target
        side = np.array([-ahead[1], ahead[0]]) / n
        q = target + side * self.detour_offset * bump
        if self.grid.segment_clear(p, q, level) and self._clear_at(q, level):
            return q
        self.detour_left = 0
        return target

    def _clear_at(self, q: np.ndarray, level: int) -> bool:
        rc = self.grid.cell(q)
        return bool(self.grid.passable[rc] and self.grid.cls[rc] == level)

    def _maybe_overshoot(
        self, p: np.ndarray, s: float, seg: int, aim: float, level: int, free: bool, slack: float
    ) -> float:
        """Near a sharp corner, sometimes keep running straight for a step or few before
        turning (a late turn), when the straight run is clear."""
        if self.overshoot_left > 0:
            self.overshoot_left -= 1
            return self.overshoot_angle
        route = self.route
        v = seg + 1
        if not free or v >= len(route.points) - 1 or v == self.corner_seen:
            return aim
        if route.lengths[v] - s > 1.0:
            return aim
        self.corner_seen = v
        d_in = route.points[v] - route.points[v - 1]
        d_out = route.points[v + 1] - route.points[v]
        turn = abs(wrap_angle(np.arctan2(d_out[1], d_out[0]) - np.arctan2(d_in[1], d_in[0])))
        if turn < np.deg2rad(40.0) or self.rng.random() >= self.persona.overshoot_prob:
            return aim
        n = int(self.rng.integers(self.persona.overshoot_len[0], self.persona.overshoot_len[1] + 1))
        heading = float(np.arctan2(d_in[1], d_in[0]))
        end = p + (n * RUN_STEP + 1.0) * np.array([np.cos(heading), np.sin(heading)])
        if slack < 2 * n + 2 or not self.grid.segment_clear(p, end, level):
            return aim
        self.overshoot_left, self.overshoot_angle = n - 1, heading
        self._event("overshoot")
        return heading

    def _next_jump_gap(self, s: float, seg: int) -> float:
        """Route distance from ``s`` to the next block edge the route jumps onto (inf: none)."""
        route = self.route
        for j in route.jumps:
            if j + 1 < seg:
                continue
            edge = self.edges[j]
            if edge >= s - 1.0:
                return edge - s
        return np.inf

    def _edge_s(self, j: int) -> float:
        """Arc length where jump segment ``j`` enters the block."""
        route = self.route
        a, b = route.points[j], route.points[j + 1]
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / 0.1)))
        for k in range(n + 1):
            q = a + (b - a) * k / n
            if self.grid.level_at(q) == LOW:
                return float(route.lengths[j] + np.linalg.norm(q - a))
        return float(route.lengths[j + 1])

    def _should_jump(self, p: np.ndarray, yaw: float, vel: np.ndarray, gap: float) -> bool:
        """Jump when the route climbs onto a block within this player's jump distance and the
        block is ahead of the heading, or when the block side has stopped the agent."""
        if not np.isfinite(gap) or gap > self.persona.jump_distance + 0.3 or gap < -1.0:
            return False
        heading = np.array([np.cos(yaw), np.sin(yaw)])
        for d in (0.5, 1.0, 1.5, 2.0, 2.5):
            if self.grid.level_at(p + d * heading) == LOW:
                return True
        return bool(np.linalg.norm(vel[:2]) < 1.0)

    def _strayed(self, dist: float, level: int, seg: int, s: float) -> bool:
        """Whether to re-plan: far off the route, or on the wrong level for this stretch (on
        the floor where the route runs over a block, or on a block the route does not use)."""
        route = self.route
        limit = 2.0 + (abs(self.detour_offset) if self.detour_left > 0 else 0.0)
        if dist > limit:
            return True
        seg_levels = route.levels[seg], route.levels[min(seg + 1, len(route.levels) - 1)]
        if level == FLOOR and seg_levels == (LOW, LOW):
            return True
        if level == FLOOR and seg in self.edges and s > self.edges[seg] + 0.8:
            return True  # passed the edge on the floor: the jump was missed
        if level == LOW and seg_levels == (FLOOR, FLOOR):
            return s > route.lengths[seg] + 1.0  # still on the block well past the drop
        return False

    def _stuck(self) -> bool:
        """No headway over the last 15 steps (a wall corner, a block side)."""
        h = self.history
        if len(h) < 15:
            return False
        moved = float(np.linalg.norm(h[-1] - h[-15]))
        return moved < 1.0


__all__ = ["GameExpert", "Personality"]
