"""Random streams (``random-<family>-<n>@<seed>``): the same tasks on every machine, a longer
stream extending a shorter one, and usable wherever a stream name is: fit, benchmark, grid."""

from __future__ import annotations

from pathlib import Path

import pytest

from hispo_pl.benchmark import grid as gr
from hispo_pl.benchmark import grid_plan, plan
from hispo_pl.benchmark.configs import datasets_needed
from hispo_pl.cli import main as cli_main
from hispo_pl.fit import check_fit_args
from hispo_pl.results import LaunchRecord
from hispo_pl.rundir import RunDir
from hispo_pl.task_families import FAMILIES
from hispo_pl.tasks import (
    TaskSpecError,
    parse_random_stream,
    parse_stream,
    parse_task,
    random_stream,
    stream_specs,
    task_space,
)

ROOT = Path(__file__).resolve().parents[2]

# written out so that any change of the draw (hash, order of the task space) fails here
PINNED = {
    "random-pointmaze-12@0": [
        "pointmaze-medium-N[500]",
        "pointmaze-large-PA[500]",
        "pointmaze-medium-IA[500]",
        "pointmaze-medium-PO[500]",
        "pointmaze-umaze-PO[500]",
        "pointmaze-medium-PA[500]",
        "pointmaze-large-IO[500]",
        "pointmaze-large-N[500]",
        "pointmaze-umaze-IA[500]",
        "pointmaze-large-IA[500]",
        "pointmaze-large-IA[500]",
        "pointmaze-medium-N[500]",
    ],
    "random-antmaze-8@3": [
        "antmaze-medium-PA[500]",
        "antmaze-medium-PO[500]",
        "antmaze-medium-PA[500]",
        "antmaze-large-IO[500]",
        "antmaze-umaze-IO[500]",
        "antmaze-umaze-IO[500]",
        "antmaze-large-IA[500]",
        "antmaze-large-PO[500]",
    ],
    "random-amazeville-8@1": [
        "amazeville-HXOO[100]",
        "amazeville-HOOO[100]",
        "amazeville-LOOO[100]",
        "amazeville-HXOO[100]",
        "amazeville-LOOX[100]",
        "amazeville-HXOX[100]",
        "amazeville-HOOX[100]",
        "amazeville-LOOX[100]",
    ],
}


# --- the draw ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name", PINNED)
def test_a_random_stream_is_pinned_to_its_tasks(name):
    assert stream_specs(name) == PINNED[name]


def test_a_longer_stream_extends_a_shorter_one():
    assert random_stream("antmaze", 4, 3) == random_stream("antmaze", 8, 3)[:4]
    assert random_stream("antmaze", 8, 3) != random_stream("antmaze", 8, 4)


@pytest.mark.parametrize("family", FAMILIES)
def test_the_draw_covers_the_family_with_repeats(family):
    space = task_space(family)
    fam = FAMILIES[family]
    assert len(space) == len(set(space)) == len(fam.mazes) * len(fam.variants)
    tasks = random_stream(family, 60, 0)
    assert set(tasks) <= set(space) and len(set(tasks)) < len(tasks)  # repeats allowed
    assert {parse_task(t).episodes for t in tasks} == {fam.default_episodes}


def test_game_tasks_are_spelled_as_the_named_streams_spell_them():
    assert task_space("simpletown")[0] == "simpletown-BASE[250]"
    assert task_space("pointmaze")[:2] == ["pointmaze-umaze-N[500]", "pointmaze-umaze-IA[500]"]


def test_parse_stream_takes_a_random_name():
    tasks = parse_stream("random-antmaze-8@3")
    assert [t.spec for t in tasks] == [parse_task(s).spec for s in PINNED["random-antmaze-8@3"]]
    assert parse_random_stream("random-antmaze-8@3") == ("antmaze", 8, 3)
    assert parse_random_stream("antmaze-1") is None


@pytest.mark.parametrize(
    "name, message",
    [
        ("random-ant-8@3", "unknown family 'ant'"),
        ("random-antmaze-0@3", "n >= 1"),
        ("random-antmaze-8", "malformed random stream"),
        ("random-antmaze-8@x", "malformed random stream"),
        ("random-antmaze-08@3", "as random-antmaze-8@3"),
    ],
)
def test_a_malformed_random_name_says_the_grammar_in_one_line(name, message):
    with pytest.raises(TaskSpecError) as err:
        parse_stream(name)
    assert message in str(err.value) and "\n" not in str(err.value)
    assert "random-antmaze-8@3" in str(err.value)  # the example or the right spelling


def test_an_unknown_name_mentions_random_streams():
    with pytest.raises(TaskSpecError, match=r"pointmaze-1.*random-<family>-<n>@<seed>"):
        parse_stream("pointmaze-9")


# --- wherever a stream name is accepted -----------------------------------------------------------


def test_fit_takes_a_random_stream_over_a_reference_config():
    argv = ["fit", "--config", str(ROOT / "configs/streams/antmaze-1.yaml")]
    argv += ["--config", str(ROOT / "configs/methods/hispo.yaml")]
    assert check_fit_args([*argv, "--data.stream", "random-antmaze-8@3"]) is None
    assert "malformed" in check_fit_args([*argv, "--data.stream", "random-antmaze-8"])


def test_datasets_needed_reads_a_random_stream_override():
    config = ROOT / "configs/streams/pointmaze-1.yaml"
    needed = datasets_needed([config], ["--data.stream", "random-pointmaze-12@0"])
    assert needed == {f"pointmaze-{m}": 500 for m in ("umaze", "medium", "large")}
    assert datasets_needed([config], ["--data.stream", "random-pointmaze-1@0"]) == {
        "pointmaze-medium": 500
    }


def test_a_random_stream_runs_on_its_family_reference_config():
    configs = ROOT / "configs"
    path = plan.stream_config_path("random-simpletown-5@2", configs)
    assert path == (configs / "streams/simpletown-1.yaml").resolve()
    assert plan.stream_fit_args("random-simpletown-5@2") == (
        "--data.stream",
        "random-simpletown-5@2",
    )
    assert plan.stream_fit_args("simpletown-1") == plan.stream_fit_args("random-x.yaml") == ()
    assert plan.stream_name("random-simpletown-5@2", path) == "random-simpletown-5@2"
    assert plan.stream_name("simpletown-1", path) == "simpletown-1"
    with pytest.raises(TaskSpecError, match="unknown family"):
        plan.stream_config_path("random-nomaze-5@2", configs)


def test_benchmark_dry_run_plans_a_random_stream(tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["benchmark", "--stream", "random-pointmaze-12@0", "--methods", "scn"]
    assert cli_main([*argv, "--seeds", "1", "--out", str(out), "--dry-run"]) == 0
    (line,) = capsys.readouterr().out.splitlines()
    assert "configs/streams/pointmaze-1.yaml" in line
    assert line.endswith("--data.stream random-pointmaze-12@0")
    assert not out.exists()


def test_a_benchmark_of_a_random_stream_plans_and_checks_its_tasks(tmp_path):
    name = "random-pointmaze-12@0"
    config = plan.stream_config_path(name, ROOT / "configs")
    (run,) = plan.plan_runs(
        config, ROOT / "configs", ["scn"], [0], tmp_path, extra=plan.stream_fit_args(name)
    )
    assert plan.planned_tasks(run) == [parse_task(s).spec for s in PINNED[name]]
    assert plan.foreign_runs([run], name) == []
    run.run_dir.mkdir(parents=True)
    RunDir(run.run_dir).write_run_record(LaunchRecord(stream="pointmaze-1"))
    assert plan.foreign_runs([run], name) == ["scn/seed0 (pointmaze-1)"]


def test_a_grid_cell_of_a_random_stream_carries_its_name(tmp_path):
    grid = gr.grid_from_dict(
        {"streams": ["pointmaze-1", "random-pointmaze-12@0"], "methods": ["scn"], "seeds": 1}, "g"
    )
    run = grid_plan.cell_run(
        grid_plan.Cell("random-pointmaze-12@0", "scn", "scn", 0), grid, ROOT / "configs", tmp_path
    )
    argv = list(run.argv)
    i = argv.index("--data.stream")
    assert argv[i + 1] == "random-pointmaze-12@0"
    assert run.configs[0] == (ROOT / "configs/streams/pointmaze-1.yaml").resolve()
    assert run.run_dir == (tmp_path / "random-pointmaze-12@0/runs/scn/seed0").resolve()
    assert plan.planned_tasks(run) == [parse_task(s).spec for s in PINNED["random-pointmaze-12@0"]]
    named = grid_plan.cell_run(
        grid_plan.Cell("pointmaze-1", "scn", "scn", 0), grid, ROOT / "configs", tmp_path
    )
    assert "--data.stream" not in named.argv
