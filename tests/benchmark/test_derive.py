"""A keep-last run (SC1, FT1) derived from its keep-all sibling's (SCN, FTN): the test that
licenses it (the derived run equals a real run of the same seed, file by file), the grid's
decision to derive instead of train, and the grid deriving a cell end to end."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch
import yaml
from helpers import BENCH_TINY_OVERRIDES, TINY_STREAM, fit_tiny_stream, nested_equal, without_times

from hispo_pl.benchmark import derive, grid_plan, grid_run
from hispo_pl.benchmark import grid as gr
from hispo_pl.errors import RunDirError
from hispo_pl.rundir import RunDir

ROOT = Path(__file__).resolve().parents[2]
# enough steps and episodes that a finished task acts differently with a later network
BUDGET = ("--trainer.max_steps", "40", "--trainer.callbacks.init_args.episodes", "6")
PAIRS = [("sc1", "scn"), ("ft1", "ftn")]


@pytest.fixture(scope="module")
def real_runs(tiny_umaze, tmp_path_factory) -> tuple[Path, dict[str, Path]]:
    """The four methods trained for real on the same tiny stream and seed."""
    root = tmp_path_factory.mktemp("derive")
    methods = [m for pair in PAIRS for m in pair]
    return root, {m: fit_tiny_stream(m, root / m, TINY_STREAM, *BUDGET)[1] for m in methods}


@pytest.mark.e2e
@pytest.mark.parametrize("target,source", PAIRS)
def test_a_derived_run_equals_a_real_run_of_the_same_seed(real_runs, target, source):
    root, runs = real_runs
    out = root / "derived" / target / "pointmaze-1" / "seed0"
    derived = derive.derive_run(runs[source], out)
    real, sibling = RunDir(runs[target]), RunDir(runs[source])
    # the entry measured again matters: copying the sibling's R would fail here
    assert derived.R != sibling.stream_results().R
    assert without_times(derived.to_json()) == without_times(real.stream_results().to_json())
    assert RunDir(out).stream_results() == derived
    progress, real_progress = RunDir(out).read_progress(), real.read_progress()
    assert without_times(progress.to_json()) == without_times(real_progress.to_json())
    assert progress.fingerprint["model.init_args.keep"] == "last"
    for task in range(len(TINY_STREAM)):
        a = torch.load(RunDir(out).checkpoint(task), weights_only=True)
        assert nested_equal(a, torch.load(real.checkpoint(task), weights_only=True))
        text = RunDir(out).task_config(task).read_text()
        assert text.replace(str(out.parents[1]), str(runs[target].parents[1])) == (
            real.task_config(task).read_text()
        )
    text = RunDir(out).config_file.read_text()
    assert text.replace(str(out.parents[1]), str(runs[target].parents[1])) == (
        real.config_file.read_text()
    )
    # its cost is the evaluation it ran: nothing trained, the first row measured nothing again
    assert [p["training"] for p in derived.phase_time_s] == [0.0, 0.0]
    assert derived.phase_time_s[0]["evaluation"] == 0.0 < derived.phase_time_s[1]["evaluation"]
    assert RunDir(out).read_run_record().derived_from == str(runs[source])


def test_a_derivation_holds_its_folder_as_a_run_does(real_runs, tmp_path):
    from hispo_pl.resume import RunDirLock

    _, runs = real_runs
    target = tmp_path / "held"
    target.mkdir()
    with RunDirLock(target), pytest.raises(RunDirError, match="in use by another run"):
        derive.derive_run(runs["scn"], target)
    assert not RunDir(target).has_results()


def test_only_a_finished_keep_all_run_with_its_checkpoints_derives(real_runs, tmp_path):
    root, runs = real_runs
    assert derive.derivable_run(runs["scn"]) and derive.derivable_run(runs["scn"], runs["scn"])
    assert not derive.derivable_run(runs["scn"], runs["ftn"])  # another run is committed there
    copy = tmp_path / "scn"
    shutil.copytree(runs["scn"], copy)
    RunDir(copy).checkpoint(1).unlink()
    assert not derive.derivable_run(copy)
    with pytest.raises(RunDirError, match="no finished run with a checkpoint for every task"):
        derive.derive_run(copy, tmp_path / "out")
    with pytest.raises(RunDirError, match="keep: all"):
        derive.derive_run(runs["sc1"], tmp_path / "out")


def _method_configs() -> dict[str, dict]:
    return {
        p.stem: yaml.safe_load(p.read_text()) for p in (ROOT / "configs/methods").glob("*.yaml")
    }


def test_keep_last_methods_derive_from_the_keep_all_config_that_differs_only_in_keep():
    configs = _method_configs()
    pairs = {"sc1": "scn", "ft1": "ftn", "bc-sc1": "bc-scn", "bc-ft1": "bc-ftn"}
    assert derive.keep_last_siblings(configs) == pairs  # FRZ keeps the last but trains once
    changed = derive.keep_all_twin(configs["sc1"])
    assert changed == configs["scn"]
    changed["trainer"]["callbacks"][1]["init_args"]["episodes"] = 10
    assert derive.keep_last_siblings({"sc1": configs["sc1"], "scn": changed}) == {}


def test_the_grid_derives_a_keep_last_cell_whose_sibling_trains_or_left_its_checkpoints():
    grid = gr.load_grid("paper", ROOT / "configs")
    sibling = grid_run.grid_sibling(grid.methods, ROOT / "configs")
    plan = grid_plan.plan_cells(grid, ["pointmaze-1"], lambda c: None, sibling, lambda c: False)
    pairs = sorted((t.name, s.name) for t, s in plan.from_sibling)
    assert pairs == sorted(
        (f"pointmaze-1/{t}/seed{s}", f"pointmaze-1/{src}/seed{s}")
        for t, src in PAIRS
        for s in range(3)
    )
    assert not {c.method for c in plan.todo} & {"sc1", "ft1"}
    line = grid_plan.describe(plan, lambda c: None)[0]
    # 13 methods, 2 of them derived, L2's and EWC's seeds waiting for their sweeps: 9 × 3 seeds,
    # and each λ tree's first value (the other four branch from it once it has finished)
    assert "0 done, 29 to run" in line and "6 to derive from a sibling" in line
    assert sum("waits for the tree's first value" in w for w in plan.waiting) == 8
    # the sibling committed: derived only where its run directory is still there (seed 0)
    done = {f"pointmaze-1/scn/seed{s}": 0.5 for s in range(3)}
    plan = grid_plan.plan_cells(
        grid, ["pointmaze-1"], lambda c: done.get(c.name), sibling, lambda c: c.seed == 0
    )
    derived = [(t.name, s.name) for t, s in plan.from_sibling if t.method == "sc1"]
    assert derived == [("pointmaze-1/sc1/seed0", "pointmaze-1/scn/seed0")]
    assert [c.name for c in plan.todo if c.method == "sc1"] == [
        "pointmaze-1/sc1/seed1",
        "pointmaze-1/sc1/seed2",
    ]
    # without a sibling rule nothing is derived
    assert grid_plan.plan_cells(grid, ["pointmaze-1"], lambda c: None).from_sibling == []


@pytest.mark.e2e
def test_grid_trains_the_sibling_then_derives_the_keep_last_cell(tiny_umaze, tmp_path, capsys):
    configs = tmp_path / "configs"
    for sub in ("methods", "streams"):
        (configs / sub).mkdir(parents=True)
    shutil.copy(ROOT / "configs/streams/pointmaze-1.yaml", configs / "streams")
    for method in ("sc1", "scn"):
        shutil.copy(ROOT / f"configs/methods/{method}.yaml", configs / "methods")
    grid = gr.Grid("tiny", ("pointmaze-1",), ("sc1", "scn"), (0,), steps_per_task=5,
                   extra=tuple(BENCH_TINY_OVERRIDES))  # fmt: skip
    work, root = tmp_path / "work", tmp_path / "results"
    assert grid_run.run_grid(grid, ["pointmaze-1"], configs, work, root, workers=1) == 0
    printed = capsys.readouterr().out
    assert "pointmaze-1: 0 done, 1 to run" in printed and "1 to derive from a sibling" in printed
    assert "pointmaze-1/sc1/seed0: derived from pointmaze-1/scn/seed0" in printed
    exported = RunDir(root / "pointmaze-1/sc1/seed0")
    meta = exported.read_run_record()
    assert meta.derived_from == "pointmaze-1/scn/seed0" and meta.method == "sc1"
    assert "configs/methods/sc1.yaml" in meta.command
    assert list(meta.to_json())[:2] == ["derived_from", "method"]  # the source named first
    config = yaml.safe_load(exported.config_file.read_text())
    assert config["model"]["init_args"]["keep"] == "last"
    assert config["trainer"]["logger"]["init_args"]["name"] == "sc1"
    assert exported.stream_results().metrics["MEM"] == pytest.approx(1, rel=1e-3)
    assert json.loads((root / "pointmaze-1/scn/seed0/results.json").read_text())["MEM"] > 1.9
    # a rerun finds both done
    assert (
        grid_run.run_grid(grid, ["pointmaze-1"], configs, work, root, workers=1, dry_run=True) == 0
    )
    assert "pointmaze-1: 2 done, 0 to run" in capsys.readouterr().out
