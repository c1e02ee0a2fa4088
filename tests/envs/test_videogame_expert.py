"""The video-game demonstration expert: A* routes over the mazes and the gamepad player."""

from __future__ import annotations

import itertools

import mujoco
import numpy as np
import pytest

from hispo_pl.envs import make_env
from hispo_pl.envs.videogame.env import GameNavEnv
from hispo_pl.envs.videogame.expert import EVENTS, GameExpert
from hispo_pl.envs.videogame.layouts import (
    AMAZEVILLE_NAMES,
    SIMPLETOWN_DOORS,
    SIMPLETOWN_NAMES,
    SIMPLETOWN_WALL_ROWS,
    layout,
)
from hispo_pl.envs.videogame.planner import AGENT_RADIUS, FLOOR, LOW, Route, cost_grid

DOOR_CELLS = {"a": [(r, c) for r in (14, 15) for c in (5, 6, 7)],
              "b": [(r, c) for r in (14, 15) for c in (22, 23, 24)]}  # fmt: skip


def samples(route: Route, step: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` metres along a route, and the level of the segment each is on
    (a jump segment counts as both levels: -1)."""
    pts, lv = [], []
    for i in range(len(route.points) - 1):
        a, b = route.points[i], route.points[i + 1]
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        pts.append(a + t * (b - a))
        same = route.levels[i] == route.levels[i + 1]
        lv.append(np.full(n, route.levels[i] if same else -1))
    return np.concatenate(pts), np.concatenate(lv)


def layout_cells(lay, pts: np.ndarray) -> set[tuple[int, int]]:
    return {lay.cell_of(x, y) for x, y in pts}


def check_route(lay, route: Route, start, goal) -> np.ndarray:
    """A route starts and ends at the requested points, never enters a wall or a high block,
    keeps the capsule clear of walls, and is on a block top only where the block is low."""
    assert route is not None, f"no route {start} -> {goal} in {lay.name}"
    np.testing.assert_allclose(route.points[0], start)
    np.testing.assert_allclose(route.points[-1], goal)
    pts, lv = samples(route)
    grid = cost_grid(lay)
    chars = np.array([lay.grid[r][c] for r, c in (lay.cell_of(x, y) for x, y in pts)])
    assert not np.any(chars == "#")
    if lay.block_height > 1.5:
        assert not np.any(chars == "G"), "a high block was crossed"
    else:  # on a low block only on a block-top segment or the jump onto it
        assert np.all(lv[chars == "G"] != FLOOR)
    assert np.all(grid.clearance_at(pts, "wall") >= AGENT_RADIUS)
    return pts


@pytest.mark.parametrize("maze", AMAZEVILLE_NAMES)
def test_astar_finds_every_amazeville_route(maze):
    lay = layout("amazeville", maze)
    grid = cost_grid(lay)
    for start, goal in itertools.product(lay.starts, lay.goals):
        route = grid.plan(np.array(start), np.array(goal))
        pts = check_route(lay, route, start, goal)
        if maze[0] == "H":
            assert route.jumps == ()
            assert np.all(route.levels == FLOOR)
        # no point of a route is farther from the previous than one straight segment allows
        assert route.length >= np.linalg.norm(np.subtract(goal, start)) - 1e-9
        assert len(pts) > 1


@pytest.mark.parametrize("maze", SIMPLETOWN_NAMES)
def test_astar_simpletown_routes_go_through_open_doors(maze):
    lay = layout("simpletown", maze)
    grid = cost_grid(lay)
    rng = np.random.default_rng(0)
    rows = lay.shape[0]
    wall_y = (
        (rows - max(SIMPLETOWN_WALL_ROWS) - 1) * lay.cell,
        (rows - min(SIMPLETOWN_WALL_ROWS)) * lay.cell,
    )
    open_doors = (
        []
        if maze == "BASE"
        else [d for d, s in zip(SIMPLETOWN_DOORS, maze, strict=True) if s == "O"]
    )
    used = set()
    for _ in range(12):
        start, goal = lay.sample_start_goal(rng)
        route = grid.plan(start, goal)
        pts = check_route(lay, route, start, goal)
        if maze == "BASE":
            continue
        crossing = pts[(pts[:, 1] >= wall_y[0]) & (pts[:, 1] <= wall_y[1])]
        assert len(crossing) > 0
        for door in open_doors:
            if np.all((crossing[:, 0] > door[0]) & (crossing[:, 0] < door[1])):
                used.add(door)
                break
        else:
            raise AssertionError(f"{maze}: a route crosses the wall outside an open door")
    assert bool(used) == (maze != "BASE")


def test_closed_doors_are_walls_and_never_crossed():
    closed = layout("amazeville", "HXOX")
    assert all(closed.grid[r][c] == "#" for cells in DOOR_CELLS.values() for r, c in cells)
    opened = layout("amazeville", "HOOO")
    assert all(opened.grid[r][c] == "." for cells in DOOR_CELLS.values() for r, c in cells)
    crossed = {"HXOX": set(), "HOOO": set()}
    for lay in (closed, opened):
        grid = cost_grid(lay)
        for start, goal in itertools.product(lay.starts, lay.goals):
            cells = layout_cells(lay, samples(grid.plan(np.array(start), np.array(goal)))[0])
            for door, door_cells in DOOR_CELLS.items():
                if cells & set(door_cells):
                    crossed[lay.name].add(door)
    assert crossed["HXOX"] == set()
    assert crossed["HOOO"] == {"a", "b"}  # the open doors are used when they are shorter


def test_low_blocks_are_jumped_when_that_is_shorter():
    start, goal = np.array([31.0, 3.0]), np.array([35.0, 55.0])  # straight over the block band
    low = cost_grid(layout("amazeville", "LOOO")).plan(start, goal)
    high = cost_grid(layout("amazeville", "HOOO")).plan(start, goal)
    assert len(low.jumps) >= 1
    j = low.jumps[0]
    assert low.levels[j] == FLOOR and low.levels[j + 1] == LOW
    assert np.any(samples(low)[1] == LOW)
    assert high.jumps == () and low.length < high.length - 5.0
    # the run-up is kept: the point before the jump lies on the floor, a metre or more away
    grid = cost_grid(layout("amazeville", "LOOO"))
    assert grid.level_at(low.points[j]) == FLOOR
    assert grid.low_clear[grid.cell(low.points[j])] >= 1.0


def test_route_noise_varies_the_route_but_stays_admissible():
    lay = layout("simpletown", "OOO")
    grid = cost_grid(lay)
    start, goal = np.array([10.0, 1.5]), np.array([10.0, 28.5])  # left and middle doors tie
    doors = set()
    for seed in range(12):
        noise = grid.route_noise(np.random.default_rng(seed), 0.4)
        assert noise.min() >= 1.0 and noise.max() <= 1.4
        route = grid.plan(start, goal, noise=noise)
        check_route(lay, route, start, goal)
        mid = route.point_at(route.length / 2)
        doors.add(int(mid[0] > 10.0))
    assert doors == {0, 1}
    a, b = grid.plan(start, goal), grid.plan(start, goal)
    np.testing.assert_array_equal(a.points, b.points)


def run_episode(task: str, seed: int, start=None, goal=None, teleport=None):
    env = make_env(task)
    expert = GameExpert(env)
    rng = np.random.default_rng(seed)
    s, g = env.unwrapped.layout.sample_start_goal(rng)
    start = s if start is None else start
    goal = g if goal is None else goal
    obs, _ = env.reset(seed=seed, options={"start": start, "goal": goal})
    expert.reset(rng)
    actions, zs = [], []
    for t in range(env.spec.max_episode_steps):
        if teleport is not None and t == teleport[0]:
            env.unwrapped.data.qpos[:2] = teleport[1]
            mujoco.mj_forward(env.unwrapped.model, env.unwrapped.data)
            obs = env.unwrapped._obs()
        action = expert.act(obs)
        actions.append(action)
        obs, _, terminated, truncated, info = env.step(action)
        zs.append(obs["achieved_goal"][2])
        if terminated or truncated:
            break
    return bool(info["success"]), np.array(actions), np.array(zs), expert


def test_expert_interface_and_action_format():
    assert GameExpert.name == "videogame-astar-gamepad"
    assert "not human" in GameExpert.description and GameExpert.action_noise == 0.0
    _, actions, _, _ = run_episode("simpletown-OXO", seed=1)
    assert actions.shape[1] == 8
    assert np.all((actions[:, :6] == 0.0) | (actions[:, :6] == 1.0))
    np.testing.assert_allclose(np.linalg.norm(actions[:, 6:], axis=1), 1.0, atol=1e-9)


def test_expert_is_reproducible():
    """Exact: the same seed twice in one process, the same simulator."""
    a = run_episode("amazeville-LOOX", seed=4)[1]
    b = run_episode("amazeville-LOOX", seed=4)[1]
    c = run_episode("amazeville-LOOX", seed=5)[1]
    np.testing.assert_array_equal(a, b)
    assert len(a) != len(c) or not np.array_equal(a, c)


@pytest.mark.parametrize("seed", range(3))
def test_expert_reaches_amazeville_goals(seed):
    ok, _, _, _ = run_episode("amazeville-HXOO", seed=seed)
    assert ok


def test_expert_jumps_onto_low_blocks():
    ok, actions, zs, expert = run_episode(
        "amazeville-LOOO", seed=0, start=(31.0, 3.0), goal=(35.0, 55.0)
    )
    assert ok
    assert expert.events["jump"] >= 1 and actions[:, 5].sum() >= 1
    assert zs.max() > 1.7  # stood on a 1 m block (centre 1.9 m up)


@pytest.mark.parametrize(
    "start, goal", [(None, None), ((1.5, 1.5), (1.5, 28.5)), ((28.5, 1.5), (2.0, 28.5))]
)
def test_expert_reaches_simpletown_goals_within_100_steps(start, goal):
    ok, actions, _, _ = run_episode("simpletown-XXO", seed=2, start=start, goal=goal)
    assert ok and len(actions) <= 100


def test_expert_replans_when_moved_off_its_route():
    ok, _, _, expert = run_episode("amazeville-HOOO", seed=3, teleport=(15, (55.0, 45.0)))
    assert ok
    assert expert.replans >= 1


def test_expert_shows_human_like_imperfections():
    """Over a few episodes the player pauses (no buttons), walks, strafes, detours or
    overshoots, and hops; the perfect player (the same planner, no habits) does none."""
    env = GameNavEnv("amazeville", "HOOO")  # unwrapped: the layout's step limit applies
    events, actions = {}, []
    for perfect in (False, True):
        expert = GameExpert(env, perfect=perfect)
        assert expert.step_limit == 300
        total = dict.fromkeys(EVENTS, 0)
        acts = []
        for k in range(4):
            rng = np.random.default_rng([11, k])
            start, goal = env.layout.sample_start_goal(rng)
            obs, _ = env.reset(options={"start": start, "goal": goal})
            expert.reset(rng)
            for _ in range(expert.step_limit):
                acts.append(expert.act(obs))
                obs, _, terminated, _, _ = env.step(acts[-1])
                if terminated:
                    break
            assert terminated
            for kind in EVENTS:
                total[kind] += expert.events[kind]
        events[perfect] = total
        actions.append(np.array(acts))
    imperfect, perfect = actions
    assert events[False]["pause"] >= 1 and events[False]["walk"] >= 1
    assert events[False]["detour"] + events[False]["overshoot"] >= 1
    assert events[False]["hop"] >= 1
    assert np.any(imperfect[:, :6].sum(1) == 0)  # paused
    assert np.any((imperfect[:, 2] == 1) & (imperfect[:, 4] == 0))  # walked
    assert np.any(imperfect[:, :2].sum(1) > 0)  # strafed
    assert sum(events[True].values()) == 0
    assert np.all(perfect[:, 4] == 1) and not np.any(perfect[:, :2].sum(1) > 0)


def test_expert_backs_off_and_replans_when_stuck():
    """Observations that show no headway (pressed into something) make the player re-plan,
    and the second time back off (backward plus a side button) before going on."""
    env = make_env("amazeville-HOOO")
    expert = GameExpert(env)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(options={"start": (31.0, 3.0), "goal": (47.0, 37.0)})
    expert.reset(rng)
    actions = [expert.act(obs) for _ in range(80)]  # the env is never stepped
    assert expert.replans >= 2 and expert.events["unstick"] >= 1
    backing = [a for a in actions if a[3] == 1.0]
    assert backing and all(a[0] + a[1] == 1.0 and a[2] == 0.0 for a in backing)
