"""``benchmarks/evaluation_reuse.py`` measures rows of R the way a task's end does: both ways
it finds the finished run's R, the reusing way with the rollouts the loop ran."""

from __future__ import annotations

from helpers import fit_tiny_stream, load_benchmark

from hispo_pl.rundir import RunDir

evaluation_reuse = load_benchmark("evaluation_reuse")
REPEATED = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]", "pointmaze-umaze-N[3]"]


def test_rows_measured_again_are_the_runs_r(tiny_umaze, tmp_path):
    results, run_dir = fit_tiny_stream("scn", tmp_path, REPEATED)
    reused, every = evaluation_reuse.measure_rows(RunDir(run_dir))
    assert reused.rows == every.rows == results["R"]
    # as test_rollout_reuse.py counts the loop's: the finished tasks' entries are reused
    assert reused.ran == [2, 2, 1] and every.ran == [3, 3, 3]
