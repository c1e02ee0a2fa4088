"""A row of R reuses a task's earlier rollouts when the module acts on it with the very
tensors it acted with then: the results are those of rolling out again, for fewer rollouts."""

from __future__ import annotations

import pytest
import torch
from helpers import fit_tiny_stream, without_times

from hispo_pl.evaluation import RolloutEvaluator
from hispo_pl.modules import PNN, HiSPO, NetworkPerTask
from hispo_pl.modules.hbc import GoalConditionedBC

REPEATED = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]", "pointmaze-umaze-N[3]"]


def _counted_fit(method: str, save_dir, monkeypatch, reuse: bool) -> tuple[dict, int]:
    """A tiny stream's results and how many rollouts (of one task, all its episodes) ran."""
    calls = []
    run = RolloutEvaluator.run

    def counted(self, *args, **kwargs):
        calls.append(self.task)
        return run(self, *args, **kwargs)

    with monkeypatch.context() as patch:
        patch.setattr(RolloutEvaluator, "run", counted)
        if not reuse:
            patch.setattr(GoalConditionedBC, "acting_digest", lambda self, task: None)
        results, _ = fit_tiny_stream(method, save_dir, REPEATED)
    return results, len(calls)


@pytest.mark.parametrize(
    ("method", "rollouts"),
    [
        # every policy is the first network: one rollout per distinct task, and PO's again
        # when it is the current task (row 2), whose paths are kept for its picture
        ("frz", 3),
        # row 1: N and PO with network 0 (the unseen N repeats the first); row 2: PO and N
        # with network 1; row 3: the last N with network 2
        ("scn", 5),
    ],
)
def test_a_row_reuses_rollouts_of_an_unchanged_policy(
    method, rollouts, tiny_umaze, tmp_path, monkeypatch
):
    reused, ran = _counted_fit(method, tmp_path / "reuse", monkeypatch, reuse=True)
    fresh, all_ran = _counted_fit(method, tmp_path / "fresh", monkeypatch, reuse=False)
    assert all_ran == len(REPEATED) ** 2 and ran == rollouts
    assert without_times(reused) == without_times(fresh)


def test_hispo_reuses_nothing_across_a_grown_subspace(tiny_umaze, tmp_path, monkeypatch):
    reused, ran = _counted_fit("hispo", tmp_path / "reuse", monkeypatch, reuse=True)
    fresh, _ = _counted_fit("hispo", tmp_path / "fresh", monkeypatch, reuse=False)
    assert without_times(reused) == without_times(fresh)
    assert ran < len(REPEATED) ** 2  # the unseen N of row 1 acts as the first N


def test_acting_digest_follows_what_a_task_acts_with():
    torch.manual_seed(0)
    scn = NetworkPerTask(obs_dim=4, action_dim=2, init="fresh", keep="all")
    scn.start_task(0)
    scn.finish_task(0)
    first = scn.acting_digest(0)
    scn.start_task(1)
    with torch.no_grad():
        next(scn.network_for(1).parameters()).add_(1.0)  # task 1's network trains
    scn.finish_task(1)
    assert scn.acting_digest(0) == first and scn.acting_digest(1) != first

    pnn = PNN(obs_dim=4, action_dim=2)
    pnn.start_task(0)
    pnn.finish_task(0)
    first = pnn.acting_digest(0)
    pnn.start_task(1)  # a new column with laterals from column 0
    with torch.no_grad():
        for p in pnn.net.parameters():
            if p.requires_grad:
                p.add_(1.0)
    pnn.finish_task(1)
    assert pnn.acting_digest(0) == first and pnn.acting_digest(1) != first

    hispo = HiSPO(obs_dim=4, action_dim=2)
    before = hispo.acting_digest(0)
    with torch.no_grad():
        next(hispo.policies.parameters()).add_(1.0)
    assert hispo.acting_digest(0) != before
