"""HiSPO's pure decision rules: the pruning test and the previous-subspace candidates."""

from __future__ import annotations

import pytest
import torch

from hispo_pl.decisions import (
    keep_previous,
    previous_subspace_candidates,
    stored_task_points,
    tolerance_problem,
)

# --- keep_previous: prune the new anchor iff L_prev <= (1 + eps) * L_curr -------------------


@pytest.mark.parametrize(
    ("l_prev", "l_curr", "eps", "expected"),
    [
        (1.0, 2.0, 0.1, True),  # the previous subspace is better: prune
        (2.0, 1.0, 0.1, False),  # much worse: keep the new anchor
        (1.05, 1.0, 0.1, True),  # worse, but within the tolerance: prune
        (1.2, 1.0, 0.1, False),  # worse than the tolerance allows: keep
        (1.0, 1.0, 0.0, True),  # equal losses, no tolerance: prune
        (1.0 + 1e-9, 1.0, 0.0, False),  # eps = 0: any loss increase keeps the anchor
        (0.0, 0.0, 0.0, True),  # both perfect: nothing to gain from a new anchor
        (5.0, 0.0, 1e9, False),  # a perfect new anchor is never pruned by a finite eps
        (1e6, 1.0, 1e9, True),  # a huge eps prunes almost anything
    ],
)
def test_keep_previous_truth_table(l_prev, l_curr, eps, expected):
    assert keep_previous(l_prev, l_curr, eps) is expected


@pytest.mark.parametrize(("l_curr", "eps"), [(1.0, 0.5), (0.25, 1.0), (4.0, 0.0), (0.5, 0.25)])
def test_keep_previous_boundary_prunes(l_curr, eps):
    # exactly representable products, so L_prev == (1 + eps) * L_curr holds in floating point
    l_prev = (1.0 + eps) * l_curr
    assert keep_previous(l_prev, l_curr, eps) is True
    assert keep_previous(l_prev * (1 + 1e-12), l_curr, eps) is False


@pytest.mark.parametrize(
    ("l_prev", "l_curr", "eps", "match"),
    [
        (-1.0, 1.0, 0.1, "positive losses"),
        (1.0, -1e-3, 0.1, "positive losses"),
        (1.0, 1.0, -0.01, "eps must be non-negative"),
    ],
)
def test_keep_previous_rejects_negative_inputs(l_prev, l_curr, eps, match):
    with pytest.raises(ValueError, match=match):
        keep_previous(l_prev, l_curr, eps)


# --- previous_subspace_candidates -----------------------------------------------------------


def test_candidates_with_one_previous_anchor_is_the_single_point():
    cands = previous_subspace_candidates(100, 2, torch.Generator().manual_seed(0))
    assert cands.tolist() == [[1.0, 0.0]]


def test_candidates_need_a_newest_anchor():
    with pytest.raises(ValueError, match="newest anchor"):
        previous_subspace_candidates(10, 1)


@pytest.mark.parametrize("k", [3, 4, 6])
def test_candidates_lie_on_the_previous_simplex(k):
    n = 257
    cands = previous_subspace_candidates(n, k, torch.Generator().manual_seed(0))
    assert cands.shape == (n, k)
    assert cands.dtype == torch.float32
    assert torch.all(cands[:, -1] == 0)
    assert torch.all(cands >= 0)
    torch.testing.assert_close(cands.sum(1), torch.ones(n))
    assert len({tuple(r) for r in cands.tolist()}) == n  # genuine draws, not one repeated point
    # every previous anchor gets weight: the draws cover the whole previous simplex
    assert torch.all(cands[:, :-1].max(0).values > 0.5)


def test_candidates_are_deterministic_given_a_seeded_generator():
    a = previous_subspace_candidates(64, 4, torch.Generator().manual_seed(7))
    b = previous_subspace_candidates(64, 4, torch.Generator().manual_seed(7))
    c = previous_subspace_candidates(64, 4, torch.Generator().manual_seed(8))
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_pac_rate_and_zero_shot_rule():
    from hispo_pl.decisions import pac_rate, zero_shot

    d = torch.tensor([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9])
    assert pac_rate(d, 0.45) == pytest.approx(0.5)
    assert pac_rate(d, 0.9) == 1.0  # within eps, bound included
    assert zero_shot(d, 0.85, delta=0.1)  # 9 of 10 within: 0.9 >= 1 - 0.1
    assert not zero_shot(d, 0.75, delta=0.1)  # 8 of 10
    assert zero_shot(d, 0.0, delta=1.0)  # delta 1 accepts anything
    with pytest.raises(ValueError, match="delta"):
        zero_shot(d, 0.1, delta=1.5)
    with pytest.raises(ValueError, match="at least one"):
        pac_rate(torch.zeros(0), 0.1)


def test_extended_subspace_candidates_start_with_the_trained_weights_and_the_new_anchor():
    from hispo_pl.decisions import extended_subspace_candidates

    trained = torch.tensor([0.3, 0.3, 0.4])
    cands = extended_subspace_candidates(50, trained, torch.Generator().manual_seed(0))
    assert cands.shape == (52, 3)
    assert torch.equal(cands[0], trained) and cands[1].tolist() == [0.0, 0.0, 1.0]
    assert torch.allclose(cands.sum(1), torch.ones(52)) and (cands >= 0).all()
    assert (cands[2:, -1] > 0).all()  # the draws use every anchor, the new one included


@pytest.mark.parametrize("bad", [-0.1, float("nan")])
def test_the_rules_callbacks_refuse_a_tolerance_by_the_one_check(bad):
    from hispo_pl.callbacks import CriticPruning, SubspacePruning

    assert tolerance_problem(bad) == "must be >= 0"
    with pytest.raises(ValueError, match="must be >= 0"):
        SubspacePruning(eps_low=bad)
    with pytest.raises(ValueError, match="must be >= 0"):
        CriticPruning(eps=bad)


def test_stored_task_points_are_the_earlier_tasks_weights_each_once():
    rows = torch.tensor(
        [
            [1.0, 0.0, 0.0],  # task 0
            [0.25, 0.75, 0.0],  # task 1
            [1.0, 0.0, 0.0],  # task 2 took task 0's point again
            [0.25, 0.25, 0.5],  # the current task: not an earlier one
        ]
    )
    assert stored_task_points(rows, 3).tolist() == [[1.0, 0.0, 0.0], [0.25, 0.75, 0.0]]
    assert stored_task_points(rows, 0).shape == (0, 3)
    # a row on the newest anchor is no point of the previous subspace
    assert stored_task_points(rows, 4).tolist() == [[1.0, 0.0, 0.0], [0.25, 0.75, 0.0]]
    assert stored_task_points(torch.ones(2, 1), 2).shape == (0, 1)  # one anchor: none
