"""Learning curves: a single-task run's curve is read from its result.json, curves of seeds are
averaged step by step, the budget is the first step from which every curve stays near its end,
and the study's report is what its committed runs give (the page embeds it)."""

from __future__ import annotations

import json

import pytest
from helpers import load_benchmark

from hispo_pl.benchmark.curves import (
    CurveStudy,
    MeanCurve,
    choose_budget,
    curves_figure,
    curves_markdown,
    load_curves,
    mean_curve,
)
from hispo_pl.results import TaskFitResult
from hispo_pl.rundir import RunDir
from lab.embed import embed_reports

study_script = load_benchmark("learning_curves")


def _curve(*successes: float, every: int = 10) -> list[dict]:
    return [{"step": every * (i + 1), "success": s} for i, s in enumerate(successes)]


def test_mean_curve_averages_seeds_step_by_step():
    curve = mean_curve([_curve(0.5, 0.9), _curve(0.7, 1.0)])
    assert curve.steps == (10, 20) and curve.seeds == 2
    assert curve.mean == pytest.approx((60.0, 95.0)) and curve.std == pytest.approx((10.0, 5.0))
    with pytest.raises(ValueError, match="different steps"):
        mean_curve([_curve(0.5, 0.9), _curve(0.5, 0.9, every=20)])


def test_budget_is_the_first_step_every_curve_stays_within_tolerance_of_its_end():
    def c(*mean):
        return MeanCurve(tuple(range(1, len(mean) + 1)), mean, (0.0,) * len(mean), 2)

    assert choose_budget({"u": c(99, 100, 100), "l": c(20, 99, 99.5)}, 2.0) == 2
    # a curve that comes within tolerance, then leaves it again, has not converged there
    assert choose_budget({"u": c(98, 90, 99, 100)}, 2.0) == 3
    assert choose_budget({"u": c(10, 50, 96)}, 2.0) == 3  # the last step when none earlier
    assert choose_budget({"u": c(96, 97, 98)}, 2.0) == 1


def _write_run(folder, name, seed, successes):
    run = RunDir(folder / "runs" / name / f"seed{seed}")
    run.path.mkdir(parents=True)
    curve = _curve(*successes)
    last = {"episode_length": 100.0, "flip_rate": 0.0, **curve[-1]}
    header = {"method": "HBC", "task": "pointmaze-umaze-N", "episodes": 4, "seconds": 1.0}
    run.write_result(TaskFitResult(**header, **last, curve=curve))


def test_report_names_the_budget_once_every_task_of_its_setting_has_runs(tmp_path):
    study = CurveStudy(("hbc", "bc"), ("pointmaze-umaze", "pointmaze-large"), "hbc", 2.0)
    _write_run(tmp_path, "hbc-pointmaze-umaze", 0, (0.9, 1.0, 1.0))
    _write_run(tmp_path, "bc-pointmaze-umaze", 0, (0.5, 0.6, 0.7))
    text = curves_markdown(study, load_curves(tmp_path, study))
    assert "| hbc | pointmaze-umaze | 1 | 90.0 | 100.0 | 100.0 |" in text
    assert "not chosen yet (hbc lacks pointmaze-large)" in text
    for seed, successes in ((0, (0.2, 0.8, 0.9)), (1, (0.4, 0.9, 0.9))):
        _write_run(tmp_path, "hbc-pointmaze-large", seed, successes)
    text = curves_markdown(study, load_curves(tmp_path, study))
    assert "| hbc | pointmaze-large | 2 | 30.0 ± 10.0 | 85.0 ± 5.0 | 90.0 ± 0.0 |" in text
    assert "Budget B = 30 steps" in text  # large is 5 points short at step 20


def test_a_study_at_a_chosen_budget_reports_no_budget_of_its_own(tmp_path):
    """A study of what a setting changes at a budget already chosen (``"budget_setting":
    null``) shows its curves and chooses no budget, in its report and its figure."""
    _write_run(tmp_path, "hbc-pointmaze-umaze", 0, (0.9, 1.0, 1.0))
    args = ["--tasks", "pointmaze-umaze", "--settings", "hbc", "--export", str(tmp_path)]
    assert study_script.main([*args, "--report-only", "--no-budget"]) == 0
    assert json.loads((tmp_path / "curves.json").read_text())["budget_setting"] is None
    study = CurveStudy.read(tmp_path)
    curves = load_curves(tmp_path, study)
    text = curves_markdown(study, curves)
    assert "| hbc | pointmaze-umaze | 1 | 90.0 | 100.0 | 100.0 |" in text
    assert "Budget" not in text
    figure = curves_figure(study, curves)
    assert not any("B =" in t.get_text() for ax in figure.axes for t in ax.texts)


@pytest.mark.e2e
def test_the_study_runs_the_products_fit_exports_and_its_page_embeds_the_report(
    tiny_umaze, tmp_path, monkeypatch
):
    out, export = tmp_path / "work", tmp_path / "docs" / "curves"
    args = ["--tasks", "pointmaze-umaze-N[6]", "--settings", "hbc", "--seeds", "0"]
    args += ["--steps", "4", "--every", "2", "--out", str(out), "--export", str(export)]
    args += ["--workers", "1", "--", "--eval_episodes", "2"]
    args += ["--trainer.enable_progress_bar", "false"]
    assert study_script.main(args) == 0
    run = RunDir(export / "runs" / "hbc-pointmaze-umaze" / "seed0")
    result = run.read_result()
    assert [p["step"] for p in result.curve] == [2, 4] and result.step == 4
    assert "commit" in json.loads((run.path / "run.json").read_text())
    assert (export / "curves.png").exists() and (export / "curves.csv").exists()
    assert "Budget B = " in (export / "curves.md").read_text()
    page = tmp_path / "page.md"
    page.write_text(
        f"x\n<!-- report: {export.relative_to(tmp_path)}/curves.md -->\nold\n<!-- end report -->\n"
    )
    rebuilt = embed_reports(page, tmp_path)
    assert "| hbc | pointmaze-umaze | 1 |" in rebuilt and "old" not in rebuilt
    # --report-only rebuilds the same report from the exported files alone
    before = (export / "curves.md").read_text()
    assert study_script.main([*args[: args.index("--workers")], "--report-only"]) == 0
    assert (export / "curves.md").read_text() == before
