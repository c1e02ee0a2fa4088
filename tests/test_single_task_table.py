"""The single-task study runs ``hispo-pl fit`` itself: its fit command is the product's CLI with
the setting's overrides, a finished run's ``result.json`` is what the table reads, and the
table rebuilds from committed files alone."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

from hispo_pl.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location(
    "single_task_table", ROOT / "benchmarks/single_task_table.py"
)
study = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = study  # its dataclasses look their module up
spec.loader.exec_module(study)

pytestmark = pytest.mark.usefixtures("one_thread")

CONFIG = str(ROOT / "configs/hbc/pointmaze-{maze}.yaml")


def test_settings_are_named_overrides_of_one_config():
    settings = study.parse_settings([CONFIG], ["a=--data.goal_horizon episode", "b="])
    assert [(s.name, s.overrides) for s in settings] == [
        ("a", ("--data.goal_horizon", "episode")),
        ("b", ()),
    ]
    assert settings[0].config_for("pointmaze-large-N").name == "pointmaze-large.yaml"
    with pytest.raises(SystemExit, match="NAME="):
        study.parse_settings([CONFIG], ["--data.goal_horizon episode"])
    with pytest.raises(SystemExit, match="exactly one --config"):
        study.parse_settings([CONFIG, CONFIG], ["a="])


def test_a_run_is_the_products_fit_and_its_result_is_read(tiny_umaze, tmp_path):
    (setting,) = study.parse_settings([CONFIG], ["segment=--data.goal_horizon segment"])
    task = "pointmaze-umaze-N[3]"
    argv = study.fit_argv(setting, task, 1, tmp_path, ["--trainer.max_steps", "3"])
    assert argv[:4] == ["-m", "hispo_pl.cli", "fit", "--config"]
    extra = ["--eval_episodes", "2", "--trainer.enable_progress_bar", "false"]
    assert cli_main(argv[2:] + extra) == 0  # the same command, in process
    run = study.run_dir(tmp_path, setting, task, 1)
    result = run.read_result()
    assert result["task"] == task and result["step"] == 3
    config = run.config_file.read_text()
    assert "goal_horizon: segment" in config and "seed_everything: 1" in config
    assert study.collect_results(tmp_path, [setting], [task]) == {("segment", task): [result]}


def test_table_is_mean_and_spread_over_seeds_from_the_files(tmp_path):
    settings = study.parse_settings([CONFIG], ["x=", "y="])
    task = "pointmaze-medium-N[500]"
    for seed, success in ((0, 0.9), (1, 0.8)):
        folder = tmp_path / "runs" / "x-pointmaze-medium" / f"seed{seed}"
        folder.mkdir(parents=True)
        result = {"success": success, "episode_length": 100.0 + seed, "step": 6000}
        (folder / "result.json").write_text(json.dumps(result))
    results = study.collect_results(tmp_path, settings, [task])
    table = study.write_tables(tmp_path, settings, [task], results)
    assert "| pointmaze-medium-N[500] | 85.0 ± 5.0 (100) | – | 2 | 6000 |" in table
    assert (tmp_path / "table.md").read_text() == table
    assert len((tmp_path / "table.csv").read_text().splitlines()) == 3  # header + one per run
