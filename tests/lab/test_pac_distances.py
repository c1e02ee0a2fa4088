"""``benchmarks/pac_distances.py`` measures what the PAC criterion tests, along a finished run:
from the run's own checkpoints, its distances give the rates a HiSPO-PAC run recorded."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from helpers import fit_tiny_stream, load_benchmark

from hispo_pl.callbacks import ZeroShotTransfer
from hispo_pl.decisions import pac_rate
from hispo_pl.rundir import RunDir
from hispo_pl.task_families import FAMILIES

pac_distances = load_benchmark("pac_distances")
ROOT = Path(__file__).resolve().parents[2]
STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]", "pointmaze-umaze-N[3]"]


def _pac_config(tmp_path: Path) -> Path:
    config = yaml.safe_load((ROOT / "configs/methods/hispo-pac.yaml").read_text())
    transfer = config["trainer"]["callbacks"][0]
    assert transfer["class_path"].endswith("ZeroShotTransfer")
    transfer["init_args"].update(eps_high=0.3, eps_low=0.5, delta=0.0, n_candidates=16)
    transfer["init_args"].update(n_batches=2)
    path = tmp_path / "pac.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


@pytest.mark.e2e
def test_the_distances_give_the_rates_the_run_recorded(tiny_umaze, tmp_path):
    method = _pac_config(tmp_path)
    run = RunDir(fit_tiny_stream(method, tmp_path / "runs", STREAM)[1])
    transfer = pac_distances.criterion(method)
    measured = pac_distances.measure(run, transfer)
    recorded = {(d.task, d.subspace): d for d in run.decisions() if d.decision in ("train",)}
    assert len(measured) == len(recorded) == 4  # tasks 2 and 3, high and low: none accepted
    for m in measured:
        decision = recorded[(m.task, m.subspace)]
        assert pac_rate(m.distances, decision.eps[m.policy]) == decision.pac_rate[m.policy]
    table = pac_distances.rows(run, measured, 0.1)
    assert [(r["task"], r["policy"]) for r in table] == [
        (2, "high"), (2, "low"), (3, "high"), (3, "low")
    ]  # fmt: skip
    assert all(0 <= r["median"] <= r["quantile"] for r in table)
    assert {r["pruning"] for r in table} <= {"keep", "prune"}


def test_the_criterion_takes_the_task_familys_tolerances_unless_given():
    ant, point = FAMILIES["antmaze"], FAMILIES["pointmaze"]
    assert ZeroShotTransfer().tolerance("low", ant) == ant.pac_eps["low"]
    assert ZeroShotTransfer().tolerance("high", point) == point.pac_eps["high"]
    assert ZeroShotTransfer(eps_low=0.2).tolerance("low", ant) == 0.2
    assert ZeroShotTransfer(eps_low=0.2).tolerance("high", ant) == ant.pac_eps["high"]
    # a policy no family names: the largest tolerance there is
    assert ZeroShotTransfer(eps_low=9.0).tolerance("policy", ant) == 9.0
    # the families' own differ: subgoals and actions have each family's units
    assert ant.pac_eps != point.pac_eps
