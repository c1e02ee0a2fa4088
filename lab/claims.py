"""The paper's claims on performance and memory, forgetting and generalisation, and its
ablations, each with our figures and a verdict under two protocols: the house defaults (the
runs under ``<root>/<stream>/``) and the paper's own recipe at its converged budget (the runs
under ``<root>/paper-protocol/<stream>/``). A folder holding ``claims.json`` (the two roots,
relative to it) gets ``claims.md``, and a page's copy of it is rebuilt like every embedded
report; the verdict rules are in :mod:`lab.claim_rules`.

A verdict is ``holds``, ``does not hold`` or ``not tested here`` with the reason: a claim is
tested only where every stream it speaks of has runs of every method it names.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from hispo_pl.benchmark.grid_report import Committed
from hispo_pl.io import atomic_write_text

from . import paper
from .claim_rules import (
    FAMILY_STREAMS,
    HIGH,
    MIN_SEEDS,
    TABLE1_ORDER,
    ZERO,
    Claim,
    ablation,
    below,
    fail_against_hispo,
    forgets,
    fwt_order,
    high_but_more_memory,
    hilow_less_memory,
    matches_with_less_memory,
    no_forgetting,
    pac_transfers,
    pnn_growth,
    random_growth,
    slightly_below_similar_memory,
    streams_run_by,
    table1_order,
)

ARCHITECTURAL = ("scn", "ftn", "pnn", "hispo")  # the methods that add parameters per task
CLAIMS_FILE = "claims.json"  # a claims folder's two roots, relative to it: house, protocol


def streams_with(methods: Sequence[str]) -> Callable[[Committed], list[str]]:
    """The streams of the paper's tables where every one of ``methods`` has a run
    (:func:`~lab.claim_rules.streams_run_by`: those with all their seeds first)."""

    def streams(committed: Committed) -> list[str]:
        return streams_run_by(committed, list(paper.PER_STREAM), methods)

    return streams


def _paper(method: str, family: str, metric: int = 0) -> str:
    values = [paper.PER_STREAM[s][method][metric][0] for s in FAMILY_STREAMS[family]]
    return f"{np.mean(values):.1f}"


CLAIMS: tuple[Claim, ...] = (
    Claim(
        "PointMaze: HiSPO nearly matches the best, PNN, with far less memory",
        "§5.3",
        f"HiSPO {_paper('hispo', 'pointmaze')} / {_paper('hispo', 'pointmaze', 3)}, "
        f"PNN {_paper('pnn', 'pointmaze')} / {_paper('pnn', 'pointmaze', 3)}",
        matches_with_less_memory("pointmaze", "pnn"),
        "HiSPO and PNN on both PointMaze streams",
    ),
    Claim(
        "PointMaze: FTN and SCN perform high but store more than HiSPO",
        "§5.3",
        f"FTN {_paper('ftn', 'pointmaze')} / 4.0, SCN {_paper('scn', 'pointmaze')} / 4.0",
        high_but_more_memory("pointmaze", ("ftn", "scn")),
        "HiSPO, FTN and SCN on both PointMaze streams",
    ),
    Claim(
        "PointMaze: the regularisers and naive methods fail (L2, EWC, FT1, SC1, FZ)",
        "§5.3",
        "PER " + ", ".join(f"{m} {_paper(m, 'pointmaze')}" for m in ("l2", "ewc", "ft1", "sc1")),
        fail_against_hispo("pointmaze", ("l2", "ewc", "ft1", "sc1", "frz")),
        "HiSPO, L2, EWC, FT1, SC1 and FZ on both PointMaze streams",
    ),
    Claim(
        "AntMaze: HiSPO approaches the best, PNN, with far less memory",
        "§5.3",
        f"HiSPO {_paper('hispo', 'antmaze')} / {_paper('hispo', 'antmaze', 3)}, "
        f"PNN {_paper('pnn', 'antmaze')} / {_paper('pnn', 'antmaze', 3)}",
        matches_with_less_memory("antmaze", "pnn"),
        "PNN on both AntMaze streams",
    ),
    Claim(
        "AntMaze: FTN and SCN perform slightly below HiSPO with similar memory",
        "§5.3",
        f"FTN {_paper('ftn', 'antmaze')}, SCN {_paper('scn', 'antmaze')}, "
        f"HiSPO {_paper('hispo', 'antmaze')}",
        slightly_below_similar_memory("antmaze", ("ftn", "scn")),
        "FTN and SCN on both AntMaze streams",
    ),
    Claim(
        "AntMaze: EWC, FT1 and FZ underperform",
        "§5.3",
        "PER " + ", ".join(f"{m} {_paper(m, 'antmaze')}" for m in ("ewc", "ft1", "frz")),
        fail_against_hispo("antmaze", ("ewc", "ft1", "frz")),
        "EWC, FT1 and FZ on both AntMaze streams",
    ),
    Claim(
        "Video games: HiSPO is as effective as PNN and FTN with less memory",
        "§5.3",
        f"HiSPO {_paper('hispo', 'videogame')} / {_paper('hispo', 'videogame', 3)}, "
        f"PNN {_paper('pnn', 'videogame')} / {_paper('pnn', 'videogame', 3)}, "
        f"FTN {_paper('ftn', 'videogame')} / {_paper('ftn', 'videogame', 3)}",
        matches_with_less_memory("videogame", "pnn", "ftn"),
        "HiSPO, PNN and FTN on both video-game streams",
    ),
    Claim(
        "Table 1's order of mean PER: PNN > HiSPO > FTN > SCN > FT1 > EWC > L2 > SC1 > FZ",
        "Table 1",
        "89.3 > 87.7 > 86.8 > 84.4 > 54.4 > 49.7 > 48.6 > 42.3 > 35.9 (six streams)",
        table1_order(streams_with(TABLE1_ORDER)),
        "every method of Table 1 on some stream",
    ),
    Claim(
        "Architectural methods do not forget: BWT 0 for SCN, FTN, PNN and HiSPO",
        "§5.4",
        "BWT 0.0 for each",
        no_forgetting(ARCHITECTURAL, streams_with(ARCHITECTURAL)),
        "SCN, FTN, PNN and HiSPO on some stream",
    ),
    Claim(
        "The regularisers forget: EWC and L2 have negative BWT",
        "§5.4",
        "BWT EWC -39.0, L2 -34.4",
        forgets(("ewc", "l2"), streams_with(("ewc", "l2"))),
        "EWC and L2 on some stream",
    ),
    Claim(
        "FT1 and FTN transfer forward; HiSPO only modestly",
        "§5.4",
        "FWT FT1 3.6, FTN 3.6, HiSPO 2.0",
        fwt_order(streams_with(("ft1", "ftn", "hispo"))),
        "FT1, FTN and HiSPO on some stream",
    ),
    Claim(
        "Ablation: CSP is far below CSPO and HiSPO",
        "Table 2",
        "CSP 42.4 / 2.7, CSPO 77.6 / 2.3, HiSPO 80.1 / 2.2",
        ablation(lambda s: below(s["csp"], s["cspo"]) and below(s["csp"], s["hispo"])),
        "CSP, CSPO and HiSPO on both AntMaze streams",
    ),
    Claim(
        "Ablation: HiSPO performs as well as CSPO with less memory",
        "Table 2",
        "HiSPO 80.1 / 2.2, CSPO 77.6 / 2.3",
        ablation(
            lambda s: not below(s["hispo"], s["cspo"]) and s["hispo"].mem < s["cspo"].mem,
            ("cspo", "hispo"),
        ),
        "CSPO and HiSPO on both AntMaze streams",
    ),
    Claim(
        "HiLOW's low-rank anchors store less than HiSPO's (an AntMaze stream)",
        "Figure 3",
        "a figure without numbers",
        hilow_less_memory,
        "HiLOW on both AntMaze streams",
    ),
    Claim(
        "PNN's memory cost grows exponentially with the number of tasks",
        "§5.3",
        "Figure 2 (no numbers)",
        pnn_growth,
        "a PNN run on PointMaze-1",
    ),
    Claim(
        "On random AntMaze streams HiSPO's subspaces grow sublinearly, PNN's memory much faster",
        "Figure 2d",
        "a figure without numbers",
        random_growth,
        "HiSPO on a random AntMaze stream of the random-streams grid",
    ),
    Claim(
        "PAC: the previous subspace is taken zero-shot where it fits, without expanding",
        "§5.5.3",
        "no figures",
        pac_transfers,
        "a HiSPO-PAC run",
    ),
)


def claims_markdown(house_root: Path, protocol_root: Path) -> str:
    """Every claim of :data:`CLAIMS` with the paper's figures and ours under the house
    protocol (runs under ``house_root``) and the paper's (runs under ``protocol_root``)."""
    house, protocol = Committed(house_root), Committed(protocol_root)
    lines = [
        "# The paper's claims and our verdicts\n",
        "| claim | where | paper | house protocol | verdict | paper's protocol | verdict |",
        "|---|---|---|---|---|---|---|",
    ]
    for claim in CLAIMS:
        cells = []
        for committed in (house, protocol):
            found = claim.test(committed)
            cells += ["", f"not tested here: needs {claim.needs}"] if found is None else found
        lines.append(
            f"| {claim.text} | {claim.where} | {claim.paper_figures} | " + " | ".join(cells) + " |"
        )
    legend = (
        "\nOurs: per method over the streams named (runs × streams), PER's interquartile mean "
        "with its 95 % stratified bootstrap interval (none on one seed) and the mean MEM, BWT "
        "or FWT; the paper's: "
        "the mean of its per-stream tables (PER / MEM), or its Table 1 and 2 as printed. "
        "Rules: *nearly matches*, *as well* and *approaches* hold when HiSPO's PER interval "
        "overlaps or lies above the other's; *fail* and *far below* when the interval lies wholly "
        f"below; *perform high* when the mean PER is at most {HIGH:g} points below HiSPO's; "
        "*slightly below with similar memory* when the mean PER is lower and MEM within 25 %; "
        f"*no forgetting* when |BWT| ≤ {ZERO}; *grow sublinearly* when HiSPO adds less MEM "
        "per task over the last half of a stream than over its first (its mean curve over the "
        "random AntMaze streams it ran) and PNN's structure more than HiSPO there. "
        f"A verdict resting on fewer than {MIN_SEEDS} seeds "
        "of a method (the paper's count) is given as provisional, with the seeds it has. "
        "The house protocol is hispo-pl's defaults "
        "(docs/results/<stream>/, the random streams under docs/results/random-streams/); "
        "the paper's is its recipe at its converged budget "
        "(docs/results/paper-protocol/<stream>/).\n"
    )
    return "\n".join(lines) + "\n" + legend


def write_claims_report(folder: Path) -> str:
    """Write ``claims.md`` in a claims folder (its ``claims.json`` names the two roots,
    relative to it); returns the text."""
    folder = Path(folder)
    roots = json.loads((folder / CLAIMS_FILE).read_text())
    text = claims_markdown(folder / roots["house"], folder / roots["protocol"])
    atomic_write_text(folder / "claims.md", text)
    return text
