"""The claims page's verdicts follow stated rules from the committed files: the rules on their
own, a claim that cannot be tested says what it needs, and the page embeds the report its runs
give (tests/lab/test_docs.py checks the embed byte for byte)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from hispo_pl.benchmark.grid_report import Committed
from hispo_pl.benchmark.growth_curves import Growth, repeats_of
from lab import claim_rules as rules
from lab import claims


def _stats(per: float, low: float, high: float, mem: float = 1.0) -> rules.Stats:
    stats = rules.Stats(((per,),), per, 0.0, 0.0, mem, 1)
    stats.__dict__["per_iqm"] = (per, low, high)  # the interval as drawn, without a bootstrap
    return stats


def test_interval_rules():
    a, b, c = _stats(99, 98.5, 99.5), _stats(98.8, 98.0, 98.9), _stats(97, 96.5, 97.5)
    assert rules.overlaps(a, b) and rules.overlaps(b, a)
    assert not rules.overlaps(a, c) and rules.below(c, a) and not rules.below(a, c)
    assert rules.verdict(True) == "holds" and rules.verdict(False) == "does not hold"


class _Empty:
    """Committed runs of a protocol with none of its streams run yet."""

    def __init__(self, root=Path("no-runs-here")):
        self.cache = {}
        self.root = root

    def measured(self, stream):
        return []


@pytest.mark.parametrize("claim", claims.CLAIMS, ids=lambda c: c.text[:40])
def test_a_claim_without_its_runs_is_not_tested(claim):
    assert claim.test(_Empty()) is None and claim.needs


def test_the_page_says_not_tested_for_a_protocol_without_runs(tmp_path):
    text = claims.claims_markdown(tmp_path / "house", tmp_path / "protocol")
    rows = [line for line in text.splitlines() if line.startswith("| ") and "§" in line]
    assert len(rows) >= 10 and all(row.count("not tested here: needs") == 2 for row in rows)


def test_growth_order_names_the_polynomial_a_memory_curve_follows():
    assert rules.growth_order([1.0, 2.0, 3.0, 4.0]) == 1
    assert rules.growth_order([1.0, 2.96, 5.88, 9.77, 14.61]) == -1  # rounded: not exact
    assert rules.growth_order([k * k + 3 * k + 1 for k in range(8)]) == 2
    assert rules.growth_order([2.0**k for k in range(8)]) == -1


def test_a_verdict_on_fewer_seeds_than_the_papers_is_provisional():
    three = rules.Stats(((99.0,), (98.0,), (99.5,)), 98.8, 0.0, 0.0, 2.0, 3)
    one = rules.Stats(((97.0,),), 97.0, 0.0, 0.0, 4.0, 1)
    assert rules.judged({"hispo": three}, True) == "holds"
    assert rules.judged({"hispo": three, "scn": one}, False) == (
        "provisionally does not hold (1 seed of 3)"
    )
    assert rules.seeds_text({"hispo": three, "scn": one}) == "seeds hispo 3, scn 1"


class _Runs:
    """Committed runs of a protocol: ``{stream: {method: [PER per seed]}}``, MEM 1 each."""

    def __init__(self, per: dict):
        self.cache, self.per = {}, per

    def measured(self, stream):
        from types import SimpleNamespace

        return [
            (
                SimpleNamespace(method=m, seed=s),
                {"PER": p, "BWT": 0.0, "FWT": 0.0, "MEM": 1.0},
                None,
            )
            for m, seeds in self.per.get(stream, {}).items()
            for s, p in enumerate(seeds)
        ]


def test_a_claim_names_the_seeds_its_figures_rest_on():
    both = {"hispo": [0.99], "ftn": [0.98], "scn": [0.97]}
    runs = _Runs({"pointmaze-1": both, "pointmaze-2": both})
    claim = next(c for c in claims.CLAIMS if c.text.startswith("PointMaze: FTN and SCN"))
    figures, verdict = claim.test(runs)
    assert figures.endswith("(1 seed each)")
    assert verdict == "provisionally does not hold (1 seed of 3)"  # equal MEM: not "more"


def test_transfer_is_judged_where_its_own_methods_ran_without_the_rest_of_table_1():
    runs = _Runs({"pointmaze-1": {"ft1": [0.5], "ftn": [0.98], "hispo": [0.99]}})
    claim = next(c for c in claims.CLAIMS if c.text.startswith("FT1 and FTN transfer"))
    figures, _ = claim.test(runs)
    assert figures.startswith("ft1: FWT 0.0; ftn: FWT 0.0; hispo: FWT 0.0")
    table1 = next(c for c in claims.CLAIMS if c.where == "Table 1")
    assert table1.test(runs) is None  # PNN, the regularisers and FZ have no run


def test_one_seed_shows_no_interval():
    one = rules.Stats(((97.0, 95.0),), 96.0, 0.0, 0.0, 4.0, 2)
    assert one.text() == "PER 96.0"


def test_transfer_rests_only_on_the_seeds_with_a_from_scratch_run():
    """A seed whose from-scratch run is not committed yet has no FWT: the transfer claim
    counts the seeds that have one, and its mean is theirs."""
    runs = _Runs({"pointmaze-1": {"ft1": [0.5], "ftn": [0.98], "hispo": [0.99, 0.97]}})
    measured = runs.measured

    def with_fwt(stream):
        rows = measured(stream)
        for run, metrics, _ in rows:
            metrics["FWT"] = {"ft1": 0.03, "ftn": 0.04}.get(run.method, [-0.02, None][run.seed])
        return rows

    runs.measured = with_fwt
    claim = next(c for c in claims.CLAIMS if c.text.startswith("FT1 and FTN transfer"))
    figures, verdict = claim.test(runs)
    assert figures == "ft1: FWT 3.0; ftn: FWT 4.0; hispo: FWT -2.0 (1 seed each)"
    assert verdict == "provisionally holds (1 seed of 3)"
    per = next(c for c in claims.CLAIMS if c.text.startswith("PointMaze: FTN and SCN"))
    assert per.test(_Runs({"pointmaze-1": {"hispo": [0.99, 0.97]}})) is None  # no SCN, FTN


def test_a_verdict_rests_only_on_the_seeds_of_the_methods_it_compares():
    ablation = {"hispo": [0.80, 0.81, 0.79], "cspo": [0.82, 0.80, 0.81], "csp": [0.3]}
    runs = _Runs({"antmaze-1": ablation, "antmaze-2": ablation})
    by_text = {c.text: c for c in claims.CLAIMS}
    figures, verdict = by_text["Ablation: HiSPO performs as well as CSPO with less memory"].test(
        runs
    )
    assert "csp:" not in figures and figures.endswith("(3 seeds each)")
    assert verdict == "does not hold"  # equal MEM; CSP's one seed does not make it provisional
    _, verdict = by_text["Ablation: CSP is far below CSPO and HiSPO"].test(runs)
    assert verdict == "provisionally holds (1 seed of 3)"


def test_a_streams_first_seed_does_not_draw_a_full_verdict_down_to_one_seed():
    """A claim over "some stream" rests on the streams where its methods have all their seeds,
    as the aggregate counts them; one seed on another stream does not make it provisional."""
    three = {"hispo-pac": [0.80, 0.82, 0.81], "hispo": [0.80, 0.81, 0.79]}
    runs = _Runs({"antmaze-1": three, "pointmaze-2": {"hispo-pac": [0.5], "hispo": [0.99]}})
    assert rules.streams_run_by(runs, ["pointmaze-2", "antmaze-1"], tuple(three)) == ["antmaze-1"]
    claim = next(c for c in claims.CLAIMS if c.text.startswith("PAC:"))
    figures, verdict = claim.test(runs)
    assert figures.endswith("(3 seeds each)") and verdict == "holds"
    # with no stream whole, every stream with a run counts, and the verdict is provisional
    runs = _Runs({"antmaze-1": {"hispo-pac": [0.8], "hispo": [0.8]}, "pointmaze-2": three})
    assert rules.streams_run_by(runs, ["antmaze-1"], tuple(three)) == ["antmaze-1"]
    _, verdict = claim.test(_Runs({"pointmaze-2": {"hispo-pac": [0.5], "hispo": [0.99]}}))
    assert verdict == "provisionally does not hold (1 seed of 3)"


RANDOM_ANTMAZE = (
    Path(__file__).resolve().parents[2] / "docs/results/random-streams/random-antmaze-8@0"
)


def test_figure_2d_is_judged_on_the_committed_random_antmaze_runs(tmp_path):
    """The growth claim reads HiSPO's MEM after each task from the random-streams runs under a
    protocol's root: a committed run's own curve gives the figures and the verdict."""
    stream = tmp_path / rules.RANDOM_STREAMS / RANDOM_ANTMAZE.name
    shutil.copytree(RANDOM_ANTMAZE / "hispo", stream / "hispo")
    shutil.copy(RANDOM_ANTMAZE / "benchmark.json", stream)
    results = json.loads((stream / "hispo/seed0/results.json").read_text())
    memory, growth = results["mem_per_task"], Growth.of(results["mem_per_task"])
    again = repeats_of(results["stream"])
    on_repeats = [memory[k] - memory[k - 1] for k in range(1, len(memory)) if again[k]]

    figures, verdict = rules.random_growth(Committed(tmp_path))

    assert figures.startswith(
        f"hispo: MEM per task {growth.first_half:.2f} over the first half, "
        f"{growth.last_half:.2f} over the last, {growth.final:.2f} after {len(memory)} tasks"
    )
    assert f"{np.mean(on_repeats):.2f} per repeat ({len(on_repeats)}))" in figures
    assert f"(1 of 2 random AntMaze streams: {RANDOM_ANTMAZE.name})" in figures
    assert verdict == f"provisionally {rules.verdict(growth.slows)} (1 seed of 3)"
    assert rules.random_growth(_Empty(tmp_path / "elsewhere")) is None
