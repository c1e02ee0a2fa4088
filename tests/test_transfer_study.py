"""The transfer study measures through the product: its runs are ``hispo-pl fit`` streams, and
the decisions it reads equal those of the same stream run by hand."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
from helpers import tiny_stream_args

from hispo_pl.cli import main

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location(
    "transfer_study", ROOT / "benchmarks/transfer_study.py"
)
study = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study)


def test_pairs_name_the_papers_tasks():
    assert study.pair_stream("U-N:L-N") == ["pointmaze-umaze-N[500]", "pointmaze-large-N[500]"]
    assert study.pair_stream("M-IO:M", episodes=3) == [
        "pointmaze-medium-IO[3]",
        "pointmaze-medium-N[3]",
    ]
    with pytest.raises(SystemExit, match="FIRST:SECOND"):
        study.pair_stream("U-N")


# a smaller search than hispo.yaml (1024 candidates, 16 batches) and one rollout episode per
# evaluation, the same in both runs: all the exact comparison needs
SMALL_SEARCH = ["--search_candidates", "32", "--search_batches", "4", "--eval_episodes", "1"]


def test_study_decisions_equal_the_products_own_run(tiny_umaze, tmp_path):
    """Exact: both are the same stream run in this process, with one thread and the same
    kernels, so their losses agree bit for bit."""
    setting, pair = "subgoal-fixed", "U-N:U-N"
    args = study.fit_args(
        tmp_path / "study",
        setting,
        pair,
        0,
        steps=5,
        episodes=2,
        task_episodes=3,
        extra=["--data.batch_size", "64", *SMALL_SEARCH],
    )
    assert main(args) == 0
    got = study.second_task_records(study.run_dir(tmp_path / "study", setting, pair, 0))

    stream = ["pointmaze-umaze-N[3]", "pointmaze-umaze-N[3]"]
    assert (
        main(
            tiny_stream_args(
                "hispo", tmp_path / "direct", stream, *study.SETTINGS[setting], *SMALL_SEARCH
            )
        )
        == 0
    )
    direct = study.second_task_records(tmp_path / "direct" / "pointmaze-1" / "seed0")

    assert set(got) == {"high", "low"}
    for name in got:
        for key in ("l_prev", "l_curr", "l_prev_train", "l_curr_train", "improvement", "decision"):
            assert got[name][key] == direct[name][key], (name, key)
    text = study.table(tmp_path / "study", [setting], [pair], [0])
    assert text.count("| subgoal-fixed | U-N:U-N | 0 |") == 2


def test_the_committed_table_rebuilds_from_the_committed_run_files():
    """Exact text: the table formats the committed files' numbers with float64 divisions, which
    every IEEE 754 machine rounds alike; nothing is retrained."""
    out = ROOT / "docs" / "results" / "transfer"
    text = study.table(out, ["obs-fixed", "goal-fixed"], ["U-N:U-N"], [0])
    assert text == (out / "table.md").read_text()
    assert text in (ROOT / "docs" / "studies" / "transfer.md").read_text()
