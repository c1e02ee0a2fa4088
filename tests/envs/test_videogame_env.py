"""The video-game mazes: layouts against the paper's maps, the MuJoCo scene against the
layouts, and the agent's physics (walls stop it, doors open only where the name says so,
low blocks can be jumped onto and high ones not)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from hispo_pl.envs import make_env
from hispo_pl.envs.videogame import (
    AMAZEVILLE_NAMES,
    SIMPLETOWN_NAMES,
    GameNavEnv,
    LayoutNameError,
    layout,
    maze_xml,
)
from hispo_pl.envs.videogame.env import OBS_DIM, move_velocity, ray_directions
from hispo_pl.envs.videogame.layouts import AMAZEVILLE_MAP

ALL_MAZES = [("amazeville", m) for m in AMAZEVILLE_NAMES] + [
    ("simpletown", m) for m in SIMPLETOWN_NAMES
]

FORWARD, RUN, JUMP = 2, 4, 5


def press(*buttons: int, heading: float = np.pi / 2) -> np.ndarray:
    action = np.zeros(8)
    action[list(buttons)] = 1.0
    action[6:] = np.cos(heading), np.sin(heading)
    return action


def drive(env: GameNavEnv, start, action: np.ndarray, steps: int) -> np.ndarray:
    """Positions over ``steps`` steps of holding ``action`` from ``start``."""
    env.reset(seed=0, options={"start": start, "goal": (-100.0, -100.0)})
    return np.array([env.step(action)[0]["achieved_goal"] for _ in range(steps)])


# --- layouts --------------------------------------------------------------------------


def test_sixteen_mazes_and_their_names():
    assert len(AMAZEVILLE_NAMES) == len(SIMPLETOWN_NAMES) == 8
    for game, maze in ALL_MAZES:
        lay = layout(game, maze)
        assert lay.name == maze
        assert set("".join(lay.grid)) <= {".", "#", "G"}
    with pytest.raises(LayoutNameError, match="known: HOOO"):
        layout("amazeville", "HOOO ")
    with pytest.raises(LayoutNameError, match="known: BASE"):
        layout("simpletown", "XXX")
    with pytest.raises(LayoutNameError, match="unknown game"):
        layout("doom", "E1M1")


@pytest.mark.parametrize("maze", AMAZEVILLE_NAMES)
def test_amazeville_doors_and_blocks_follow_the_name(maze):
    lay = layout("amazeville", maze)
    grid, raw = lay.array(), np.array([list(r) for r in AMAZEVILLE_MAP])
    for door, state in (("a", maze[1]), ("b", maze[3])):
        cells = grid[raw == door]
        assert len(cells) == 6
        assert set(cells) == ({"#"} if state == "X" else {"."})
    assert set(grid[13:17, 13:17].ravel()) == {"."}  # the middle gap is always open
    assert lay.block_height == (3.0 if maze[0] == "H" else 1.0)
    # everything else is the map, except the two L-maze differences
    same = (raw != "a") & (raw != "b")
    diff = np.argwhere(same & (grid != raw))
    if maze[0] == "H":
        assert len(diff) == 0
    else:
        assert {tuple(d) for d in diff} == {(13, 4)} | {(r, 18) for r in range(21, 26)}


@pytest.mark.parametrize("maze", SIMPLETOWN_NAMES)
def test_simpletown_wall_has_doors_where_the_name_says(maze):
    lay = layout("simpletown", maze)
    grid = lay.array()
    assert grid.shape == (30, 30) and lay.size == (30.0, 30.0)
    if maze == "BASE":
        assert set(grid.ravel()) == {"."}
        return
    for row in (14, 15):
        for (c0, c1), state in zip(((3, 7), (13, 17), (23, 27)), maze, strict=True):
            assert set(grid[row, c0:c1]) == ({"."} if state == "O" else {"#"})
        assert (grid[row] == "#").sum() == 30 - 4 * maze.count("O")
    assert set(np.delete(grid, [14, 15], axis=0).ravel()) == {"."}


def test_start_and_goal_points():
    lay = layout("amazeville", "HXOX")
    rng = np.random.default_rng(0)
    pairs = [lay.sample_start_goal(rng) for _ in range(400)]
    starts = {tuple(s) for s, _ in pairs}
    goals = {tuple(g) for _, g in pairs}
    assert starts == set(lay.starts) and len(starts) == 3
    assert goals == set(lay.goals) and len(goals) == 6
    assert all(y < 6 for _, y in starts)  # along the bottom edge
    assert all(y > 30 for _, y in goals)  # in the upper half
    grid = lay.array()
    for x, y in (*lay.starts, *lay.goals):
        assert grid[lay.cell_of(x, y)] == "."
    town = layout("simpletown", "OXO")
    s, g = np.array([town.sample_start_goal(rng) for _ in range(200)]).transpose(1, 0, 2)
    assert np.allclose(s[:, 1], 1.5) and np.allclose(g[:, 1], 28.5)
    assert 1.5 <= s[:, 0].min() < 5 and 25 < s[:, 0].max() <= 28.5


# --- the MuJoCo scene matches the layout -----------------------------------------------


@pytest.mark.parametrize("game, maze", ALL_MAZES)
def test_scene_heights_match_the_map_at_every_cell(game, maze):
    """A ray dropped on every cell centre hits the floor, a wall (3 m) or a block at the
    height the layout gives: the scene is the map, cell by cell."""
    lay = layout(game, maze)
    model = mujoco.MjModel.from_xml_string(maze_xml(lay))
    data = mujoco.MjData(model)
    data.qpos[:3] = (-50.0, -50.0, 0.9)  # the agent out of the way
    mujoco.mj_forward(model, data)
    geomid = np.zeros(1, dtype=np.int32)
    heights = lay.heights()
    rows, cols = heights.shape
    for r in range(rows):
        for c in range(cols):
            x, y = lay.cell_centre(r, c)
            dist = mujoco.mj_ray(model, data, np.array([x, y, 10.0]), np.array([0, 0, -1.0]),
                                 None, 1, -1, geomid)  # fmt: skip
            assert 10.0 - dist == pytest.approx(heights[r, c], abs=1e-6), (r, c)


def test_scene_is_enclosed_and_leaves_no_files(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    env = make_env("amazeville-HOOO")
    pos = drive(env.unwrapped, (3.0, 3.0), press(FORWARD, RUN, heading=-np.pi * 3 / 4), 30)
    assert pos[:, 0].min() > 0.3 and pos[:, 1].min() > 0.3  # the border wall holds it
    assert list(tmp_path.iterdir()) == []


# --- physics ---------------------------------------------------------------------------


def test_walk_run_and_turn_speeds():
    env = GameNavEnv("simpletown", "BASE")
    walk = drive(env, (15.0, 2.0), press(FORWARD), 20)
    run = drive(env, (15.0, 2.0), press(FORWARD, RUN), 20)
    assert np.diff(walk[5:, 1]).mean() * 10 == pytest.approx(4.0, rel=0.05)
    assert np.diff(run[5:, 1]).mean() * 10 == pytest.approx(6.0, rel=0.05)
    assert np.allclose(walk[:, 2], 0.9, atol=0.02)  # stays on the floor
    env.reset(seed=0, options={"start": (15.0, 15.0), "goal": (0.0, 0.0)})
    yaws = [np.arctan2(*env.step(press(heading=0.0))[0]["observation"][1::-1]) for _ in range(4)]
    assert np.rad2deg(yaws) == pytest.approx([54, 18, 0, 0], abs=1e-6)  # 36° per step


def test_move_buttons_are_relative_to_the_heading():
    east = 0.0
    assert move_velocity(np.array([0, 0, 1, 0, 0, 0.0]), east) == pytest.approx([4, 0])
    assert move_velocity(np.array([1, 0, 0, 0, 0, 0.0]), east) == pytest.approx([0, -4])
    assert move_velocity(np.array([0, 1, 0, 0, 1, 0.0]), east) == pytest.approx([0, 6])
    assert move_velocity(np.array([0, 0, 1, 1, 0, 0.0]), east) == pytest.approx([0, 0])
    diag = move_velocity(np.array([0, 1, 1, 0, 0, 0.0]), np.pi / 2)
    assert np.linalg.norm(diag) == pytest.approx(4.0) and diag == pytest.approx(
        [-2.828, 2.828], abs=1e-3
    )


def test_observation_layout_and_depth():
    env = GameNavEnv("simpletown", "OXO")
    obs, info = env.reset(seed=0, options={"start": (15.0, 10.0), "goal": (15.0, 28.5)})
    assert obs["observation"].shape == (OBS_DIM,) == (127,)
    assert obs["achieved_goal"] == pytest.approx([15, 10, 0.9])
    assert obs["desired_goal"] == pytest.approx([15, 28.5, 0.9])
    assert obs["observation"][:3] == pytest.approx([0, 1, 0], abs=1e-9)  # facing +y
    depth = obs["observation"][6:].reshape(11, 11)
    # the centre ray (level, straight ahead) meets the closed middle door 4 m ahead (wall at
    # y = 14, eye at y = 10), over the 20 m range
    assert depth[5, 5] == pytest.approx(4.0 / 20.0, abs=1e-6)
    assert (depth[-1] < depth[5]).all()  # the lowest row sees the floor, closer
    assert info["floor_contact"] and not info["wall_contact"] and not info["success"]
    assert set(info) >= {"goal_contact", "timestep", "up"}
    unit = ray_directions(0.3)
    assert np.linalg.norm(unit, axis=1) == pytest.approx(np.ones(121))


def test_walls_stop_the_agent_and_register_contact():
    env = GameNavEnv("simpletown", "XOX")
    pos = drive(env, (5.0, 10.0), press(FORWARD, RUN), 20)  # at the closed left door
    assert 13.0 < pos[-1, 1] < 14.0
    assert env._info()["wall_contact"]
    pos = drive(env, (5.0, 10.0), press(FORWARD, RUN, JUMP), 30)  # cannot jump a 3 m wall
    assert pos[:, 1].max() < 14.0 and pos[:, 2].max() > 2.0


@pytest.mark.parametrize("maze", SIMPLETOWN_NAMES)
def test_simpletown_doors_pass_only_when_open(maze):
    env = GameNavEnv("simpletown", maze)
    for x, state in zip((5.0, 15.0, 25.0), "OOO" if maze == "BASE" else maze, strict=True):
        pos = drive(env, (x, 10.0), press(FORWARD, RUN), 20)
        assert (pos[-1, 1] > 18.0) == (state == "O"), (maze, x)


@pytest.mark.parametrize("maze", AMAZEVILLE_NAMES)
def test_amazeville_doors_and_blocks_by_driving(maze):
    env = GameNavEnv("amazeville", maze)
    # the doors (rows 14-15 = y 28..32) seen from below: left x 10..16, right x 44..50; the
    # middle gap x 26..34 is always open
    for x, state in ((13.0, maze[1]), (47.0, maze[3]), (30.0, "O")):
        pos = drive(env, (x, 24.0), press(FORWARD, RUN), 25)
        assert (pos[-1, 1] > 33.0) == (state == "O"), (maze, x)
    # the bottom-left block bar (y 8..18, x 8..34) from below: walking never climbs it;
    # jumping onto it works only when it is low (1 m)
    pos = drive(env, (20.0, 5.0), press(FORWARD, RUN), 20)
    assert pos[-1, 1] < 8.0
    pos = drive(env, (20.0, 5.0), press(FORWARD, RUN, JUMP), 25)
    if maze[0] == "L":
        assert pos[-1, 1] > 12.0 and pos[:, 2].max() > 1.9  # on top of the block
    else:
        assert pos[-1, 1] < 8.0
