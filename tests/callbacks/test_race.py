"""The two-stage race over candidate weights, and the precision it scores in."""

from __future__ import annotations

import pytest
import torch

from hispo_pl.config import BackboneConfig
from hispo_pl.modules.hispo import HiSPO
from hispo_pl.nn.simplex import sample_dirichlet
from hispo_pl.race import race_candidates, resolve_precision


def _quadratic_score(target: torch.Tensor, noise: float = 0.0):
    """Loss of α on batch b: squared distance to ``target`` plus a per-(batch, α) jitter, and
    a log of which candidates each call scored."""
    calls = []

    def score(alphas: torch.Tensor, batch: int) -> torch.Tensor:
        calls.append((batch, len(alphas)))
        g = torch.Generator().manual_seed(1000 + batch)
        w = 100 * torch.randn(alphas.shape[1], generator=g)
        jitter = noise * (1 + torch.sin(alphas @ w))  # a function of the candidate and batch
        return (alphas - target).pow(2).sum(-1) + jitter

    return score, calls


def test_exhaustive_race_is_the_mean_over_batches_of_every_candidate():
    cands = sample_dirichlet(50, 3, torch.Generator().manual_seed(0))
    score, calls = _quadratic_score(torch.tensor([0.2, 0.5, 0.3]), noise=0.01)
    race = race_candidates(score, cands, batches=[0, 1, 2], probe=None)
    expected = torch.stack([score(cands, b) for b in (0, 1, 2)]).mean(0)
    assert race.probe_losses is None
    assert torch.equal(race.survivors, torch.arange(50))
    torch.testing.assert_close(race.losses, expected)
    assert race.best == int(expected.argmin())
    assert race.best_loss == pytest.approx(float(expected.min()))


def test_race_scores_all_on_the_probe_and_only_survivors_on_the_batches():
    cands = sample_dirichlet(200, 3, torch.Generator().manual_seed(1))
    score, calls = _quadratic_score(torch.tensor([0.6, 0.1, 0.3]), noise=1e-3)
    race = race_candidates(score, cands, batches=[0, 1, 2, 3], probe=99, survivors=10)
    assert calls == [(99, 200)] + [(b, 10) for b in range(4)]
    assert race.probe_losses.shape == (200,)
    # survivors are the 10 lowest on the probe, and their losses are full-batch means
    assert set(race.survivors.tolist()) == set(race.probe_losses.argsort()[:10].tolist())
    kept = cands[race.survivors]
    expected = torch.stack([score(kept, b) for b in range(4)]).mean(0)
    torch.testing.assert_close(race.losses, expected)


def test_race_finds_the_exhaustive_winner_when_the_probe_ranks_like_the_batches():
    cands = sample_dirichlet(500, 4, torch.Generator().manual_seed(2))
    score, _ = _quadratic_score(torch.tensor([0.1, 0.2, 0.3, 0.4]), noise=1e-4)
    full = race_candidates(score, cands, batches=[0, 1, 2])
    raced = race_candidates(score, cands, batches=[0, 1, 2], probe=7, survivors=16)
    assert raced.best == full.best
    assert raced.best_loss == pytest.approx(full.best_loss)


def test_more_survivors_than_candidates_is_exhaustive():
    cands = sample_dirichlet(5, 2, torch.Generator().manual_seed(3))
    score, calls = _quadratic_score(torch.tensor([0.5, 0.5]))
    race = race_candidates(score, cands, batches=[0], probe=1, survivors=64)
    assert race.probe_losses is None and calls == [(0, 5)]


@pytest.mark.parametrize(
    "kwargs, match",
    [({"batches": []}, "at least one batch"), ({"batches": [0], "survivors": 0}, "positive")],
)
def test_race_rejects_bad_arguments(kwargs, match):
    score, _ = _quadratic_score(torch.tensor([0.5, 0.5]))
    with pytest.raises(ValueError, match=match):
        race_candidates(score, torch.ones(3, 2) / 2, **{"probe": 0, **kwargs})


def test_resolve_precision():
    cpu = torch.device("cpu")
    assert resolve_precision("32", cpu) == "32"
    assert resolve_precision("bf16", cpu) == "bf16"
    assert resolve_precision("auto", cpu) in {"32", "bf16"}


def test_bf16_scores_track_float32_scores():
    """Scoring in bf16 autocast changes the losses by well under the pruning tolerance (10 %),
    and ranks clearly different candidates the same way."""
    torch.manual_seed(0)
    m = HiSPO(obs_dim=4, action_dim=2, backbone=BackboneConfig(low_hidden=64), anchor_init="random")
    for _ in range(2):
        m.add_anchor("low")
    g = torch.Generator().manual_seed(0)
    batch = {
        k: torch.randn(512, d, generator=g)
        for k, d in {"observation": 4, "position": 2, "goal": 2, "subgoal": 2, "action": 2}.items()
    }
    alphas = torch.eye(3)
    fp32 = m.score_alphas("low", alphas, batch, precision="32")
    bf16 = m.score_alphas("low", alphas, batch, precision="bf16")
    assert bf16.dtype == torch.float32
    torch.testing.assert_close(bf16, fp32, rtol=2e-2, atol=1e-4)


def test_seeded_candidates_are_scored_on_every_batch_whatever_their_probe_rank():
    cands = sample_dirichlet(200, 3, torch.Generator().manual_seed(4))
    target = torch.tensor([0.3, 0.3, 0.4])
    far = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # worst on the probe
    score, calls = _quadratic_score(target, noise=1e-3)
    race = race_candidates(score, torch.cat([far, cands]), [0, 1], probe=5, survivors=10, seeded=2)
    assert calls == [(5, 202)] + [(b, 12) for b in range(2)]
    assert race.survivors[:2].tolist() == [0, 1]  # kept though they rank last on the probe
    assert set(race.probe_losses.argsort()[-2:].tolist()) == {0, 1}
    drawn = race.probe_losses[2:].argsort()[:10] + 2
    assert race.survivors[2:].tolist() == drawn.tolist()  # the others race as before
    plain = race_candidates(score, cands, [0, 1], probe=5, survivors=10)
    torch.testing.assert_close(race.losses[2:], plain.losses)
