"""Stream metrics: hand-worked PER/BWT/FWT values, validation, memory and the results table."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from hispo_pl.metrics import (
    UNKNOWN,
    continual_metrics,
    memory_ratio,
    module_bytes,
    results_row_table,
)
from hispo_pl.results import StreamResults, summarize_runs

NAN = float("nan")

# R[i, k]: success on task k after training task i; upper triangle not yet measured.
R3 = [
    [0.8, NAN, NAN],
    [0.6, 0.9, NAN],
    [0.5, 0.7, 1.0],
]
SCRATCH3 = [0.7, 0.8, 0.9]
# Hand-worked:
#   PER = (0.5 + 0.7 + 1.0) / 3                         = 2.2 / 3  = 0.7333...
#   BWT = ((0.5-0.8) + (0.7-0.9) + (1.0-1.0)) / 3      = -0.5 / 3 = -0.1666...
#   FWT = ((0.8-0.7) + (0.9-0.8) + (1.0-0.9)) / 3      = 0.3 / 3  = 0.1
PER3, BWT3, FWT3 = 0.7333333333333333, -0.16666666666666666, 0.1


def test_hand_computed_n3():
    m = continual_metrics(R3, SCRATCH3)
    assert set(m) == {"PER", "BWT", "FWT"}
    assert m["PER"] == pytest.approx(PER3)
    assert m["BWT"] == pytest.approx(BWT3)
    assert m["FWT"] == pytest.approx(FWT3)
    assert all(isinstance(v, float) for v in m.values())


def test_fwt_absent_without_scratch():
    m = continual_metrics(R3)
    assert set(m) == {"PER", "BWT"}
    assert m["PER"] == pytest.approx(PER3)
    assert m["BWT"] == pytest.approx(BWT3)


def test_fwt_vector_and_matrix_forms_agree():
    # Only the diagonal of a from-scratch matrix is used; off-diagonal may be anything (even NaN).
    scratch_matrix = np.full((3, 3), NAN)
    np.fill_diagonal(scratch_matrix, SCRATCH3)
    from_vector = continual_metrics(R3, SCRATCH3)["FWT"]
    from_matrix = continual_metrics(R3, scratch_matrix)["FWT"]
    assert from_vector == from_matrix
    assert from_matrix == pytest.approx(FWT3)


def test_no_forgetting_gives_exact_zero_bwt():
    # Each column constant from the diagonal down: nothing forgotten, nothing gained.
    R = [
        [0.25, NAN, NAN],
        [0.25, 0.5, NAN],
        [0.25, 0.5, 0.75],
    ]
    m = continual_metrics(R)
    assert m["BWT"] == 0.0
    assert m["PER"] == pytest.approx(0.5)


def test_forgetting_gives_negative_bwt():
    # Task 0 drops 1.0 -> 0.0 by the end, task 1 drops 1.0 -> 0.4, last task untouched.
    R = [
        [1.0, NAN, NAN],
        [0.5, 1.0, NAN],
        [0.0, 0.4, 1.0],
    ]
    m = continual_metrics(R)
    assert m["BWT"] == pytest.approx(-(1.0 + 0.6) / 3)
    assert m["BWT"] < 0
    assert m["PER"] == pytest.approx(1.4 / 3)


def test_upper_triangle_is_ignored():
    filled = np.array(R3)
    filled[np.triu_indices(3, k=1)] = [0.11, 0.22, 0.33]  # e.g. zero-shot evals of future tasks
    assert continual_metrics(filled, SCRATCH3) == continual_metrics(R3, SCRATCH3)


def test_single_task():
    m = continual_metrics([[0.4]], [0.1])
    assert m["PER"] == pytest.approx(0.4)
    assert m["BWT"] == 0.0
    assert m["FWT"] == pytest.approx(0.3)
    assert continual_metrics(np.array([[0.4]]), np.array([[0.1]]))["FWT"] == pytest.approx(0.3)


@pytest.mark.parametrize(
    ("R", "match"),
    [
        ([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]], "square"),
        ([0.1, 0.2], "square"),
        (np.zeros((0, 0)), "at least one task"),
        ([[NAN, NAN], [0.1, 0.2]], r"finite on and below the diagonal; R\[0, 0\]"),
        ([[0.1, NAN], [NAN, 0.2]], r"R\[1, 0\]"),
        ([[0.1, NAN], [0.3, math.inf]], r"R\[1, 1\]"),
    ],
)
def test_invalid_results_matrix(R, match):
    with pytest.raises(ValueError, match=match):
        continual_metrics(R)


@pytest.mark.parametrize(
    ("scratch", "match"),
    [
        ([0.7, 0.8], "length N=3"),
        ([0.7, 0.8, 0.9, 1.0], "length N=3"),
        (np.zeros((2, 2)), "3×3"),
        (np.zeros((3, 3, 1)), "vector or an 3×3 matrix"),
        ([0.7, NAN, 0.9], "finite"),
    ],
)
def test_invalid_scratch(scratch, match):
    with pytest.raises(ValueError, match=match):
        continual_metrics(R3, scratch)


def test_memory_ratio():
    assert memory_ratio(96, 32) == 3.0
    assert memory_ratio(0, 32) == 0.0
    assert memory_ratio(16, 32) == 0.5
    with pytest.raises(ValueError, match="reference_bytes must be positive"):
        memory_ratio(10, 0)
    with pytest.raises(ValueError, match="reference_bytes must be positive"):
        memory_ratio(10, -4)
    with pytest.raises(ValueError, match="stored_bytes"):
        memory_ratio(-1, 32)


def test_module_bytes_linear_and_buffers():
    lin = torch.nn.Linear(3, 2)  # 3*2 weights + 2 biases = 8 float32 = 32 bytes
    assert module_bytes(lin) == 32
    lin.register_buffer("stats", torch.zeros(4))  # 4 float32 = 16 bytes
    lin.register_buffer("anchor", torch.zeros(2, dtype=torch.float64))  # 2 float64 = 16 bytes
    assert module_bytes(lin) == 64
    assert module_bytes(lin, include_buffers=False) == 32
    assert memory_ratio(module_bytes(lin), module_bytes(torch.nn.Linear(3, 2))) == 2.0


def test_module_bytes_nested_and_half():
    net = torch.nn.Sequential(torch.nn.Linear(3, 2), torch.nn.Linear(2, 1)).half()
    # (6 + 2) + (2 + 1) = 11 float16 = 22 bytes
    assert module_bytes(net) == 22


def test_results_row_table_format():
    table = results_row_table(R3)
    lines = table.splitlines()
    assert len(lines) == 4  # header + one row per training step
    assert lines[0].split() == ["T01", "T02", "T03"]
    assert lines[1].startswith("after T01")
    assert lines[3].startswith("after T03")
    assert lines[1].split()[2:] == ["80.0", UNKNOWN, UNKNOWN]
    assert lines[2].split()[2:] == ["60.0", "90.0", UNKNOWN]
    assert lines[3].split()[2:] == ["50.0", "70.0", "100.0"]
    assert UNKNOWN == "·"
    # Columns line up: every line has the same width.
    assert len({len(line) for line in lines}) == 1


def test_results_row_table_one_decimal_and_wide_index():
    table = results_row_table([[0.12345]])
    assert "12.3" in table and "12.35" not in table
    big = np.full((100, 100), NAN)
    lines = results_row_table(big).splitlines()
    assert lines[0].split()[0] == "T001" and lines[0].split()[-1] == "T100"
    assert lines[-1].startswith("after T100")
    with pytest.raises(ValueError, match="2-D"):
        results_row_table([0.1, 0.2])


def test_summarize_runs_mean_and_std_per_metric():
    R = [[1.0, None], [1.0, 1.0]]
    runs = [
        StreamResults(stream=["a", "b"], R=R, wall_time_s=[60, 60], metrics=m)
        for m in ({"PER": 0.9, "BWT": 0.0, "MEM": 2.0}, {"PER": 1.0, "BWT": -0.02, "MEM": 3.0})
    ]
    runs[1].metrics["FWT"], runs[1].wall_time_s = 0.1, [120, 120]
    s = summarize_runs(runs)
    assert s["PER"] == pytest.approx((0.95, 0.05))
    assert s["BWT"] == pytest.approx((-0.01, 0.01))
    assert s["MEM"] == pytest.approx((2.5, 0.5))
    assert s["minutes"] == pytest.approx((3.0, 1.0))
    assert "FWT" not in s  # only one run has it: no mean over a subset
    with pytest.raises(ValueError, match="no runs"):
        summarize_runs([])
