"""The stream report's pure parts: which values a logger receives and the text tables."""

from __future__ import annotations

import numpy as np
import pytest

from hispo_pl.figures import simplex_figure, success_matrix_figure, to_triangle
from hispo_pl.results import (
    CriticDecision,
    LossDecision,
    StreamResults,
    ZeroShotDecision,
    rule_metrics,
)
from hispo_pl.stream_report import (
    alpha_metrics,
    anchors_markdown,
    chosen_hparams,
    custom_scalars_layout,
    custom_scalars_summary,
    run_decisions_markdown,
    stream_metrics,
    success_markdown,
    task_row_metrics,
)


def test_task_row_metrics_cover_every_task_and_the_mean_of_those_seen():
    metrics = task_row_metrics(1, [1.0, 0.5, 0.2])  # the third task: a zero-shot point
    assert metrics == pytest.approx(  # in %, as the console and the tables print success
        {
            "stream/success/T01": 100.0,
            "stream/success/T02": 50.0,
            "stream/success/T03": 20.0,
            "stream/success/mean_seen": 75.0,
        }
    )


def test_stream_and_alpha_metrics():
    results = StreamResults(
        stream=["a"], R=[[0.9]], wall_time_s=[1.0], metrics={"PER": 0.9, "BWT": -0.012, "MEM": 2.07}
    )
    assert stream_metrics(results) == pytest.approx(  # success in %, MEM a ratio
        {"stream/PER": 90.0, "stream/BWT": -1.2, "stream/MEM": 2.07}
    )
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
    rows = run_decisions_markdown(
        [
            LossDecision(task=0, subspace="low", decision="first", l_curr=0.2, eps=0.1, anchors=1),
            LossDecision(
                task=1,
                subspace="low",
                decision="prune",
                l_prev=0.21,
                l_curr=0.2,
                eps=0.1,
                anchors=1,
            ),
        ]
    ).splitlines()
    assert rows[0].startswith("| task | subspace | L_prev | L_curr | L_prev / L_curr | ε |")
    assert rows[2] == "| 1 | low |  | 0.2000 |  | 0.1 |  |  | first | 1 |"
    assert rows[3] == "| 2 | low | 0.2100 | 0.2000 | 1.050 | 0.1 |  |  | prune | 1 |"


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
        LossDecision(
            task=1, subspace="high", decision="keep", l_prev=0.9, l_curr=0.05, eps=0.1, anchors=2
        ),
        LossDecision(
            task=1, subspace="low", decision="prune", l_prev=0.21, l_curr=0.2, eps=0.1, anchors=1
        ),
        LossDecision(task=0, subspace="low", decision="first", l_curr=0.2, eps=0.1, anchors=1),
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
    critic = CriticDecision(task=2, subspace="policy", decision="prune", eps=0.1, anchors=1)
    critic.w_prev, critic.w_curr, critic.l_prev, critic.l_curr = -0.5, -0.48, 0.3, 0.1
    assert task_summary(2, 4, 52, [1.0, 1.0, 1.0, 0.0], [critic]).endswith(
        "; policy prune (W -0.480 vs -0.450)"  # the critic's bar, not the losses' ratio
    )


def test_each_kind_of_decision_gets_its_own_table():
    zero_shot = ZeroShotDecision(
        task=1,
        subspace="low",
        decision="zero-shot",
        pac_rate={"low": 0.97},
        eps={"low": 1.0},
        delta=0.05,
        anchors=1,
        alpha=[1.0],
    )
    critic = CriticDecision(task=1, subspace="policy", decision="keep", eps=0.1, anchors=2)
    critic.w_prev, critic.w_curr = 0.4, 0.52
    tables = run_decisions_markdown([zero_shot, critic]).split("\n\n")
    assert tables[0].splitlines()[0].startswith("| task | W_prev | W_curr | ε |")
    assert tables[1].splitlines()[2] == "| 2 | low | low 0.970 | 0.95 | zero-shot | 1 |"
    assert chosen_hparams({}, [zero_shot, critic]) == {"eps_policy": 0.1}  # no PAC tolerance


FINGERPRINT = {  # a stream run's flat settings, as the loop stores them
    "seed_everything": 3,
    "trainer.accelerator": "cpu",
    "trainer.inference_mode": True,
    "trainer.max_steps": 3000,
    "trainer.callbacks[DirichletEvaluation].class_path": "hispo_pl.callbacks.DirichletEvaluation",
    "trainer.callbacks[DirichletEvaluation].init_args.n_candidates": 1024,
    "trainer.callbacks[SubspacePruning].class_path": "hispo_pl.callbacks.SubspacePruning",
    "trainer.callbacks[SubspacePruning].init_args.eps_low": None,
    "trainer.callbacks[RolloutEvaluation].class_path": "hispo_pl.callbacks.RolloutEvaluation",
    "trainer.callbacks[RolloutEvaluation].init_args.episodes": 100,
    "model.class_path": "hispo_pl.modules.HiSPO",
    "model.init_args.backbone.high_hidden": 64,
    "model.init_args.backbone.low_hidden": 256,
    "model.init_args.backbone.dropout": 0.1,
    "model.init_args.optim.lr": 0.001,
    "data.batch_size": 1024,
    "data.stream": ["pointmaze-umaze-N[500]", "pointmaze-umaze-PA[500]"],
    "preset": None,
}
DECISIONS = [
    LossDecision(task=0, subspace="high", decision="first", eps=0.1, anchors=1),
    LossDecision(task=0, subspace="low", decision="first", eps=0.6, anchors=1),
    LossDecision(task=1, subspace="high", decision="prune", eps=0.1, anchors=1),
    LossDecision(task=1, subspace="low", decision="keep", eps=0.6, anchors=2),
]


def test_hparams_hold_the_settings_a_user_chose_by_name():
    assert chosen_hparams(FINGERPRINT, DECISIONS) == {
        "method": "HiSPO",
        "stream": "pointmaze-umaze-N[500] -> pointmaze-umaze-PA[500]",
        "seed": 3,
        "steps_per_task": 3000,
        "batch_size": 1024,
        "lr": 0.001,
        "episodes": 100,
        "high_hidden": 64,
        "low_hidden": 256,
        "eps_high": 0.1,  # the tolerance applied, where the setting says None (family default)
        "eps_low": 0.6,
    }
    zero_shot = [ZeroShotDecision(task=1, subspace="low", decision="zero-shot", eps={"low": 1.0})]
    assert "eps_low" not in chosen_hparams(FINGERPRINT, zero_shot)


def test_hparams_name_a_method_as_its_registry_entry_does():
    """One class, several methods: the name comes from the method's entry and its settings."""
    networks = {
        "model.class_path": "hispo_pl.modules.NetworkPerTask",
        "model.init_args.init": "previous",
        "model.init_args.keep": "last",
        "trainer.callbacks[TaskNetworks].class_path": "hispo_pl.callbacks.TaskNetworks",
        "trainer.callbacks[TaskNetworks].init_args.train": "all",
    }
    assert chosen_hparams(networks)["method"] == "FT1"
    frozen = {**networks, "trainer.callbacks[TaskNetworks].init_args.train": "first"}
    assert chosen_hparams(frozen)["method"] == "FRZ"


def test_custom_scalars_give_each_task_its_chart_and_the_rule_as_a_ratio():
    layout = custom_scalars_layout(["high", "low"], n_tasks=2)
    charts = {title: tags for category in layout.values() for title, tags in category.items()}
    logged = [
        "stream/success/T01",
        "stream/success/T02",
        "stream/success/mean_seen",
        "stream/PER",
        "anchors/high/count",
        "anchors/low/count",
        "search/high/L_prev",
        "search/high/L_curr",
        "search/high/L_prev_over_L_curr",
        "search/high/1_plus_eps",
        "search/low/L_prev_over_L_curr",
        "search/low/1_plus_eps",
        "task_01/search/high/l_prev",
    ]

    def matched(title_start: str) -> list[str]:
        title = next(t for t in charts if t.startswith(title_start))
        return [tag for tag in logged if tag in charts[title]]

    # one chart per task: the runs of a folder are the lines of a task's chart, each its colour
    assert matched("T01:") == ["stream/success/T01"]
    assert matched("T02:") == ["stream/success/T02"]
    assert list(layout)[0] == "forgetting curves"  # the first the tab shows
    assert matched("anchors per subspace") == ["anchors/high/count", "anchors/low/count"]
    assert matched("high:") == ["search/high/L_prev_over_L_curr", "search/high/1_plus_eps"]
    assert matched("low:") == ["search/low/L_prev_over_L_curr", "search/low/1_plus_eps"]
    assert "pruning rule" not in custom_scalars_layout([], n_tasks=2)  # no decisions


def test_the_layout_bands_each_tag_by_itself_so_no_value_is_an_outlier():
    from tensorboard.plugins.custom_scalar import layout_pb2

    layout = custom_scalars_layout(["high", "low"], n_tasks=2)
    (value,) = custom_scalars_summary(layout).value
    assert value.tag == "custom_scalars__config__"
    decoded = layout_pb2.Layout.FromString(value.tensor.string_val[0])
    assert [c.title for c in decoded.category] == list(layout)
    for category in decoded.category:
        for chart in category.chart:
            tags = [s.value for s in chart.margin.series]
            assert tags == layout[category.title][chart.title]
            assert all(s.lower == s.value == s.upper for s in chart.margin.series)


def test_the_rule_is_logged_as_a_ratio_against_one_plus_eps():
    decided = [
        LossDecision(task=0, subspace="low", decision="first", eps=0.6, l_curr=0.21),
        LossDecision(task=1, subspace="high", decision="prune", eps=0.1, l_curr=0.03, l_prev=0.032),
        LossDecision(task=1, subspace="low", decision="keep", eps=0.6, l_curr=0.2, l_prev=1.9),
    ]
    assert rule_metrics(decided) == pytest.approx(
        {
            "search/high/L_prev_over_L_curr": 0.032 / 0.03,
            "search/high/1_plus_eps": 1.1,
            "search/low/L_prev_over_L_curr": 9.5,
            "search/low/1_plus_eps": 1.6,
        }
    )
    assert rule_metrics(decided[:1]) == {}  # the first task compares nothing


def test_anchor_counts_as_a_table():
    assert anchors_markdown(DECISIONS).splitlines() == [
        "| after | high | low |",
        "|---|---:|---:|",
        "| T01 | 1 (first) | 1 (first) |",
        "| T02 | 1 (prune) | 2 (keep) |",
    ]
