"""``benchmarks/stream_speed.py`` compares the product's own runs: each is the ``fit`` command the
benchmark launches for (stream, method, seed), and the reference child really trains on the
reference path (every switch of the fast path reads it while the command runs)."""

from __future__ import annotations

import argparse
from pathlib import Path

from helpers import load_benchmark, write_run_files

from hispo_pl.benchmark.plan import fit_argv, stream_config_path
from hispo_pl.nn import fast

ROOT = Path(__file__).resolve().parents[2]
script = load_benchmark("stream_speed")


def test_runs_are_the_benchmarks_fit_commands(tmp_path):
    args = argparse.Namespace(
        stream="pointmaze-1",
        method="hispo",
        seed=3,
        steps_per_task=50,
        out=str(tmp_path),
        config_dir=str(ROOT / "configs"),
    )
    runs = script.planned(args)
    stream = stream_config_path("pointmaze-1", ROOT / "configs")
    method = (ROOT / "configs/methods/hispo.yaml").resolve()
    for path in script.PATHS:
        name = f"hispo-{path}"
        run_dir, argv = runs[path]
        assert run_dir == tmp_path / "runs" / name / "seed3"
        assert argv == fit_argv(stream, method, name, 3, tmp_path, 1, 50)
        assert "--trainer.max_steps" in argv and str(method) in argv


def test_reference_child_runs_fit_on_the_reference_path(monkeypatch):
    seen = []

    def fake_main(argv):
        seen.append((list(argv), fast.enabled()))
        return 0

    monkeypatch.setattr("hispo_pl.cli.main", fake_main)
    assert script.main(["--child", "reference", "--", "fit", "--config", "x.yaml"]) == 0
    assert script.main(["--child", "fast", "--", "fit"]) == 0
    assert seen == [(["fit", "--config", "x.yaml"], False), (["fit"], True)]
    assert fast.enabled()


def test_report_only_reads_exported_runs(tmp_path, capsys):
    for path, minutes in (("reference", 13.0), ("fast", 10.0)):
        results = {
            "stream": ["pointmaze-umaze-N[500]", "pointmaze-umaze-PO[500]"],
            "R": [[1.0, None], [1.0, 0.9 if path == "fast" else 0.95]],
            "PER": 0.95,
            "BWT": 0.0,
            "MEM": 2.0,
            "anchors": {"high": 1, "low": 2},
            "wall_time_s": [60 * minutes / 2] * 2,
            "phase_time_s": [{"training": 60 * minutes / 2 - 6, "evaluation": 6}] * 2,
        }
        write_run_files(tmp_path / f"hispo-{path}" / "seed0", results)
    assert script.main(["--report-only", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    (total,) = [line.split() for line in out.splitlines() if line.startswith("all ")]
    assert total == ["all", "13.00", "10.00", "1.30"]
    assert "fast       training 9.80 (98%), evaluation 0.20 (2%)" in out
    assert "largest success difference between the two R matrices: 5.0 points" in out
