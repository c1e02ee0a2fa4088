"""The game mazes through the whole pipeline: planner data in Minari, HBC with a gamepad head
from the CLI, evaluation of its checkpoint, and a short HiSPO stream over two mazes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from hispo_pl.cli import main
from hispo_pl.data.datasets import dataset_stats, load_episodes, local_dataset_id
from hispo_pl.data.generation import generate_dataset

ROOT = Path(__file__).resolve().parents[2]
EPISODES = 4


@pytest.fixture(scope="module")
def town_data(minari_home):
    for maze in ("OXO", "BASE"):
        generate_dataset(f"simpletown-{maze}", episodes=EPISODES, progress=False)
    return load_episodes(f"simpletown-OXO[{EPISODES}]")


def test_planner_dataset(town_data):
    data = town_data
    assert data.n_episodes == EPISODES
    assert data.observations.shape[1] == 127 and data.positions.shape[1] == 3
    buttons = data.actions[data.sample_index, :6]
    assert set(np.unique(buttons)) <= {0.0, 1.0}
    rotation = data.actions[data.sample_index, 6:]
    assert np.allclose(np.linalg.norm(rotation, axis=1), 1.0, atol=1e-5)
    # every episode ends at its goal: the last position within 1 m of the desired goal
    ends = np.unique(data.episode_end)
    assert (data.positions[ends, 1] > 26.5).all()  # the goals lie along the top side
    stats = dataset_stats(local_dataset_id("simpletown-OXO"))
    assert "Planner-generated, not human play" in stats["description"]
    assert f"Expert success: {EPISODES}/{EPISODES}" in stats["description"]


def _fit_args(save_dir: Path, configs: list[str], *extra: str) -> list[str]:
    return [
        "fit",
        *(arg for config in configs for arg in ("--config", str(ROOT / "configs" / config))),
        "--trainer.max_steps", "6",
        "--data.batch_size", "64",
        "--trainer.logger.init_args.save_dir", str(save_dir),
        "--trainer.enable_progress_bar", "false",
        *extra,
    ]  # fmt: skip


def test_hbc_fit_and_evaluate_with_buttons(town_data, tmp_path, capsys):
    args = _fit_args(
        tmp_path,
        ["hbc/simpletown.yaml"],
        "--data.task", f"simpletown-OXO[{EPISODES}]",
        "--trainer.callbacks.init_args.episodes", "2",
    )  # fmt: skip
    assert main(args) == 0
    assert f"HBC on simpletown-OXO-N[{EPISODES}]: success" in capsys.readouterr().out
    (ckpt,) = tmp_path.rglob("*.ckpt")
    checkpoint = torch.load(ckpt, map_location="cpu", weights_only=True)
    assert checkpoint["hyper_parameters"]["backbone"]["binary_actions"] == 6  # linked from the data
    assert checkpoint["hyper_parameters"]["goal_dim"] == 3
    assert main(["evaluate", "--ckpt", str(ckpt), "--task", "simpletown-BASE", "--episodes", "2",
                 "--json"]) == 0  # fmt: skip
    report = json.loads(capsys.readouterr().out)
    assert report["task"] == "simpletown-BASE-N[250]" and 0 < report["episode_length"] <= 100
    # a checkpoint of the gamepad cannot act on a maze family with other controls
    assert main(["evaluate", "--ckpt", str(ckpt), "--task", "pointmaze-umaze"]) == 2
    assert "trained with obs_dim 127, but pointmaze-umaze-N[500] has obs_dim 4" in (
        capsys.readouterr().err
    )


@pytest.mark.e2e
def test_hispo_stream_over_two_mazes(town_data, tmp_path, capsys):
    stream = [f"simpletown-OXO[{EPISODES}]", f"simpletown-BASE[{EPISODES}]"]
    args = _fit_args(
        tmp_path,
        ["streams/simpletown-1.yaml", "methods/hispo.yaml"],
        "--data.stream", json.dumps(stream),
        "--trainer.callbacks.init_args.episodes", "2",
    )  # fmt: skip
    assert main(args) == 0
    results = json.loads((tmp_path / "simpletown-1" / "seed0" / "results.json").read_text())
    assert len(results["R"]) == 2 and all(len(row) == 2 for row in results["R"])
    assert set(results["anchors"]) == {"high", "low"}
    assert all(1 <= n <= 2 for n in results["anchors"].values())
