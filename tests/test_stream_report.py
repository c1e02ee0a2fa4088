"""The stream report's pure parts: which values a logger receives and the text tables."""

from __future__ import annotations

import numpy as np
import pytest

from hispo_pl.figures import simplex_figure, success_matrix_figure, to_triangle
from hispo_pl.stream_report import (
    alpha_metrics,
    decisions_markdown,
    stream_metrics,
    success_markdown,
    task_row_metrics,
)


def test_task_row_metrics_cover_every_task_and_the_mean_of_those_seen():
    metrics = task_row_metrics(1, [1.0, 0.5, 0.2])  # the third task: a zero-shot point
    assert metrics == {
        "stream/success/T01": 1.0,
        "stream/success/T02": 0.5,
        "stream/success/T03": 0.2,
        "stream/success/mean_seen": 0.75,
    }


def test_stream_and_alpha_metrics():
    results = {"PER": 0.9, "BWT": 0.0, "FWT": None, "MEM": 2.07}
    assert stream_metrics(results) == {"stream/PER": 0.9, "stream/BWT": 0.0, "stream/MEM": 2.07}
    alphas = {"low": [[1.0, 0.0], [0.25, 0.75]]}
    assert alpha_metrics(alphas) == {
        "alpha/low/T01/anchor_1": 1.0,
        "alpha/low/T01/anchor_2": 0.0,
        "alpha/low/T02/anchor_1": 0.25,
        "alpha/low/T02/anchor_2": 0.75,
    }


def test_tables():
    assert success_markdown([[1.0, None], [0.98, 0.5]]).splitlines()[2:] == [
        "| T01 | 100 |  |",
        "| T02 | 98 | 50 |",
    ]
    rows = decisions_markdown(
        [
            {"task": 0, "subspace": "low", "decision": "first", "l_curr": 0.2, "eps": 0.1},
            {
                "task": 1,
                "subspace": "low",
                "decision": "prune",
                "l_prev": 0.21,
                "l_curr": 0.2,
                "eps": 0.1,
                "anchors": 1,
            },
        ]
    ).splitlines()
    assert rows[2].startswith("| T01 | low | first |  | 0.2000 |  | 1.10 |")
    assert rows[3] == "| T02 | low | prune | 0.2100 | 0.2000 | 1.050 | 1.10 | 1 |"


def test_figures():
    fig = success_matrix_figure([[1.0, None], [0.9, 0.8]])
    texts = sorted(t.get_text() for t in fig.axes[0].texts)
    assert texts == ["100", "80", "90"]  # the untrained cell stays blank
    np.testing.assert_allclose(to_triangle(np.eye(3)), [[0, 0], [1, 0], [0.5, np.sqrt(3) / 2]])
    with pytest.raises(ValueError, match="3 anchors"):
        simplex_figure([[0.5, 0.5]], "low")


def test_console_lines():
    from hispo_pl.console import duration, task_summary

    assert [duration(s) for s in (52, 247, 3725)] == ["52s", "4m07s", "1h02m"]
    decisions = [
        {
            "task": 1,
            "subspace": "high",
            "decision": "keep",
            "l_prev": 0.9,
            "l_curr": 0.05,
            "eps": 0.1,
        },
        {
            "task": 1,
            "subspace": "low",
            "decision": "prune",
            "l_prev": 0.21,
            "l_curr": 0.2,
            "eps": 0.1,
        },
        {"task": 0, "subspace": "low", "decision": "first", "l_curr": 0.2, "eps": 0.1},
    ]
    assert task_summary(1, 4, 247, [1.0, 0.82, 0.1, 0.0], decisions) == (
        "task 2/4 done in 4m07s: success 82 % (earlier tasks: mean 100 %); "
        "high keep (18.00 vs 1.10), low prune (1.05 vs 1.10)"
    )
    assert task_summary(0, 4, 52, [0.97, 0.1, 0.0, 0.0], decisions) == (
        "task 1/4 done in 52s: success 97 %"
    )
    phases = {"training": 150.2, "evaluation": 61, "search": 30}
    assert task_summary(0, 4, 247, [0.97, 0.1, 0.0, 0.0], decisions, phases) == (
        "task 1/4 done in 4m07s (training 2m30s, evaluation 1m01s, search 30s): success 97 %"
    )
    critic = {"task": 2, "subspace": "policy", "decision": "prune", "rule": "critic", "eps": 0.1}
    critic |= {"w_prev": -0.5, "w_curr": -0.48, "l_prev": 0.3, "l_curr": 0.1}
    assert task_summary(2, 4, 52, [1.0, 1.0, 1.0, 0.0], [critic]).endswith(
        "; policy prune (W -0.480 vs -0.450)"  # the critic's bar, not the losses' ratio
    )


def test_zero_shot_records_have_no_pruning_tolerance():
    row = decisions_markdown(
        [{"task": 1, "subspace": "low", "decision": "zero-shot", "eps": {"low": 1.0}}]
    ).splitlines()[2]
    assert row == "| T02 | low | zero-shot |  |  |  |  |  |"
