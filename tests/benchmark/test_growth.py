"""The memory of SCN, FTN and PNN after each task, grown from their structure without
training, equals what their committed runs stored; and grows as their structure says."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hispo_pl.benchmark.growth import module_for, structural_memory

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("method", ["scn", "ftn", "pnn"])
def test_grown_memory_equals_the_stored_size_of_committed_runs(method):
    configs = [ROOT / "configs/streams/pointmaze-1.yaml", ROOT / f"configs/methods/{method}.yaml"]
    memory = structural_memory(module_for(configs), 4)
    for seed in (0, 1, 2):
        run = json.loads(
            (ROOT / f"docs/results/pointmaze-1/{method}/seed{seed}/results.json").read_text()
        )
        assert memory[-1] == pytest.approx(run["MEM"], rel=1e-9)
    assert memory[0] == pytest.approx(1.0, rel=1e-3)
    if method in ("scn", "ftn"):  # one network per task
        assert memory == pytest.approx([1.0, 2.0, 3.0, 4.0], rel=1e-3)
    else:  # a column per task and laterals from every earlier column: faster than linear
        steps = [b - a for a, b in zip(memory, memory[1:], strict=False)]
        assert steps == sorted(steps) and steps[-1] > steps[0]


def test_a_method_that_grows_by_its_decisions_is_refused():
    configs = [ROOT / "configs/streams/pointmaze-1.yaml", ROOT / "configs/methods/hispo.yaml"]
    with pytest.raises(TypeError, match="grows by its decisions"):
        structural_memory(module_for(configs), 3)


def test_growing_a_structure_prints_none_of_lightnings_notices(capfd, caplog):
    """A report grows SCN's memory between runs: Lightning's accelerator lines and tips would
    land in the middle of the command's output."""
    configs = [ROOT / "configs/streams/pointmaze-1.yaml", ROOT / "configs/methods/scn.yaml"]
    with caplog.at_level("INFO"):
        module_for(configs)
    said = capfd.readouterr()
    shown = said.out + said.err + caplog.text
    assert "GPU available" not in shown and "Tip" not in shown, shown
