"""``hispo-pl benchmark`` running: the launchers on fake commands, and two end-to-end runs on a
tiny stream (local processes, a local Ray instance)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from helpers import BENCH_TINY, BENCH_TINY_OVERRIDES, benchmark_config_dir

from hispo_pl import benchmark as bm
from hispo_pl.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[2]
NAN = None  # JSON's null above the diagonal of R


# --- launchers on fake commands ---------------------------------------------------------------


def _fake_run(tmp_path: Path, name: str, code: str) -> bm.PlannedRun:
    run_dir = tmp_path / "runs" / name / "seed0"
    return bm.PlannedRun(name, 0, run_dir, ("-c", code))


def test_run_local_reports_failures_and_continues(tmp_path, capsys):
    ok = _fake_run(
        tmp_path,
        "ok",
        "import json, pathlib; print('training');"
        f"pathlib.Path({str(tmp_path / 'runs/ok/seed0/results.json')!r}).write_text("
        "json.dumps({'PER': 0.5, 'wall_time_s': [60, 60]}))",
    )
    bad = _fake_run(tmp_path, "bad", "import sys; print('step 1'); print('boom'); sys.exit(3)")
    silent = _fake_run(tmp_path, "silent", "pass")  # exit 0 without results.json
    reporter = bm.Reporter(total=3)
    bm.run_local([bad, ok, silent], 2, reporter, {"PYTHONUNBUFFERED": "1"})
    reporter.close()
    out, err = capsys.readouterr()
    # into a pipe: lines, and progress as a line at each tenth, never a carriage return
    assert "\r" not in out + err and "[hispo-pl] benchmark: 3/3 runs (100 %)" in err
    assert "[benchmark] ok seed 0: PER 50.0  2.0 min" in out
    assert f"FAILED bad seed 0 (exit 3); log: {bad.log_path}" in out
    assert "    step 1\n    boom" in out
    assert "FAILED silent seed 0 (exit 0, no results.json)" in out
    assert {r.name for r in reporter.failed} == {"bad/seed0", "silent/seed0"}
    assert "training" in ok.log_path.read_text()


# --- end to end on the tiny stream ------------------------------------------------------------


def _benchmark_args(configs: Path, out: Path, methods: str, *launcher: str) -> list[str]:
    return [
        "benchmark",
        "--stream",
        "pointmaze-1",
        "--methods",
        methods,
        "--seeds",
        "1",
        "--out",
        str(out),
        "--config-dir",
        str(configs),
        "--steps-per-task",
        "5",
        "--workers",
        "2",
        "--num-threads",
        "1",
        *launcher,
        "--",
        *BENCH_TINY_OVERRIDES,
    ]


@pytest.mark.e2e
def test_benchmark_local_end_to_end_and_skip(tiny_umaze, tmp_path, capsys):
    configs = benchmark_config_dir(tmp_path, ["hispo", "scn"])
    out = tmp_path / "out"
    assert cli_main(_benchmark_args(configs, out, "all")) == 0
    printed = capsys.readouterr().out
    assert "2 runs (2 methods x 1 seeds), 2 to run" in printed
    assert "[benchmark] hispo seed 0: PER" in printed and "[benchmark] scn seed 0: PER" in printed
    for method in ("hispo", "scn"):
        run_dir = out / "runs" / method / "seed0"
        results = json.loads((run_dir / "results.json").read_text())
        assert results["stream"] == BENCH_TINY and len(results["R"]) == 2
        meta = json.loads((run_dir / "run.json").read_text())
        assert meta["steps_per_task"] == 5 and "--num_threads 1" in meta["command"]
        assert "=== " in (run_dir / "fit.log").read_text()
    rows = {r["method"]: r for r in csv.DictReader((out / "table.csv").open())}
    assert set(rows) == {"hispo", "scn"}
    assert rows["scn"]["FWT_mean"] == "0.0" and rows["hispo"]["FWT_mean"] != ""
    assert rows["hispo"]["anchors_high_mean"] != "" and rows["hispo"]["seeds"] == "1"
    assert "| hispo | 1 |" in (out / "table.md").read_text()
    runtime = list(csv.DictReader((out / "runtime.csv").open()))
    assert [(r["method"], r["steps_per_task"]) for r in runtime] == [("hispo", "5"), ("scn", "5")]
    assert (out / "perf_vs_memory.png").stat().st_size > 0

    # the same command again, scn as if interrupted after its last task (results.json not
    # yet written): hispo is skipped with its log untouched, scn resumes with the same command
    log = out / "runs/hispo/seed0/fit.log"
    before = log.stat().st_mtime_ns, log.read_text()
    (out / "runs/scn/seed0/results.json").unlink()
    assert cli_main(_benchmark_args(configs, out, "all")) == 0
    printed = capsys.readouterr().out
    assert "hispo/seed0: skipped, results.json exists" in printed
    assert "scn/seed0: resuming an interrupted run" in printed and "1 to run" in printed
    assert (log.stat().st_mtime_ns, log.read_text()) == before
    scn_log = (out / "runs/scn/seed0/fit.log").read_text()
    assert scn_log.count("=== ") == 2 and "tasks 1..2 already trained" in scn_log
    assert (out / "runs/scn/seed0/results.json").exists()


@pytest.mark.slow  # the local end-to-end above runs the same plan by default; Ray adds ~20 s
def test_benchmark_ray_end_to_end(tiny_umaze, tmp_path, capsys):
    pytest.importorskip("ray")
    configs = benchmark_config_dir(tmp_path, ["hispo"])
    out = tmp_path / "out"
    args = _benchmark_args(configs, out, "hispo", "--launcher", "ray", "--address", "local")
    assert cli_main(args) == 0
    printed = capsys.readouterr().out
    assert "1 to run with the ray launcher" in printed
    assert "[benchmark] hispo seed 0: PER" in printed
    results = json.loads((out / "runs/hispo/seed0/results.json").read_text())
    assert results["stream"] == BENCH_TINY
    table = (out / "table.md").read_text()
    assert "| hispo | 1 |" in table and "¹ hispo: no FWT, no scn or sc1 run" in table

    import ray

    assert not ray.is_initialized()  # the runner shut down the instance it started
