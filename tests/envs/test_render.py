"""``hispo-pl render``: every maze drawn from its map, dataset and policy paths overlaid."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import pytest
from matplotlib.image import imread
from matplotlib.patches import Rectangle

from hispo_pl.cli import main
from hispo_pl.cli_verbs import expand_render_tasks
from hispo_pl.config import BackboneConfig
from hispo_pl.envs.drawing import cell_rectangles
from hispo_pl.envs.videogame.layouts import layout
from hispo_pl.render import (
    Overlay,
    dataset_paths,
    draw_paths,
    maze_figure,
    rollout_paths,
)
from hispo_pl.task_families import FAMILIES
from hispo_pl.tasks import parse_task

GAME_TASKS = [f"{g}-{m}" for g in ("amazeville", "simpletown") for m in FAMILIES[g].mazes]
DRAWN_AS = {"wall": "#", "door-closed": "#", "block-high": "G", "block-low": "G"}


def _patches(ax, gid: str) -> list[Rectangle]:
    return [p for p in ax.patches if p.get_gid() == gid]


def _cells(ax, gid: str, shape: tuple[int, int], cell: float, origin=(0.0, 0.0)) -> np.ndarray:
    """How many ``gid`` rectangles cover each cell (rows down the map): the drawing read
    back as a map."""
    rows = shape[0]
    count = np.zeros(shape, dtype=int)
    for p in _patches(ax, gid):
        c0, bottom = round((p.get_x() - origin[0]) / cell), round((p.get_y() - origin[1]) / cell)
        c1, top = c0 + round(p.get_width() / cell), bottom + round(p.get_height() / cell)
        count[rows - top : rows - bottom, c0:c1] += 1
    return count


def _raster(ax, shape: tuple[int, int], cell: float, origin=(0.0, 0.0)) -> np.ndarray:
    """The character grid the drawn walls and blocks describe; no cell may be drawn twice."""
    grid = np.full(shape, ".")
    total = np.zeros(shape, dtype=int)
    for gid, char in DRAWN_AS.items():
        count = _cells(ax, gid, shape, cell, origin)
        grid[count > 0] = char
        total += count
    assert total.max() <= 1, "overlapping patches"
    return grid


def _area(ax, gids: tuple[str, ...]) -> float:
    return sum(p.get_width() * p.get_height() for g in gids for p in _patches(ax, g))


def test_cell_rectangles_cover_a_mask_exactly_once():
    rng = np.random.default_rng(0)
    for _ in range(50):
        mask = rng.random((7, 9)) < 0.5
        cover = np.zeros(mask.shape, dtype=int)
        for r0, r1, c0, c1 in cell_rectangles(mask):
            cover[r0:r1, c0:c1] += 1
        assert np.array_equal(cover, mask)
    # a solid block is one rectangle, not one per row
    assert cell_rectangles(np.ones((5, 4), dtype=bool)) == [(0, 5, 0, 4)]


@pytest.mark.parametrize("spec", GAME_TASKS)
def test_every_game_maze_is_drawn_from_its_map(spec):
    task = parse_task(spec)
    lay = layout(task.family, task.maze)
    ax = maze_figure([spec]).axes[0]
    assert ax.get_title() == spec
    assert ax.get_xlim() == (0.0, lay.size[0]) and ax.get_ylim() == (0.0, lay.size[1])
    # the rectangles, read back as a map, are the layout's map
    assert np.array_equal(_raster(ax, lay.shape, lay.cell), lay.array())
    grid = lay.array()
    assert _area(ax, ("wall", "door-closed")) == pytest.approx((grid == "#").sum() * lay.cell**2)
    # high blocks for H mazes (3 m), low ones for L mazes (1 m); SimpleTown has none
    high, low = _area(ax, ("block-high",)), _area(ax, ("block-low",))
    blocks = (grid == "G").sum() * lay.cell**2
    assert (high, low) == ((0.0, blocks) if task.maze.startswith("L") else (blocks, 0.0))
    # start and goal marks sit on the layout's points (or segments' ends)
    marks = {line.get_gid(): line.get_xydata() for line in ax.lines}
    kind = "segment" if lay.segments else ""
    starts = marks["start-segment" if kind else "starts"]
    goals = marks["goal-segment" if kind else "goals"]
    assert np.allclose(starts, lay.starts) and np.allclose(goals, lay.goals)


@pytest.mark.parametrize(
    ("spec", "closed", "opened"),
    [
        ("amazeville-HXOO", (5, 8), (22, 25)),  # left door closed, right one open
        ("amazeville-LOOX", (22, 25), (5, 8)),
        ("simpletown-OXO", (13, 17), (3, 7)),  # middle closed; left (and right) open
        ("simpletown-XOX", (3, 7), (13, 17)),
    ],
)
def test_doors_are_drawn_closed_or_open(spec, closed, opened):
    task = parse_task(spec)
    lay = layout(task.family, task.maze)
    ax = maze_figure([spec]).axes[0]
    rows = lay.shape[0]

    def cells(gid: str) -> set[tuple[int, int]]:
        return {(int(r), int(c)) for r, c in np.argwhere(_cells(ax, gid, lay.shape, lay.cell))}

    door_rows = (14, 15)  # both games' door rows
    assert {(r, c) for r in door_rows for c in range(*closed)} <= cells("door-closed")
    assert {(r, c) for r in door_rows for c in range(*opened)} <= cells("door-open")
    assert not cells("door-open") & {(r, c) for r in range(rows) for c in range(*closed)}


def test_all_sixteen_game_mazes_in_one_figure():
    fig = maze_figure(GAME_TASKS)
    assert len(fig.axes) == 16
    assert [ax.get_title() for ax in fig.axes] == GAME_TASKS
    labels = {t.get_text() for t in fig.legends[0].get_texts()}
    assert {"wall", "closed door", "open door", "high block (3 m)"} <= labels


def test_pointmaze_walls_are_its_maze_map():
    from hispo_pl.envs import make_env
    from hispo_pl.envs.mazes import maze_array

    env = make_env("pointmaze-medium")
    grid, size = maze_array(env), env.unwrapped.maze.maze_size_scaling
    env.close()
    ax = maze_figure(["pointmaze-medium"]).axes[0]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert (x1 - x0, y1 - y0) == pytest.approx((grid.shape[1] * size, grid.shape[0] * size))
    drawn = _raster(ax, grid.shape, size, origin=(x0, y0))
    assert np.array_equal(drawn == "#", grid == 1)


def test_dataset_paths_are_the_stored_episodes(tiny_umaze):
    paths = dataset_paths("pointmaze-umaze", 4)
    ends = np.unique(tiny_umaze.episode_end)
    assert len(paths) == 4
    assert [len(p) for p in paths] == list(np.diff(np.concatenate([[-1], ends[:4]])))
    assert np.array_equal(paths[1], tiny_umaze.positions[ends[0] + 1 : ends[1] + 1])
    ax = maze_figure(["pointmaze-umaze"], [Overlay(paths)]).axes[0]
    lines = [line for line in ax.lines if line.get_gid() == "path"]
    assert len(lines) == 4 and all(line.get_linestyle() == "-" for line in lines)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    xy = np.concatenate(paths)
    assert (x0 < xy[:, 0]).all() and (xy[:, 0] < x1).all()
    assert (y0 < xy[:, 1]).all() and (xy[:, 1] < y1).all()


def test_failed_episodes_are_red_and_dashed():
    from matplotlib.figure import Figure

    ax = Figure().subplots()
    paths = [np.array([[0.0, 0.0], [1.0, 1.0]]), np.array([[0.0, 1.0], [1.0, 0.0]])]
    success, failure = draw_paths(ax, paths, successes=np.array([True, False]))
    assert success.get_linestyle() == "-" and failure.get_linestyle() == "--"
    assert failure.get_color() == "#d62020" != success.get_color()


def test_game_rollouts_are_drawn_in_world_coordinates():
    import torch

    def forward(observation, position, goal, velocity=None):  # press "forward": walk up the map
        action = torch.zeros(len(observation), 8)
        action[:, 2] = 1.0
        return action

    overlay = rollout_paths("simpletown-BASE", forward, episodes=2, seed=0)
    assert len(overlay.paths) == 2 and overlay.successes.shape == (2,)
    for path in overlay.paths:
        assert path.shape[1] == 3 and path[-1, 1] > path[0, 1] + 10  # metres up the map
    ax = maze_figure(["simpletown-BASE"], [overlay]).axes[0]
    assert len([line for line in ax.lines if line.get_gid() == "path"]) == 2


def test_family_names_stand_for_all_their_mazes():
    tasks = expand_render_tasks(["amazeville", "pointmaze-umaze-PO"])
    assert [t.maze for t in tasks] == [*FAMILIES["amazeville"].mazes, "umaze"]
    assert tasks[-1].variant == "PO"


def _tiny_checkpoint(path: Path) -> Path:
    from hispo_pl.modules.hbc import HBC

    trainer = L.Trainer(logger=False, enable_checkpointing=False, accelerator="cpu")
    trainer.strategy.connect(
        HBC(obs_dim=4, action_dim=2, backbone=BackboneConfig(high_hidden=8, low_hidden=16))
    )
    trainer.save_checkpoint(path)
    return path


def test_cli_draws_mazes_dataset_and_policy(tiny_umaze, tmp_path, capsys):
    out = tmp_path / "mazes.png"
    assert main(["render", "amazeville", "simpletown", "--out", str(out)]) == 0
    assert f"16 maze(s): {out}" in capsys.readouterr().out
    height, width, _ = imread(out).shape
    assert 0.8 < height / width < 1.25  # a 4 × 4 grid of square panels

    data = tmp_path / "pics" / "data.png"  # the folder is made
    assert (
        main(["render", "pointmaze-umaze", "--dataset", "--episodes", "3", "--out", str(data)]) == 0
    )
    assert f"with 3 paths: {data}" in capsys.readouterr().out and data.exists()

    ckpt = _tiny_checkpoint(tmp_path / "m.ckpt")
    policy = tmp_path / "policy.png"
    args = ["render", "pointmaze-umaze", "--ckpt", str(ckpt), "--episodes", "3"]
    assert main([*args, "--as-task", "1", "--out", str(policy)]) == 0
    printed = capsys.readouterr().out
    assert "with 3 paths (" in printed and "reached their goal" in printed and policy.exists()


def test_cli_names_the_command_for_a_missing_dataset(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "empty"))
    out = tmp_path / "x.png"
    assert main(["render", "amazeville-HOOO", "--dataset", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "hispo-pl data generate amazeville-HOOO" in err and not out.exists()


def test_cli_rejects_a_checkpoint_for_another_agent(tmp_path, capsys):
    ckpt = _tiny_checkpoint(tmp_path / "m.ckpt")  # a PointMaze policy: 4 observation values
    assert (
        main(["render", "amazeville-HOOO", "--ckpt", str(ckpt), "--out", str(tmp_path / "x.png")])
        == 2
    )
    assert "obs_dim 4" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--dataset", "--ckpt", "m.ckpt"], "pick one"),
        (["--as-task", "2"], "needs --ckpt"),
        (["--ckpt", "nope.ckpt"], "no checkpoint at"),
    ],
)
def test_cli_rejects_contradictory_sources(extra, message, tmp_path, capsys):
    assert main(["render", "simpletown-BASE", "--out", str(tmp_path / "x.png"), *extra]) == 2
    assert message in capsys.readouterr().err
