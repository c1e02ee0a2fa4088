"""``hispo-pl benchmark --grid``: the grid's definition, its planning against committed runs,
an end-to-end grid with a sweep on the tiny stream, and the grid's reports (the paper's beside
them: tests/lab/test_lab.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import BENCH_TINY, BENCH_TINY_OVERRIDES, grid_config_dir, write_run_files

from hispo_pl.benchmark import grid as gr
from hispo_pl.benchmark import grid_plan
from hispo_pl.benchmark import grid_report as gp
from hispo_pl.benchmark.finished_runs import RunRecord
from hispo_pl.benchmark.launch import execute_run
from hispo_pl.benchmark.plan import planned_tasks
from hispo_pl.benchmark.tables import run_minutes
from hispo_pl.cli import main as cli_main
from hispo_pl.errors import ConfigError
from hispo_pl.rundir import RunDir

ROOT = Path(__file__).resolve().parents[2]

GRID = {
    "streams": ["pointmaze-1", "pointmaze-2"],
    "parts": {"pm": ["pointmaze-1", "pointmaze-2"]},
    "methods": ["scn", "l2"],
    "seeds": 2,
    "sweeps": {
        "l2": {"key": "model.init_args.penalty_lambda", "name": "lambda", "values": [0.1, 1, 10]}
    },
}


# --- the definition ---------------------------------------------------------------------------


def test_the_paper_grid_loads_with_every_method_of_its_tables():
    grid = gr.load_grid("paper", ROOT / "configs")
    four = ("pointmaze-1", "pointmaze-2", "videogame-1", "videogame-2")
    assert grid.streams == (*four, "antmaze-1", "antmaze-2")
    assert grid.aggregates == {"four-streams": four}  # the aggregate before AntMaze, kept
    assert gr.grid_streams(grid, "antmaze") == ["antmaze-1", "antmaze-2"]
    assert set(grid.methods) == {
        "sc1", "scn", "ft1", "ftn", "frz", "l2", "ewc", "pnn", "hispo", "csp", "cspo", "hilow",
        "hispo-pac",
    }  # fmt: skip
    assert grid.seeds == (0, 1, 2)
    for method in ("l2", "ewc"):
        assert grid.sweeps[method].values == (0.01, 0.1, 1.0, 10.0, 100.0)
        assert grid.sweeps[method].branch  # task 1 trains alike at every λ
    for method in grid.methods:
        assert (ROOT / "configs/methods" / f"{method}.yaml").is_file()
    assert gr.grid_streams(grid, "videogame") == ["videogame-1", "videogame-2"]
    assert gr.grid_from_dict(grid.to_dict(), "paper") == grid  # grid.json round trip


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"streams": []}, "`streams` must be a non-empty list"),
        ({"method": ["scn"]}, "unknown key(s) method"),
        ({"seeds": [-1]}, "`seeds` is a count or a list"),
        ({"parts": {"x": ["antmaze-1"]}}, "part x names streams the grid does not list"),
        ({"aggregates": {"y": ["antmaze-1"]}}, "aggregate y names streams the grid does not"),
        ({"aggregates": {"y": []}}, "each aggregate of `aggregates` is a list of the grid's"),
        ({"sweeps": {"ewc": {"key": "k", "values": [1]}}}, "sweep of ewc, which is not among"),
        ({"sweeps": {"l2": {"key": "k"}}}, "sweep of l2 needs `key` and `values`"),
        (
            {"sweeps": {"l2": {"key": "model.init_args.lr", "values": [1], "branch": True}}},
            "sweep of l2: `branch` needs keys among eps_high, eps_low, "
            "model.init_args.penalty_lambda",
        ),
    ],
)
def test_a_malformed_grid_is_refused_in_one_line(change, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)")):
        gr.grid_from_dict({**GRID, **change}, "g")


def test_grid_refuses_fit_arguments_of_the_command_line(capsys):
    args = ["benchmark", "--grid", "paper", "--out", "w", "--export", "r", "--", "--seed", "1"]
    assert cli_main(args) == 2
    assert "put fit arguments and the budget in the grid file" in capsys.readouterr().err


def test_methods_and_seeds_select_part_of_the_grid(tmp_path, capsys):
    args = ["benchmark", "--grid", "paper", "--part", "pointmaze-1", "--out", str(tmp_path / "w")]
    args += ["--export", str(tmp_path / "r"), "--methods", "scn", "--dry-run"]
    assert cli_main([*args, "--seeds", "1,2"]) == 0
    out = capsys.readouterr().out
    assert "[grid] selected: scn; seeds 1, 2\n" in out
    planned = [line for line in out.splitlines() if " fit " in line]
    assert [line.split("--trainer.logger.init_args.version ")[1][:5] for line in planned] == [
        "seed1",
        "seed2",
    ]
    assert all("--trainer.logger.init_args.name scn " in line for line in planned)
    # a bare number is a count: said with the seeds it selects, and how to name one seed
    assert cli_main([*args, "--seeds", "2"]) == 0
    out = capsys.readouterr().out
    assert "seeds 0, 1 (--seeds 2 is a count; one seed alone is --seeds 2,)" in out
    assert cli_main([*args, "--seeds", "0,7"]) == 2
    assert "--seeds 0,7: the grid paper has seeds 0, 1, 2" in capsys.readouterr().err


def test_parts_streams_and_unknown_names():
    grid = gr.grid_from_dict(GRID, "g")
    assert gr.grid_streams(grid, None) == ["pointmaze-1", "pointmaze-2"]
    assert gr.grid_streams(grid, "pointmaze-2,pm") == ["pointmaze-2", "pointmaze-1"]
    with pytest.raises(ConfigError, match="--part antmaze: not a part .pm. or stream"):
        gr.grid_streams(grid, "antmaze")
    with pytest.raises(ConfigError, match="known grids: paper"):
        gr.load_grid("papr", ROOT / "configs")


# --- planning ---------------------------------------------------------------------------------


def test_chosen_value_waits_for_every_value_and_breaks_ties_by_order():
    sweep = gr.Sweep("l2", "k", (0.1, 1.0, 10.0))
    assert grid_plan.chosen_value(sweep, {0.1: 0.5, 1.0: None, 10.0: 0.9}) is None
    assert grid_plan.chosen_value(sweep, {0.1: 0.5, 1.0: 0.7, 10.0: 0.6}) == 1.0
    assert grid_plan.chosen_value(sweep, {0.1: 0.7, 1.0: 0.7, 10.0: 0.6}) == 0.1


def test_plan_runs_sweeps_first_then_the_seeds_at_the_best_value():
    grid = gr.grid_from_dict({**GRID, "streams": ["pointmaze-1"], "parts": {}}, "g")
    done: dict[str, float] = {"pointmaze-1/scn/seed0": 0.9}
    plan = grid_plan.plan_cells(grid, grid.streams, lambda c: done.get(c.name))
    assert [c.name for c in plan.done] == ["pointmaze-1/scn/seed0"]
    assert [c.name for c in plan.todo] == [
        "pointmaze-1/scn/seed1",
        "pointmaze-1/l2-lambda0.1/seed0",
        "pointmaze-1/l2-lambda1/seed0",
        "pointmaze-1/l2-lambda10/seed0",
    ]
    assert plan.todo[-1].extra == ("--model.init_args.penalty_lambda", "10")
    assert plan.waiting == ["pointmaze-1/l2: 2 seed(s) wait for the lambda sweep"]

    done.update({"pointmaze-1/l2-lambda0.1/seed0": 0.4, "pointmaze-1/l2-lambda1/seed0": 0.6})
    done["pointmaze-1/l2-lambda10/seed0"] = 0.5
    plan = grid_plan.plan_cells(grid, grid.streams, lambda c: done.get(c.name))
    ((target, source),) = plan.derived
    assert (target.name, source.name) == ("pointmaze-1/l2/seed0", "pointmaze-1/l2-lambda1/seed0")
    assert target.extra == source.extra == ("--model.init_args.penalty_lambda", "1")
    assert [c.name for c in plan.todo] == ["pointmaze-1/scn/seed1", "pointmaze-1/l2/seed1"]
    assert not plan.waiting


def test_a_derived_run_has_the_command_of_its_source_but_for_where_it_logs(tmp_path):
    grid = gr.grid_from_dict(GRID, "g")
    source = grid_plan.Cell("pointmaze-1", "l2-lambda1", "l2", 0, ("--x", "1"), sweep=True)
    target = grid_plan.Cell("pointmaze-1", "l2", "l2", 0, ("--x", "1"))
    a = grid_plan.cell_run(source, grid, ROOT / "configs", tmp_path).argv
    b = grid_plan.cell_run(target, grid, ROOT / "configs", tmp_path).argv
    differ = [(x, y) for x, y in zip(a, b, strict=True) if x != y]
    assert differ == [("l2-lambda1", "l2")]  # the logger's name: the run folder only


def _committed(
    root: Path, cell: grid_plan.Cell, tasks: list[str], config: dict | None = None
) -> None:
    run = cell.result_dir(root)
    run.mkdir(parents=True)
    R = [[0.5 if k <= i else None for k in range(len(tasks))] for i in range(len(tasks))]
    write_run_files(run, {"stream": tasks, "PER": 0.5, "R": R})
    (run / "config.yaml").write_text(yaml.safe_dump(config or {}))


def test_committed_runs_of_an_older_stream_or_another_value_are_not_done(tmp_path):
    grid = gr.grid_from_dict(GRID, "g")
    reader = grid_plan.committed_reader(grid, ROOT / "configs", tmp_path)
    tasks = planned_tasks(
        grid_plan.cell_run(
            grid_plan.Cell("pointmaze-1", "scn", "scn", 0), grid, ROOT / "configs", tmp_path
        )
    )
    ok = grid_plan.Cell("pointmaze-1", "scn", "scn", 0)
    old = grid_plan.Cell("pointmaze-1", "scn", "scn", 1)
    _committed(tmp_path, ok, tasks)
    _committed(tmp_path, old, ["pointmaze-umaze-N[500]"])
    assert reader(ok) == 0.5 and reader(old) is None
    flag = ("--model.init_args.penalty_lambda", "1")
    right, wrong = (
        grid_plan.Cell("pointmaze-2", "l2", "l2", 0, flag),
        grid_plan.Cell("pointmaze-2", "l2", "l2", 1, flag),
    )
    tasks2 = planned_tasks(grid_plan.cell_run(right, grid, ROOT / "configs", tmp_path))
    _committed(tmp_path, right, tasks2, {"model": {"init_args": {"penalty_lambda": 1.0}}})
    _committed(tmp_path, wrong, tasks2, {"model": {"init_args": {"penalty_lambda": 0.1}}})
    assert reader(right) == 0.5 and reader(wrong) is None
    (old.result_dir(tmp_path) / "results.json").write_text("{")  # cut short: run it again
    assert reader(old) is None
    write_run_files(ok.result_dir(tmp_path), launch={"steps_per_task": 100})
    assert reader(ok) is None  # another budget than the stream config's


# --- end to end -------------------------------------------------------------------------------


def _tiny_grid_configs(tmp_path: Path) -> Path:
    grid = {
        "streams": ["pointmaze-1"],
        "methods": ["scn"],
        "seeds": [0, 1],
        "steps_per_task": 5,
        "extra": BENCH_TINY_OVERRIDES,
        "sweeps": {"scn": {"key": "data.batch_size", "name": "batch", "values": [32, 64]}},
    }
    return grid_config_dir(tmp_path, "tiny", grid)


@pytest.mark.e2e
def test_grid_end_to_end_exports_derives_and_resumes(tiny_umaze, tmp_path, capsys):
    pytest.importorskip("rliable")
    configs = _tiny_grid_configs(tmp_path)
    work, root = tmp_path / "work", tmp_path / "results"
    args = ["benchmark", "--grid", "tiny", "--config-dir", str(configs), "--out", str(work)]
    args += ["--export", str(root), "--workers", "2"]
    assert cli_main(args) == 0
    printed = capsys.readouterr().out
    assert "pointmaze-1: 0 done, 2 to run" in printed
    assert "pointmaze-1/scn: 2 seed(s) wait for the batch sweep" in printed
    pers = {}
    for value in (32, 64):
        results = json.loads(
            (root / f"pointmaze-1/sweeps/scn-batch{value}/seed0/results.json").read_text()
        )
        assert results["stream"] == BENCH_TINY
        pers[value] = results["PER"]
    best = 32 if pers[32] >= pers[64] else 64
    assert f"pointmaze-1/scn/seed0: the same run as pointmaze-1/scn-batch{best}/seed0" in printed
    meta = json.loads((root / "pointmaze-1/scn/seed0/run.json").read_text())
    assert meta["derived_from"] == f"pointmaze-1/scn-batch{best}/seed0"
    seed1 = json.loads((root / "pointmaze-1/scn/seed1/run.json").read_text())
    assert seed1["argv"][-2:] == ["--data.batch_size", str(best)]
    assert seed1["machine"]["cpus"] >= 1 and "commit" not in seed1  # no git in the product
    assert "| scn | 2 |" in (root / "pointmaze-1/table.md").read_text()
    report = root / "grid-tiny"
    assert {p.name for p in report.iterdir()} >= {"grid.json", "aggregate.md", "sweeps.md"}
    assert f"**{100 * pers[best]:.1f}**" in (report / "sweeps.md").read_text()

    # the derived seed trains exactly as a real run of its own command would
    grid = gr.load_grid("tiny", configs)
    real = grid_plan.cell_run(
        grid_plan.Cell("pointmaze-1", "scn", "scn", 0, ("--data.batch_size", str(best))),
        grid,
        configs,
        tmp_path / "real",
    )
    real.run_dir.mkdir(parents=True)
    outcome = execute_run(real.argv, str(real.log_path), str(real.results_path))
    derived = json.loads((root / "pointmaze-1/scn/seed0/results.json").read_text())
    assert outcome["results"]["R"] == derived["R"] and outcome["results"]["MEM"] == derived["MEM"]

    # nothing is left: a rerun plans no run and trains nothing
    assert cli_main(args) == 0
    printed = capsys.readouterr().out
    assert "pointmaze-1: 4 done, 0 to run" in printed and "FAILED" not in printed

    # a run stopped between its results and its export is exported by the next launch
    other = 64 if best == 32 else 32
    lost = root / f"pointmaze-1/sweeps/scn-batch{other}/seed0"
    kept = (lost / "results.json").read_bytes()
    shutil.rmtree(lost)
    assert cli_main(args) == 0
    printed = capsys.readouterr().out
    assert f"scn-batch{other}/seed0: finished before its export" in printed
    assert (lost / "results.json").read_bytes() == kept and "FAILED" not in printed

    # a dry run names the seed it would copy from its sweep and copies nothing
    copied = root / "pointmaze-1/scn/seed0"
    shutil.rmtree(copied)
    assert cli_main([*args, "--dry-run"]) == 0
    assert "1 to copy from their sweep" in capsys.readouterr().out and not copied.exists()
    assert cli_main(args) == 0
    assert "the same run as" in capsys.readouterr().out and copied.is_dir()


def test_grid_report_reads_each_stream_once_and_aggregates_its_methods(tmp_path, monkeypatch):
    pytest.importorskip("rliable")
    root = tmp_path / "results"
    for stream in ("pointmaze-1", "pointmaze-2"):
        shutil.copytree(ROOT / "docs/results" / stream, root / stream)
    grid = gr.grid_from_dict({**GRID, "methods": ["scn", "hispo"], "seeds": 3, "sweeps": {}}, "g")
    read = []
    load_records = gp.load_records
    monkeypatch.setattr(gp, "load_records", lambda out: read.append(out) or load_records(out))
    gp.write_grid_report(grid, root, figures=False)
    assert sorted(p.name for p in read) == ["pointmaze-1", "pointmaze-2"]  # each read once
    monkeypatch.undo()
    aggregate = (root / "grid-g/aggregate.md").read_text()
    assert "| scn | 2 of 2 |" in aggregate and "| hispo | 2 of 2 |" in aggregate
    assert aggregate.splitlines()[2].endswith("| PER IQM [95 % CI] |")  # its last column
    texts, _ = gp.grid_reports(grid, root)
    assert texts["aggregate.md"] == aggregate  # the intervals are seeded


def test_a_named_aggregate_is_the_grid_over_its_streams_alone(tmp_path):
    pytest.importorskip("rliable")
    root = tmp_path / "results"
    for stream in ("pointmaze-1", "pointmaze-2"):
        shutil.copytree(ROOT / "docs/results" / stream / "scn", root / stream / "scn")
    raw = {**GRID, "methods": ["scn"], "seeds": 3, "sweeps": {}}
    grid = gr.grid_from_dict({**raw, "aggregates": {"first": ["pointmaze-1"]}}, "g")
    gp.write_grid_report(grid, root, figures=False)
    whole = (root / "grid-g/aggregate.md").read_text()
    first = (root / "grid-g/aggregate-first.md").read_text()
    assert "| scn | 2 of 2 |" in whole and "| scn | 1 of 1 |" in first
    assert first.startswith("# Aggregate: grid g, first\n")
    # the named aggregate is what a grid of that stream alone reports
    alone = gr.grid_from_dict({**raw, "streams": ["pointmaze-1"], "parts": {}}, "g, first")
    committed = gp.Committed(root)
    assert first == gp.aggregate_markdown(alone, gp.aggregate_rows(alone, committed))
    texts, _ = gp.grid_reports(grid, root)
    assert texts["aggregate-first.md"] == first  # what a page's embed rebuilds


def test_iqm_interval_is_seeded_and_leaves_numpy_alone():
    pytest.importorskip("rliable")
    np.random.seed(5)
    before = np.random.get_state()[1].copy()
    scores = np.array([[90.0, 80.0], [95.0, 70.0], [85.0, 75.0]])
    first = gp.iqm_interval(scores, reps=200)
    assert first == gp.iqm_interval(scores, reps=200)
    assert (np.random.get_state()[1] == before).all()
    point, low, high = first
    assert low <= point <= high and low >= 70.0 and high <= 95.0


def test_cost_sums_the_same_runs_per_part_of_the_grid():
    """On the committed paper grid: each part's runs are the committed runs under its streams
    (sweeps included, a seed copied from its sweep once), and the parts add up to the whole."""
    grid = gr.load_grid("paper", ROOT / "configs")
    text = gp.cost_markdown(grid, gp.Committed(ROOT / "docs/results"))
    rows = {line.split("|")[1].strip(): line.split("|")[2:] for line in text.splitlines()
            if line.startswith("| ")}  # fmt: skip
    (total_runs, total_hours) = (int(rows["all"][0]), float(rows["all"][1]))
    parts = {p: (int(rows[p][1]), float(rows[p][2])) for p in grid.parts}
    assert sum(r for r, _ in parts.values()) == total_runs
    assert sum(h for _, h in parts.values()) == pytest.approx(total_hours, abs=0.15)
    for part, streams in grid.parts.items():
        found = 0
        for stream in streams:
            folder = ROOT / "docs/results" / stream
            found += len(list(folder.glob("sweeps/*/seed*/results.json")))
            for method in grid.methods:
                for seed in folder.glob(f"{method}/seed*/results.json"):
                    source = json.loads((seed.parent / "run.json").read_text()).get(
                        "derived_from", ""
                    )
                    label_seed = source.partition("/")[2]
                    copied = source and (folder / "sweeps" / label_seed).is_dir()
                    found += not copied
        assert parts[part][0] == found, part


def test_cost_counts_a_seed_copied_from_its_sweep_once(tmp_path):
    src = ROOT / "docs/results/pointmaze-1"
    root = tmp_path / "results"
    shutil.copytree(src / "l2", root / "pointmaze-1/l2")
    for value in ("0.01", "0.1", "1", "10", "100"):
        name = f"sweeps/l2-lambda{value}"
        shutil.copytree(src / name, root / "pointmaze-1" / name)
    seed0 = json.loads((root / "pointmaze-1/l2/seed0/run.json").read_text())
    assert seed0["derived_from"] == "pointmaze-1/l2-lambda0.01/seed0"  # the sweep's own run
    grid = gr.grid_from_dict(
        {**GRID, "streams": ["pointmaze-1"], "parts": {}, "methods": ["l2"], "seeds": 3}, "g"
    )
    runs = [root / "pointmaze-1/l2/seed1", root / "pointmaze-1/l2/seed2"]
    runs += sorted((root / "pointmaze-1/sweeps").glob("*/seed0"))
    minutes = sum(run_minutes(RunRecord("l2", 0, RunDir(r).stream_results())) for r in runs)
    (line,) = [
        row for row in gp.cost_markdown(grid, gp.Committed(root)).splitlines() if "| l2 |" in row
    ]
    assert line.startswith(f"| l2 | 7 | {minutes / 60:.1f} | {minutes / 7:.1f} |")
