"""benchmarks/vertex_probe.py: each weight variant is what the module acts with while it is
rolled out, and the stored weights are back afterwards."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from helpers import perturb_newest, tiny_hispo

spec = importlib.util.spec_from_file_location(
    "vertex_probe", Path(__file__).resolve().parents[1] / "benchmarks" / "vertex_probe.py"
)
vertex_probe = importlib.util.module_from_spec(spec)
spec.loader.exec_module(vertex_probe)


def _two_task_module():
    m = tiny_hispo()
    for name in ("high", "low"):
        m.set_task_alpha(0, name, torch.ones(1))
    m.freeze_all()
    for name in ("high", "low"):
        m.add_anchor(name)
        perturb_newest(m, name)
    m.set_task_alpha(1, "high", torch.tensor([0.3, 0.7]))
    m.set_task_alpha(1, "low", torch.tensor([0.6, 0.4]))
    m.eval()
    return m


class RecordingEvaluator:
    """Stands in for the rollouts: records the weights task 1 acts with when it is run."""

    def __init__(self, module):
        self.module, self.seen = module, []

    def run(self, policy):
        self.seen.append({s: self.module.alpha_for(s, 1).tolist() for s in ("high", "low")})
        return SimpleNamespace(success=len(self.seen) / 10)


def test_vertex_is_the_newest_weighted_anchor_alone():
    assert vertex_probe.vertex(torch.tensor([0.2, 0.8, 0.0])).tolist() == [0.0, 1.0, 0.0]
    assert vertex_probe.vertex(torch.tensor([1.0, 0.0])).tolist() == [1.0, 0.0]


def test_probe_acts_with_each_variant_and_restores_the_stored_weights():
    m = _two_task_module()
    before = {s: m.task_alphas(s).clone() for s in ("high", "low")}
    evaluator = RecordingEvaluator(m)
    rows = vertex_probe.probe(m, 1, evaluator)
    high, low = [0.3, 0.7], [0.6, 0.4]
    assert [r["weights"] for r in rows] == ["stored", "high vertex", "low vertex", "both vertices"]
    expected = [
        {"high": high, "low": low},
        {"high": [0.0, 1.0], "low": low},
        {"high": high, "low": [0.0, 1.0]},
        {"high": [0.0, 1.0], "low": [0.0, 1.0]},
    ]
    for seen, want in zip(evaluator.seen, expected, strict=True):
        for s in ("high", "low"):
            assert seen[s] == pytest.approx(want[s])
    assert [r["success"] for r in rows] == [0.1, 0.2, 0.3, 0.4]
    for s in ("high", "low"):
        assert torch.equal(m.task_alphas(s), before[s])
