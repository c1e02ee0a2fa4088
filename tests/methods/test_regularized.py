"""L2 and EWC: the penalty's sufficient statistics, the empirical Fisher, the method end to end."""

from __future__ import annotations

import json
from pathlib import Path

import lightning as L
import pytest
import torch
from helpers import fit_tiny_stream

from hispo_pl.config import BackboneConfig
from hispo_pl.modules import GoalConditionedBC, RegularizedFineTuning
from hispo_pl.modules.regularized import empirical_fisher, flat_parameters, merge_quadratics

ROOT = Path(__file__).resolve().parents[2]
STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]


def _batch(n: int, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    sizes = {"observation": 4, "position": 2, "goal": 2, "subgoal": 2, "action": 2}
    return {k: torch.randn(n, d, generator=g) for k, d in sizes.items()}


def _module(penalty: str, lam: float = 1.0) -> RegularizedFineTuning:
    net = BackboneConfig(high_hidden=8, low_hidden=16)
    return RegularizedFineTuning(4, 2, backbone=net, penalty=penalty, penalty_lambda=lam)


@pytest.mark.parametrize("uniform", [False, True])
def test_merged_statistics_equal_the_sum_of_per_task_penalties(uniform):
    g = torch.Generator().manual_seed(1)
    d = 50
    centres = [torch.randn(d, generator=g, dtype=torch.float64) for _ in range(3)]
    if uniform:  # L2: one importance number per task
        weights = [torch.ones(1, dtype=torch.float64) for _ in range(3)]
    else:
        weights = [torch.rand(d, generator=g, dtype=torch.float64) for _ in range(3)]
        weights[1][:5] = 0  # parameters some task does not care about
    A, mu, C = (
        torch.zeros(0, dtype=torch.float64),
        torch.zeros(0, dtype=torch.float64),
        torch.zeros((), dtype=torch.float64),
    )
    for w, c in zip(weights, centres, strict=True):
        A, mu, C = merge_quadratics(A, mu, C, w, c)
    for _ in range(3):
        theta = torch.randn(d, generator=g, dtype=torch.float64)
        direct = sum((w * (theta - c).pow(2)).sum() for w, c in zip(weights, centres, strict=True))
        assert (A * (theta - mu).pow(2)).sum() + C == pytest.approx(direct.item(), rel=1e-10)
    assert A.shape == ((1,) if uniform else (d,))


def test_empirical_fisher_is_the_mean_squared_per_sample_gradient():
    m = _module("ewc")
    net = m.nets[0]
    batch = _batch(6)
    fisher = empirical_fisher(net, [batch], chunk=4)  # chunks that do not divide the batch
    net.eval()
    expected = torch.zeros_like(fisher)
    for i in range(6):
        net.zero_grad()
        net.losses({k: v[i : i + 1] for k, v in batch.items()})["loss"].backward()
        expected += torch.cat([p.grad.reshape(-1) for p in net.parameters()]).pow(2)
    torch.testing.assert_close(fisher, expected / 6, rtol=1e-3, atol=1e-6)  # float32 sums
    assert net.training is False  # mode restored (it was eval here)


@pytest.mark.parametrize("penalty", ["l2", "ewc"])
def test_penalty_is_zero_at_the_consolidated_weights_and_pulls_back(penalty):
    m = _module(penalty, lam=10.0)
    assert m.penalty().item() == 0.0 and "penalty" not in m.losses(_batch(8))
    m.consolidate([_batch(32)])
    assert m.penalty().item() == pytest.approx(0.0, abs=1e-9)
    with torch.no_grad():
        for p in m.parameters():
            p.add_(0.05)
    moved = m.penalty()
    assert moved.item() > 0
    moved.backward()
    # the penalty is c·(Σ A (θ − μ)² + C): its gradient is 2cA(θ − μ), pointing away from μ
    theta = flat_parameters(m.nets[0]).detach()
    gradient = torch.cat([p.grad.reshape(-1) for p in m.nets[0].parameters()])
    quadratic = moved.item() - m.penalty_coefficient * m.penalty_constant.item()
    assert (gradient * (theta - m.penalty_centre)).sum().item() == pytest.approx(
        2 * quadratic, rel=1e-3
    )
    if penalty == "l2":  # λ ‖θ − θ*‖² exactly
        assert moved.item() == pytest.approx(
            10.0 * flat_parameters(m.nets[0]).numel() * 0.05**2, rel=1e-3
        )


def test_checkpoint_restores_the_penalty(tmp_path):
    m = _module("ewc")
    m.consolidate([_batch(16)])
    with torch.no_grad():
        next(m.parameters()).add_(0.1)
    trainer = L.Trainer(logger=False, enable_checkpointing=False, accelerator="cpu")
    trainer.strategy.connect(m)
    trainer.save_checkpoint(tmp_path / "m.ckpt")
    restored = GoalConditionedBC.from_checkpoint_file(str(tmp_path / "m.ckpt"))
    assert isinstance(restored, RegularizedFineTuning)
    assert restored.penalty().item() == pytest.approx(m.penalty().item())
    assert restored.penalty().item() > 0


# ewc.yaml's callbacks with a Fisher over 2 batches of 64 (its own: 16 of 256, most of the run)
EWC_CALLBACKS = [
    {"class_path": "hispo_pl.callbacks.TaskNetworks"},
    {
        "class_path": "hispo_pl.callbacks.WeightConsolidation",
        "init_args": {"fisher_batches": 2, "batch_size": 64},
    },
    {
        "class_path": "hispo_pl.callbacks.RolloutEvaluation",
        "init_args": {"eval_every": 0, "episodes": 2, "seed": 0},
    },
]


@pytest.mark.parametrize("method,mem", [("l2", 2), ("ewc", 3)])
def test_stream_end_to_end(method, mem, tiny_umaze, tmp_path):
    extra = ["--trainer.log_every_n_steps", "1"]
    if method == "ewc":
        extra += ["--trainer.callbacks", json.dumps(EWC_CALLBACKS)]
    results, run_dir = fit_tiny_stream(method, tmp_path, STREAM, *extra)
    # stored: the network plus the penalty's centre (and, for EWC, its importance vector)
    assert results["MEM"] == pytest.approx(mem, rel=1e-3)
    second = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_02.ckpt"))
    first = GoalConditionedBC.from_checkpoint_file(str(run_dir / "task_01.ckpt"))
    # after task 1 the penalty is centred on task 1's weights
    torch.testing.assert_close(first.penalty_centre, flat_parameters(first.nets[0]))
    assert second.penalty_centre.shape == first.penalty_centre.shape
    assert len(second.nets) == 1  # one network, fine-tuned
