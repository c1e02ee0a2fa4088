"""The single-task study runs ``hispo-pl fit`` itself: its fit command is the product's CLI with
the setting's overrides, the benchmark's runner launches and skips its runs, a finished run's
``result.json`` is what the table reads, and the table rebuilds from committed files alone."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from helpers import load_benchmark

from hispo_pl.benchmark import PlannedRun, finished_run_dirs, pending_runs
from hispo_pl.cli import main as cli_main
from hispo_pl.results import TaskFitResult
from hispo_pl.rundir import RunDir

ROOT = Path(__file__).resolve().parents[2]
study = load_benchmark("single_task_table")


CONFIG = str(ROOT / "configs/hbc/pointmaze-{maze}.yaml")
FINISHED = TaskFitResult(
    method="HBC",
    task="pointmaze-medium-N",
    episodes=4,
    seconds=1.0,
    success=1.0,
    episode_length=80.0,
    flip_rate=0.0,
    step=5.0,
)


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
    argv = study.fit_argv(setting, task, 1, tmp_path, ["--trainer.max_steps", "5"])
    assert argv[:4] == ["-m", "hispo_pl.cli", "fit", "--config"]
    extra = ["--eval_episodes", "2", "--eval_every", "2", "--trainer.enable_progress_bar", "false"]
    assert cli_main(argv[2:] + extra) == 0  # the same command, in process
    run = study.run_dir(tmp_path, setting, task, 1)
    result = run.read_result()
    assert result.task == task and result.step == 5
    # the learning curve: every periodic evaluation, then the final one it ends on
    assert [point["step"] for point in result.curve] == [2, 4, 5]
    assert result.curve[-1] == result.evaluation
    config = run.config_file.read_text()
    assert "goal_horizon: segment" in config and "seed_everything: 1" in config
    assert study.collect_results(tmp_path, [setting], [task]) == {("segment", task): [result]}


def test_table_is_mean_and_spread_over_seeds_from_the_files(tmp_path):
    settings = study.parse_settings([CONFIG], ["x=", "y="])
    task = "pointmaze-medium-N[500]"
    for seed, success in ((0, 0.9), (1, 0.8)):
        folder = tmp_path / "runs" / "x-pointmaze-medium" / f"seed{seed}"
        folder.mkdir(parents=True)
        result = replace(FINISHED, success=success, episode_length=100.0 + seed, step=6000)
        RunDir(folder).write_result(result)
    results = study.collect_results(tmp_path, settings, [task])
    table = study.write_tables(tmp_path, settings, [task], results)
    assert "| pointmaze-medium-N[500] | 85.0 ± 5.0 (100) | – | 2 | 6000 |" in table
    assert (tmp_path / "table.md").read_text() == table
    assert len((tmp_path / "table.csv").read_text().splitlines()) == 3  # header + one per run


def test_a_single_task_run_is_finished_by_its_result_file(tmp_path, capsys):
    (setting,) = study.parse_settings([CONFIG], ["x="])
    runs = study.plan_runs([setting], ["pointmaze-medium-N"], [0, 1], tmp_path, [])
    assert all(isinstance(r, PlannedRun) and r.single_task for r in runs)
    assert runs[0].results_path == runs[0].run_dir / "result.json"
    runs[0].run_dir.mkdir(parents=True)
    RunDir(runs[0].run_dir).write_result(FINISHED)
    assert pending_runs(runs, stream=None) == runs[1:]
    assert "x-pointmaze-medium/seed0: skipped, result.json exists" in capsys.readouterr().out
    assert RunDir(runs[1].run_dir).read_run_record().argv == list(runs[1].argv)
    assert finished_run_dirs(tmp_path, RunDir.RESULT) == [runs[0].run_dir]
    assert finished_run_dirs(tmp_path) == []  # a stream's results.json marks a stream run


@pytest.mark.e2e
def test_main_launches_through_the_runner_and_skips_finished_runs(tiny_umaze, tmp_path, capsys):
    args = ["--config", CONFIG, "--setting", "n=", "--tasks", "pointmaze-umaze-N[3]"]
    args += ["--workers", "1", "--out", str(tmp_path), "--", "--trainer.max_steps", "3"]
    args += ["--eval_episodes", "2", "--trainer.enable_progress_bar", "false"]
    assert study.main(args) == 0
    assert "[1/1] n-pointmaze-umaze seed 0: " in capsys.readouterr().out
    run = RunDir(tmp_path / "runs" / "n-pointmaze-umaze" / "seed0")
    assert run.read_result().step == 3 and run.fit_log.exists()
    assert study.main(args) == 0
    printed = capsys.readouterr().out
    assert "skipped, result.json exists" in printed
    assert "| pointmaze-umaze-N[3] | " in printed
