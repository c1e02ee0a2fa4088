"""``benchmarks/gpu_speed.py`` runs on a machine without a GPU: its CPU rows are measured, its
GPU rows, the shared-GPU section and the stream say they were skipped."""

from __future__ import annotations

import sys

import pytest
import torch
from helpers import load_benchmark


@pytest.mark.e2e
def test_the_gpu_benchmark_runs_without_a_gpu(tiny_umaze, monkeypatch, capsys):
    gpu_speed = load_benchmark("gpu_speed")
    args = ["--task", "pointmaze-umaze-N[6]", "--methods", "HBC", "HiSPO-4", "--steps", "2"]
    args += ["--cpu-steps", "2", "--warmup", "2", "--rounds", "1", "--group", "2"]
    args += ["--batch-sizes", "32", "--cpu-batch-sizes", "32", "--workers", "1"]
    args += ["--worker-seconds", "1", "--no-stream"]
    monkeypatch.setattr(sys, "argv", ["gpu_speed.py", *args])
    threads = torch.get_num_threads()
    try:
        gpu_speed.main()
    finally:
        torch.set_num_threads(threads)
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.startswith("cpu ")]
    assert [row[1] for row in rows] == ["HBC", "HiSPO-4"]
    for row in rows:  # ref fast captured c/f capt-ms | ref fast captured xG c/f
        numbers = [float(x) for x in row[3:] if x not in ("|", "-")]  # "-": no capture
        assert len(numbers) == 9 and all(x > 0 for x in numbers), row
    if not torch.cuda.is_available():
        assert "cuda   HBC HiSPO-4 at [32]: skipped: no CUDA" in out
        assert "workers: skipped: no CUDA" in out
    assert "stream: not asked (--no-stream)" in out
