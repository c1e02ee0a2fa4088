"""``hispo-pl benchmark``: planning and aggregation as pure functions, the reports and the
command's errors (the launchers and end-to-end runs: test_benchmark_runs.py)."""

from __future__ import annotations

import csv
import io
import json
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
from helpers import BENCH_TINY, BENCH_TINY_OVERRIDES, benchmark_config_dir

from hispo_pl import benchmark as bm
from hispo_pl.cli import main as cli_main
from hispo_pl.results import Decision, LaunchRecord, StreamResults
from hispo_pl.rundir import RunDir

ROOT = Path(__file__).resolve().parents[2]
NAN = None  # JSON's null above the diagonal of R


# --- planning ---------------------------------------------------------------------------------


def test_parse_seeds():
    assert bm.parse_seeds("3") == [0, 1, 2]
    assert bm.parse_seeds("1") == [0]
    assert bm.parse_seeds("0,4") == [0, 4]
    assert bm.parse_seeds("4,") == [4]
    for bad in ("0", "-1", "a", "1,1", "0,-2", ","):
        with pytest.raises(ValueError, match="--seeds"):
            bm.parse_seeds(bad)


def test_select_methods_all_list_and_unknown(tmp_path):
    configs = benchmark_config_dir(tmp_path, ["scn", "hispo", "bc-sc1"])
    known = bm.known_methods(configs)
    assert known == ["bc-sc1", "hispo", "scn"]
    assert bm.select_methods("all", known) == known
    assert bm.select_methods("scn, hispo,scn", known) == ["scn", "hispo"]
    with pytest.raises(ValueError, match=r"unknown method\(s\) ewc, pnn; known .*: bc-sc1, hispo"):
        bm.select_methods("hispo,ewc,pnn", known)


def test_stream_config_path(tmp_path):
    configs = benchmark_config_dir(tmp_path, ["hispo"])
    path = bm.stream_config_path("pointmaze-1", configs)
    assert path == (configs / "streams/pointmaze-1.yaml").resolve()
    assert bm.stream_config_path(str(path), tmp_path / "elsewhere") == path
    with pytest.raises(FileNotFoundError, match="known streams: pointmaze-1"):
        bm.stream_config_path("pointmaze-9", configs)


def test_configured_max_steps_reads_configs_then_overrides(tmp_path):
    stream = ROOT / "configs/streams/pointmaze-1.yaml"
    method = ROOT / "configs/methods/hispo.yaml"
    assert bm.configured_max_steps([stream, method]) == 6000
    late = tmp_path / "late.yaml"
    late.write_text("trainer:\n  max_steps: 70\n")
    assert bm.configured_max_steps([stream, late]) == 70
    assert bm.configured_max_steps([stream], ["--trainer.max_steps", "5"]) == 5
    assert bm.configured_max_steps([stream], ["--trainer.max_steps=9", "--x", "1"]) == 9


def test_configured_value_and_datasets_needed(tmp_path):
    stream = ROOT / "configs/streams/pointmaze-1.yaml"
    assert bm.configured_value([stream], [], "data.stream") == "pointmaze-1"
    assert bm.configured_value([stream], [], "data.dataset") is None
    assert bm.configured_value([stream], ["--data.batch_size", "64"], "data.batch_size") == 64
    assert bm.datasets_needed([stream]) == {
        "pointmaze-umaze": 500,
        "pointmaze-large": 500,
        "pointmaze-medium": 500,
    }
    assert bm.datasets_needed([stream], BENCH_TINY_OVERRIDES) == {"pointmaze-umaze": 3}
    d4rl = ["--data.dataset", "D4RL/pointmaze/umaze-v2"]
    assert bm.datasets_needed([stream], d4rl) == {}  # not ours to generate


def test_prepare_datasets_generates_only_the_missing_ones(tiny_umaze, monkeypatch, capsys):
    from hispo_pl.data import generation

    made = []
    monkeypatch.setattr(
        generation, "generate_dataset", lambda name, episodes: made.append((name, episodes))
    )
    bm.prepare_datasets({"pointmaze-umaze": 3, "pointmaze-medium": 7})
    assert made == [("pointmaze-medium", 500)]  # umaze exists (the tiny one)
    assert "generating the pointmaze-medium expert dataset" in capsys.readouterr().out


def test_runs_about_to_train_on_other_episodes_than_the_kept_ones_are_told(
    tiny_umaze, tmp_path, capsys
):
    """Before training, a benchmark compares this machine's datasets with the episodes the
    stream's finished runs read, so a run on a dataset made again is not found out an hour
    later in its table."""
    from hispo_pl.benchmark.finished_runs import warn_of_other_episodes

    config = tmp_path / "stream.yaml"  # two tasks of the session's 6-episode dataset
    config.write_text("data:\n  stream:\n  - pointmaze-umaze-N[6]\n  - pointmaze-umaze-PO[6]\n")
    about_to_train = [SimpleNamespace(configs=(config,), argv=())]
    here = tiny_umaze.content_digest()
    kept = tmp_path / "kept"
    for method, digest in (("hispo", "0123456789abcdef"), ("scn", here)):
        results = _results([0.5, 0.9], [0.5, 0.9])
        results.datasets = [{"dataset": "hispo/pointmaze-umaze-expert-v0", "episodes": 6}]
        results.datasets[0]["digest"] = digest
        (kept / method / "seed0").mkdir(parents=True)
        RunDir(kept / method / "seed0").write_results(results)
    warn_of_other_episodes("umaze", about_to_train, [kept, tmp_path / "not-made-yet"])
    said = capsys.readouterr().out
    assert said.count("\n") == 1 and said.startswith("[benchmark] umaze: ")
    assert f"pointmaze-umaze-expert-v0 (6 episodes) holds {here} here" in said
    assert "read 0123456789abcdef for hispo seed 0." in said and "scn" not in said
    (kept / "hispo").rename(tmp_path / "hispo")  # only runs that read these episodes
    warn_of_other_episodes("umaze", about_to_train, [kept])
    assert capsys.readouterr().out == ""


def test_plan_runs_builds_fit_commands(tmp_path):
    configs = benchmark_config_dir(tmp_path, ["hispo", "scn"])
    stream = bm.stream_config_path("pointmaze-1", configs)
    out = tmp_path / "out"
    runs = bm.plan_runs(stream, configs, ["scn", "hispo"], [0, 4], out, 2, 123, ["--a", "1"])
    assert [(r.method, r.seed) for r in runs] == [
        ("scn", 0),
        ("scn", 4),
        ("hispo", 0),
        ("hispo", 4),
    ]
    run = runs[3]
    assert run.run_dir == out.resolve() / "runs/hispo/seed4"
    assert run.results_path == run.run_dir / "results.json"
    assert run.log_path.parent == run.run_dir
    assert run.steps_per_task == 123
    assert run.configs == (stream, configs.resolve() / "methods/hispo.yaml")
    argv = list(run.argv)
    assert argv[:3] == ["-m", "hispo_pl.cli", "fit"]
    assert argv[3:7] == [
        "--config",
        str(stream),
        "--config",
        str(configs.resolve() / "methods/hispo.yaml"),
    ]
    pairs = dict(zip(argv[7:-2:2], argv[8:-2:2], strict=True))
    assert pairs == {
        "--seed_everything": "4",
        "--num_threads": "2",
        "--trainer.max_steps": "123",
        "--trainer.logger.init_args.save_dir": str(out.resolve() / "runs"),
        "--trainer.logger.init_args.name": "hispo",
        "--trainer.logger.init_args.version": "seed4",
        "--trainer.enable_progress_bar": "false",
    }
    assert argv[-2:] == ["--a", "1"]  # extra overrides last: they win
    assert run.command("py")[:2] == ["py", "-m"]
    # no --steps-per-task: the stream config's budget, and no max_steps override
    default = bm.plan_runs(stream, configs, ["hispo"], [0], out)[0]
    assert "--trainer.max_steps" not in default.argv and default.steps_per_task == 6000
    assert (
        bm.plan_runs(stream, configs, ["hispo"], [0], out, extra=["--trainer.max_steps", "5"])[
            0
        ].steps_per_task
        == 5
    )


# --- aggregation ------------------------------------------------------------------------------


def _results(diag, final, mem=None, anchors=None, minutes=1.0) -> StreamResults:
    """results.json of a 2-task stream: R = [[d0, null], [f0, f1]] with f1 = d1."""
    out = {
        "stream": BENCH_TINY,
        "R": [[diag[0], NAN], [final[0], diag[1]]],
        "wall_time_s": [30 * minutes, 30 * minutes],
    }
    assert final[1] == diag[1]
    if mem is not None:
        out["MEM"] = mem
    if anchors is not None:
        out["anchors"] = anchors
    return StreamResults.from_json(out)


def test_a_launch_records_the_versions_that_move_its_numbers():
    """run.json names the physics and arithmetic a run was made with: the same code and seed on
    another MuJoCo collects other episodes and rolls out other successes."""
    from importlib.metadata import version

    from hispo_pl.benchmark import plan

    machine = plan.provenance().machine
    for package in ("torch", "numpy", "mujoco", "gymnasium-robotics", "minari"):
        assert machine[package] == version(package)
    # and the processor, whose kernels set a training run's last bits
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists() and "model name" in cpuinfo.read_text():
        assert machine["processor"] and machine["processor"] in cpuinfo.read_text()


def test_scratch_method_for():
    assert bm.scratch_method_for("hispo", {"hispo", "sc1", "scn"}) == "scn"
    assert bm.scratch_method_for("hispo", {"hispo", "sc1", "bc-scn"}) == "sc1"
    assert bm.scratch_method_for("bc-ftn", {"scn", "bc-sc1"}) == "bc-sc1"
    assert bm.scratch_method_for("bc-ftn", {"scn", "sc1"}) is None
    assert bm.scratch_method_for("ft1", set()) is None


def test_run_metrics_fwt_from_scratch_diagonal():
    run = _results([0.8, 0.6], [0.4, 0.6], mem=2.0, anchors={"high": 2, "low": 1})
    scratch = _results([0.5, 0.9], [0.1, 0.9])
    m = bm.run_metrics(run, scratch)
    assert m["PER"] == pytest.approx(0.5)  # (0.4 + 0.6) / 2
    assert m["BWT"] == pytest.approx(-0.2)  # ((0.4 - 0.8) + 0) / 2
    assert m["FWT"] == pytest.approx(0.0)  # ((0.8 - 0.5) + (0.6 - 0.9)) / 2
    assert m["MEM"] == 2.0 and m["anchors"] == {"high": 2.0, "low": 1.0}
    assert "FWT" not in bm.run_metrics(run)
    longer = StreamResults(
        stream=["a", "b", "c"],
        R=[[0.5, NAN, NAN], [0.5, 0.5, NAN], [0.5, 0.5, 0.5]],
        wall_time_s=[],
    )
    assert "FWT" not in bm.run_metrics(run, longer)  # another stream: no reference


def test_mean_std_and_format():
    assert bm.mean_std([0.8, 0.6]) == pytest.approx((0.7, 0.1))  # population std
    assert bm.mean_std([0.5]) == (0.5, 0.0)
    assert bm.format_mean_std(0.7, 0.1) == "70.0 ± 10.0"
    assert bm.format_mean_std(3.0, 0.25, scale=1, digits=2) == "3.00 ± 0.25"
    assert bm.format_mean_std(-0.0123, 0.0) == "-1.2 ± 0.0"


def _records() -> list[bm.RunRecord]:
    return [
        bm.RunRecord(
            "scn", 0, _results([0.5, 0.9], [0.1, 0.9], mem=2.0), LaunchRecord(steps_per_task=5)
        ),
        bm.RunRecord("scn", 1, _results([0.7, 0.9], [0.1, 0.9], mem=2.0)),
        bm.RunRecord(
            "hispo", 0, _results([0.8, 0.6], [0.8, 0.6], 1.5, {"high": 2, "low": 1}, minutes=2)
        ),
        bm.RunRecord("hispo", 1, _results([1.0, 0.8], [1.0, 0.8], 2.5, {"high": 2, "low": 2})),
        bm.RunRecord("bc-ft1", 0, _results([1.0, 1.0], [0.0, 1.0])),  # no MEM, no bc-sc*
    ]


def _rounded(value: tuple[float, float] | None) -> tuple[float, ...] | None:
    return None if value is None else tuple(round(v, 9) for v in value)


def test_aggregate_rows_fwt_per_seed_and_footnote():
    rows, notes = bm.aggregate(_records())
    assert [r.method for r in rows] == ["bc-ft1", "hispo", "scn"]
    bc, hispo, scn = rows
    assert hispo.seeds == [0, 1]
    assert _rounded(hispo.metrics["PER"]) == (0.8, 0.1)  # PER 0.7 and 0.9
    assert _rounded(hispo.metrics["BWT"]) == (0.0, 0.0)
    # FWT seed 0 vs scn seed 0: (0.3 - 0.3)/2 = 0; seed 1 vs scn seed 1: (0.3 - 0.1)/2 = 0.1
    assert _rounded(hispo.metrics["FWT"]) == (0.05, 0.05) and hispo.fwt_reference == "scn"
    assert _rounded(hispo.metrics["MEM"]) == (2.0, 0.5)
    assert list(hispo.metrics) == ["PER", "BWT", "FWT", "MEM"]  # the order of METRICS
    assert hispo.anchors == {"high": (2.0, 0.0), "low": (1.5, 0.5)}
    assert scn.metrics["FWT"] == (0.0, 0.0) and scn.anchors == {}
    assert "FWT" not in bc.metrics and "MEM" not in bc.metrics
    assert notes == ["bc-ft1: no FWT, no bc-scn or bc-sc1 run (with the same stream) for seed 0"]


def test_tables_markdown_and_csv():
    rows, notes = bm.aggregate(_records())
    md = bm.table_markdown(rows, notes, "pointmaze-1")
    assert md.startswith("# Benchmark: pointmaze-1\n")
    line = "| hispo | 2 | 80.0 ± 10.0 | 0.0 ± 0.0 | 5.0 ± 5.0 | 2.00 ± 0.50 |"
    assert line + " high 2.0 ± 0.0, low 1.5 ± 0.5 |" in md
    assert "| bc-ft1 | 1 | 50.0 | -50.0 | ¹ |  |  |" in md
    assert "¹ bc-ft1: no FWT" in md
    table = list(csv.DictReader(io.StringIO(bm.table_csv(rows))))
    hispo = next(r for r in table if r["method"] == "hispo")
    assert float(hispo["PER_mean"]) == 80.0 and float(hispo["FWT_std"]) == 5.0
    assert float(hispo["MEM_mean"]) == 2.0 and float(hispo["anchors_low_mean"]) == 1.5
    assert hispo["seeds"] == "2" and hispo["fwt_reference"] == "scn"
    bc = next(r for r in table if r["method"] == "bc-ft1")
    assert bc["FWT_mean"] == "" and bc["MEM_mean"] == "" and bc["anchors_high_mean"] == ""


def test_write_report_from_disk_and_report_only(tmp_path, capsys):
    for r in _records():
        run_dir = tmp_path / "runs" / r.method / f"seed{r.seed}"
        run_dir.mkdir(parents=True)
        RunDir(run_dir).write_results(r.results)
        if r.meta.to_json():
            RunDir(run_dir).write_run_record(r.meta)
    (tmp_path / "runs/hispo/seed7").mkdir()  # unfinished: no results.json, ignored
    assert [(r.method, r.seed) for r in bm.load_records(tmp_path)[0]] == [
        ("bc-ft1", 0),
        ("hispo", 0),
        ("hispo", 1),
        ("scn", 0),
        ("scn", 1),
    ]
    assert cli_main(["benchmark", "--out", str(tmp_path), "--report-only"]) == 0
    out = capsys.readouterr().out
    for name in ("table.md", "table.csv", "runtime.csv", "perf_vs_memory.png"):
        assert f"wrote {tmp_path / name}" in out
        assert (tmp_path / name).stat().st_size > 0
    heatmaps = sorted(p.name for p in tmp_path.glob("success_*.png"))  # one per method
    assert heatmaps == ["success_bc-ft1.png", "success_hispo.png", "success_scn.png"]
    runtime = list(csv.DictReader((tmp_path / "runtime.csv").open()))
    assert runtime[1] == {"method": "hispo", "seed": "0", "minutes": "2.0", "steps_per_task": ""}
    assert runtime[3]["steps_per_task"] == "5"
    assert cli_main(["benchmark", "--out", str(tmp_path / "empty"), "--report-only"]) == 2
    assert "no finished runs" in capsys.readouterr().err


def test_the_table_names_runs_that_trained_on_other_episodes(tmp_path, capsys):
    """A dataset made again on another machine can hold other episodes: the table says which
    runs read which, so methods are never compared on different data unsaid."""

    def read(*digests):
        return [{"dataset": f"hispo/{n}-expert-v0", "episodes": 9, "digest": d} for n, d in digests]

    same = read(("umaze", "u1"), ("umaze", "u1"))
    runs = {
        ("hispo", 0): same,
        ("scn", 0): same,
        ("scn", 1): read(("umaze", "u2"), ("umaze", "u2")),  # the dataset made again
        ("hispo", 1): [{"dataset": "hispo/umaze-expert-v0", "episodes": 9}] * 2,  # no digest
    }
    for (method, seed), datasets in runs.items():
        results = _results([0.5, 0.9], [0.5, 0.9])
        results.datasets = datasets
        run_dir = tmp_path / "runs" / method / f"seed{seed}"
        run_dir.mkdir(parents=True)
        RunDir(run_dir).write_results(results)
    assert cli_main(["benchmark", "--out", str(tmp_path), "--report-only"]) == 0
    capsys.readouterr()
    table = (tmp_path / "table.md").read_text()
    assert "## Runs that trained on other episodes" in table
    assert (
        "- hispo/umaze-expert-v0 (9 episodes): u1 for hispo seed 0, scn seed 0; u2 for scn seed 1"
        in table
    )
    for run_dir in (tmp_path / "runs").glob("*/seed*"):  # every run on the same episodes
        results = RunDir(run_dir).stream_results()
        results.datasets = same
        RunDir(run_dir).write_results(results)
    assert cli_main(["benchmark", "--out", str(tmp_path), "--report-only"]) == 0
    assert "other episodes" not in (tmp_path / "table.md").read_text()


def test_export_copies_small_files_and_the_report_rebuilds_with_decisions(tmp_path, capsys):
    decisions = [
        {
            "task": 0,
            "subspace": "low",
            "decision": "first",
            "eps": 0.1,
            "l_curr": 0.2,
            "anchors": 1,
        },
        {
            "task": 1,
            "subspace": "low",
            "decision": "prune",
            "eps": 0.1,
            "l_prev": 0.21,
            "l_curr": 0.2,
            "l_prev_train": 0.19,
            "l_curr_train": 0.18,
            "improvement": 0.02,
            "anchors": 1,
        },
        {"task": 2, "subspace": "low", "decision": "zero-shot", "anchors": 1},
    ]
    for r in _records():
        run_dir = tmp_path / "runs" / r.method / f"seed{r.seed}"
        run_dir.mkdir(parents=True)
        RunDir(run_dir).write_results(r.results)
        (run_dir / "task_01.ckpt").write_bytes(b"weights")  # never exported
        (run_dir / "config.yaml").write_text("seed_everything: 0\n")
        if r.method == "hispo":
            lines = "".join(json.dumps(d) + "\n" for d in decisions)
            (run_dir / "decisions.jsonl").write_text(lines)
    dest = tmp_path / "docs" / "pointmaze-1"
    args = ["benchmark", "--out", str(tmp_path), "--report-only", "--export", str(dest)]
    assert cli_main(args) == 0
    assert "exported" in capsys.readouterr().out
    assert sorted(p.name for p in (dest / "hispo" / "seed0").iterdir()) == [
        "config.yaml",
        "decisions.jsonl",
        "results.json",
    ]
    assert not list(dest.rglob("*.ckpt"))
    assert "| hispo | 2 | 80.0 ± 10.0 |" in (dest / "table.md").read_text()
    # the committed layout (no runs/) is read back by --report-only alone
    (dest / "table.md").unlink()
    assert cli_main(["benchmark", "--out", str(dest), "--report-only"]) == 0
    assert "| hispo | 2 | 80.0 ± 10.0 |" in (dest / "table.md").read_text()
    md = (dest / "decisions.md").read_text()
    assert (
        "| hispo | 0 | 2 | low | 0.2100 | 0.2000 | 1.050 | 0.1 | 1.056 | +2.0% | prune | 1 |" in md
    )
    assert "zero-shot" not in md and md.count("| hispo |") == 4  # 2 seeds x (first, prune)


def test_critic_decisions_go_to_their_own_table():
    critic = {
        "task": 1,
        "subspace": "policy",
        "decision": "prune",
        "rule": "critic",
        "eps": 0.1,
        "w_prev": 0.5,
        "w_curr": 0.52,
        "l_prev": 0.3,
        "l_curr": 0.2,
        "q_action_std": 0.01,
        "q_state_std": 0.2,
        "action_dependence": 0.05,
        "anchors": 1,
    }
    loss = {"task": 1, "subspace": "policy", "decision": "keep", "eps": 0.1, "l_prev": 0.3}
    empty = StreamResults(stream=[], R=[], wall_time_s=[])
    records = [
        bm.RunRecord("csp", 0, empty, decisions=[Decision.from_json(critic)]),
        bm.RunRecord(
            "cspo", 0, empty, decisions=[Decision.from_json({**loss, "l_curr": 0.2, "anchors": 2})]
        ),
    ]
    md = bm.critic_markdown(records, "pointmaze-1")
    row = "| csp | 0 | 2 | 0.5000 | 0.5200 | 0.1 | 1.500 | 0.0100 | 0.2000 | 0.050 | prune | 1 |"
    assert md.startswith("# Critic decisions: pointmaze-1") and row in md
    assert "| cspo |" not in md  # loss rules stay in decisions.md
    assert "| csp |" not in bm.loss_decisions_markdown(records)
    assert bm.critic_markdown(records[1:]) == ""


def test_report_without_matplotlib_writes_tables(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)  # import fails
    rows, _ = bm.aggregate(_records())
    assert not bm.plot_perf_vs_memory(rows, tmp_path / "fig.png")
    assert "matplotlib is not installed" in capsys.readouterr().out
    assert not (tmp_path / "fig.png").exists()


def test_cli_help_and_errors(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        cli_main(["benchmark", "--help"])
    assert e.value.code == 0
    help_text = capsys.readouterr().out
    assert (
        "--steps-per-task" in help_text and "100000" in help_text and "--report-only" in help_text
    )
    configs = benchmark_config_dir(tmp_path, ["hispo"])
    for args, message in (
        (["--stream", "pointmaze-1", "--methods", "ewc"], "unknown method(s) ewc; known"),
        (["--methods", "hispo"], "--stream is required"),
        (["--stream", "pointmaze-1", "--seeds", "x"], "--seeds takes"),
    ):
        argv = ["benchmark", "--out", str(tmp_path / "o"), "--config-dir", str(configs), *args]
        assert cli_main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1 and "usage:" not in err


def test_dry_run_prints_commands_and_writes_nothing(tmp_path, capsys):
    configs = benchmark_config_dir(tmp_path, ["hispo", "scn"])
    out = tmp_path / "out"
    args = ["benchmark", "--stream", "pointmaze-1", "--seeds", "0,4", "--out", str(out)]
    extra = ["--", "--trainer.max_steps", "7"]
    assert cli_main([*args, "--config-dir", str(configs), "--dry-run", *extra]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 4 and lines[0].startswith("[benchmark] hispo/seed0 (to run): ")
    assert "--seed_everything 4" in lines[3] and lines[3].endswith("--trainer.max_steps 7")
    assert not out.exists()
    # the overrides are checked as fit would parse them
    assert cli_main([*args, "--config-dir", str(configs), "--dry-run", "--", "--x", "1"]) == 2
    assert "--x" in capsys.readouterr().err
