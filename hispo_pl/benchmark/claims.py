"""The paper's claims on performance and memory, forgetting and generalisation, and its
ablations, each with our figures and a verdict under two protocols: the house defaults (the
runs under ``docs/results/<stream>/``) and the paper's own recipe at its converged budget (the
runs under ``docs/results/paper-protocol/<stream>/``). Rebuilt from the committed files like
every report: a folder holding ``claims.json`` (the two roots) gets ``claims.md``, and
``embed_reports`` rebuilds a page's copy of it; the verdict rules are the small functions
below, so a reader can see what "nearly matches" means here.

A verdict is ``holds``, ``does not hold`` or ``not tested here`` with the reason: a claim is
tested only where every stream it speaks of has runs of every method it names.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from ..io import atomic_write_text
from . import paper
from .grid_report import Committed, iqm_interval

FAMILY_STREAMS = {
    "pointmaze": ("pointmaze-1", "pointmaze-2"),
    "antmaze": ("antmaze-1", "antmaze-2"),
    "videogame": ("videogame-1", "videogame-2"),
}
CLAIMS_FILE = "claims.json"  # a claims folder's two roots, relative to it: house, protocol
TABLE1_ORDER = ("pnn", "hispo", "ftn", "scn", "ft1", "ewc", "l2", "sc1", "frz")  # its PER order
ZERO = 0.5  # a BWT within half a point of 0 is no forgetting


@dataclass(frozen=True)
class Stats:
    """One method over a set of streams: the means of PER, BWT, FWT (×100) and MEM over its
    runs, and PER's IQM with its 95 % interval (×100, runs × streams stratified), drawn when
    first asked for."""

    scores: tuple[tuple[float, ...], ...]  # PER ×100, seeds × streams
    per: float
    bwt: float
    fwt: float
    mem: float
    runs: int

    @cached_property
    def per_iqm(self) -> tuple[float, float, float]:
        return iqm_interval(np.array(self.scores))

    def text(self, what: str = "per") -> str:
        point, low, high = self.per_iqm
        if what == "mem":
            return f"MEM {self.mem:.2f}"
        if what == "bwt":
            return f"BWT {self.bwt:.1f}"
        if what == "fwt":
            return f"FWT {self.fwt:.1f}"
        return f"PER {point:.1f} [{low:.1f}, {high:.1f}]"


def method_stats(committed: Committed, streams: Sequence[str], method: str) -> Stats | None:
    """``method`` over ``streams`` (None unless every stream has a run of it), once per
    protocol's committed runs. The IQM takes the seeds every stream has."""
    key = ("claims", tuple(streams), method)
    if key not in committed.cache:
        committed.cache[key] = _method_stats(committed, streams, method)
    return committed.cache[key]


def _method_stats(committed: Committed, streams: Sequence[str], method: str) -> Stats | None:
    if not streams:
        return None
    by_stream = {}
    for stream in streams:
        runs = {r.seed: m for r, m, _ in committed.measured(stream) if r.method == method}
        if not runs:
            return None
        by_stream[stream] = runs
    seeds = sorted(set.intersection(*(set(r) for r in by_stream.values())))
    if not seeds:
        return None
    scores = tuple(tuple(100 * by_stream[s][seed]["PER"] for s in streams) for seed in seeds)
    every = [m for runs in by_stream.values() for m in runs.values()]

    def mean(name: str, scale: float = 100.0) -> float:
        values = [scale * m[name] for m in every if m.get(name) is not None]
        return float(np.mean(values)) if values else float("nan")

    return Stats(scores, mean("PER"), mean("BWT"), mean("FWT"), mean("MEM", 1.0), len(every))


# --- the verdict rules: pure -------------------------------------------------------------------


def overlaps(a: Stats, b: Stats) -> bool:
    """The two IQM intervals of PER overlap: neither is separable from the other here."""
    return a.per_iqm[1] <= b.per_iqm[2] and b.per_iqm[1] <= a.per_iqm[2]


def below(a: Stats, b: Stats) -> bool:
    """``a``'s PER interval lies wholly below ``b``'s."""
    return a.per_iqm[2] < b.per_iqm[1]


def verdict(ok: bool) -> str:
    return "holds" if ok else "does not hold"


@dataclass(frozen=True)
class Claim:
    """A claim of the paper, where it says it, and how it is tested on a protocol's runs:
    ``test(committed)`` gives (our figures, verdict), or None when it cannot be tested."""

    text: str
    where: str
    paper_figures: str
    test: Callable[[Committed], tuple[str, str] | None]
    needs: str  # what it needs, named when it cannot be tested


def _stats(committed: Committed, family: str, methods: Sequence[str]) -> dict[str, Stats] | None:
    found = {m: method_stats(committed, FAMILY_STREAMS[family], m) for m in methods}
    return None if any(s is None for s in found.values()) else found


def _figures(stats: dict[str, Stats], what: Sequence[str] = ("per", "mem")) -> str:
    return "; ".join(f"{m}: " + ", ".join(s.text(w) for w in what) for m, s in stats.items())


def rule_on_family(
    family: str,
    methods: Sequence[str],
    ok: Callable[[dict[str, Stats]], bool],
    what: Sequence[str] = ("per", "mem"),
) -> Callable:
    """A claim on ``methods`` over a family's streams, judged by ``ok`` on their stats."""

    def test(committed: Committed):
        stats = _stats(committed, family, methods)
        return None if stats is None else (_figures(stats, what), verdict(ok(stats)))

    return test


def rule_on_streams(
    methods: Sequence[str],
    ok: Callable[[dict[str, Stats]], bool],
    what: Sequence[str],
    streams_of: Callable[[Committed], Sequence[str]],
) -> Callable:
    """A claim on ``methods`` over the streams ``streams_of`` picks, judged by ``ok``."""

    def test(committed: Committed):
        streams = streams_of(committed)
        found = {m: method_stats(committed, streams, m) for m in methods}
        if not streams or any(s is None for s in found.values()):
            return None
        return _figures(found, what), verdict(ok(found))

    return test


def matches_with_less_memory(family: str, other: str) -> Callable:
    """HiSPO's PER interval overlaps (or lies above) ``other``'s, with less memory."""

    def ok(s: dict[str, Stats]) -> bool:
        return not below(s["hispo"], s[other]) and s["hispo"].mem < s[other].mem

    return rule_on_family(family, ("hispo", other), ok)


HIGH = 5.0  # "high performance" beside HiSPO: a mean PER at most this many points below it


def high_but_more_memory(family: str, others: Sequence[str]) -> Callable:
    """``others`` perform high (mean PER within :data:`HIGH` points of HiSPO's, or above) but
    store more than HiSPO."""

    def ok(s: dict[str, Stats]) -> bool:
        h = s["hispo"]
        return all(s[o].per >= h.per - HIGH and s[o].mem > h.mem for o in others)

    return rule_on_family(family, ("hispo", *others), ok)


def slightly_below_similar_memory(family: str, others: Sequence[str]) -> Callable:
    """``others`` lie below HiSPO in PER (mean) with memory within 25 % of its."""

    def ok(s: dict[str, Stats]) -> bool:
        h = s["hispo"]
        return all(s[o].per < h.per and abs(s[o].mem - h.mem) <= 0.25 * h.mem for o in others)

    return rule_on_family(family, ("hispo", *others), ok)


def fail_against_hispo(family: str, others: Sequence[str]) -> Callable:
    """Every one of ``others`` has a PER interval wholly below HiSPO's."""

    def ok(s: dict[str, Stats]) -> bool:
        return all(below(s[o], s["hispo"]) for o in others)

    return rule_on_family(family, ("hispo", *others), ok, ("per",))


def table1_order(streams_of: Callable[[Committed], Sequence[str]]) -> Callable:
    """Our mean PER over the streams every method has orders the methods as Table 1 does."""

    def test(committed: Committed):
        streams = streams_of(committed)
        found = {m: method_stats(committed, streams, m) for m in TABLE1_ORDER}
        if not streams or any(s is None for s in found.values()):
            return None
        ours = sorted(TABLE1_ORDER, key=lambda m: -found[m].per)
        text = " > ".join(f"{m} {found[m].per:.1f}" for m in ours)
        return f"{text} ({len(streams)} streams)", verdict(tuple(ours) == TABLE1_ORDER)

    return test


def no_forgetting(methods: Sequence[str], streams_of: Callable[[Committed], Sequence[str]]):
    """Every one of ``methods`` keeps BWT within :data:`ZERO` of 0."""

    def ok(s: dict[str, Stats]) -> bool:
        return all(abs(v.bwt) <= ZERO for v in s.values())

    return rule_on_streams(methods, ok, ("bwt",), streams_of)


def forgets(methods: Sequence[str], streams_of: Callable[[Committed], Sequence[str]]):
    """Every one of ``methods`` has a negative BWT."""

    def ok(s: dict[str, Stats]) -> bool:
        return all(v.bwt < -ZERO for v in s.values())

    return rule_on_streams(methods, ok, ("bwt",), streams_of)


def fwt_order(streams_of: Callable[[Committed], Sequence[str]]):
    """FT1 and FTN transfer forward (FWT > 0) and HiSPO less than FTN."""

    def ok(s: dict[str, Stats]) -> bool:
        return s["ft1"].fwt > 0 and s["ftn"].fwt > 0 and s["hispo"].fwt < s["ftn"].fwt

    return rule_on_streams(("ft1", "ftn", "hispo"), ok, ("fwt",), streams_of)


def ablation(ok: Callable[[dict[str, Stats]], bool]) -> Callable:
    """The AntMaze ablation (CSP, CSPO, HiSPO) judged by ``ok``."""
    return rule_on_family("antmaze", ("csp", "cspo", "hispo"), ok)


def _hilow_stores_less(s: dict[str, Stats]) -> bool:
    """HiLOW stores less than HiSPO (the paper's Figure 3 is an AntMaze stream)."""
    return s["hilow"].mem < s["hispo"].mem


hilow_less_memory = rule_on_family("antmaze", ("hilow", "hispo"), _hilow_stores_less)


def growth_order(memory: Sequence[float], rtol: float = 1e-6) -> int:
    """The degree of the polynomial in the task count that ``memory`` (MEM after each task)
    follows exactly: 1 when its increments are constant, 2 when their increments are, and so
    on (-1: none up to its length, e.g. exponential growth).

    Example:
        >>> growth_order([1, 2, 3, 4]), growth_order([1, 3, 6, 10, 15])
        (1, 2)
        >>> growth_order([1, 2, 4, 8, 16])
        -1
    """
    diffs = np.asarray(memory, dtype=float)
    for order in range(1, len(memory) - 1):
        diffs = np.diff(diffs)
        if np.allclose(diffs, diffs[0], rtol=rtol, atol=rtol):
            return order
    return -1


PNN_GROWTH_TASKS = 12  # tasks over which PNN's memory is grown from its structure


def pnn_growth(committed: Committed):
    """PNN's memory grown from its structure (PointMaze's reference config) over
    :data:`PNN_GROWTH_TASKS` tasks, pinned to a committed PNN run's MEM after its 4 tasks:
    exponential growth, as the paper says, or a polynomial of the task count."""
    from ..config_files import config_root
    from .growth import module_for, structural_memory

    runs = [m for r, m, _ in committed.measured("pointmaze-1") if r.method == "pnn"]
    if not runs:
        return None
    configs = config_root()
    module = module_for([configs / "streams/pointmaze-1.yaml", configs / "methods/pnn.yaml"])
    memory = structural_memory(module, PNN_GROWTH_TASKS)
    if not np.isclose(memory[3], runs[0]["MEM"], rtol=1e-6):
        return None  # the configs no longer build what the runs stored
    order = growth_order(memory)
    shape = {1: "linear", 2: "quadratic"}.get(order, f"of degree {order}" if order > 0 else "")
    text = (
        f"pnn: MEM {memory[3]:.2f} after 4 tasks (as its runs), {memory[7]:.2f} after 8, "
        f"{memory[-1]:.2f} after {PNN_GROWTH_TASKS}: {shape or 'faster than polynomial'}"
    )
    return text, verdict(order < 0)


def pac_transfers(committed: Committed):
    """HiSPO-PAC takes a task zero-shot somewhere, at no loss of PER against HiSPO."""
    streams = [s for f in FAMILY_STREAMS.values() for s in f]
    have = [s for s in streams if method_stats(committed, [s], "hispo-pac") is not None]
    if not have:
        return None
    stats = {m: method_stats(committed, have, m) for m in ("hispo-pac", "hispo")}
    if stats["hispo"] is None:
        return None
    ok = not below(stats["hispo-pac"], stats["hispo"])
    return _figures(stats), verdict(ok)


def streams_with_every_method(committed: Committed) -> list[str]:
    """The streams of the paper's tables where every method of Table 1 has a run."""
    return [
        s
        for s in paper.PER_STREAM
        if all(method_stats(committed, [s], m) is not None for m in TABLE1_ORDER)
    ]


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
        lambda c: _both_tests(
            c,
            matches_with_less_memory("videogame", "pnn"),
            matches_with_less_memory("videogame", "ftn"),
        ),  # fmt: skip
        "HiSPO, PNN and FTN on both video-game streams",
    ),
    Claim(
        "Table 1's order of mean PER: PNN > HiSPO > FTN > SCN > FT1 > EWC > L2 > SC1 > FZ",
        "Table 1",
        "89.3 > 87.7 > 86.8 > 84.4 > 54.4 > 49.7 > 48.6 > 42.3 > 35.9 (six streams)",
        table1_order(streams_with_every_method),
        "every method of Table 1 on some stream",
    ),
    Claim(
        "Architectural methods do not forget: BWT 0 for SCN, FTN, PNN and HiSPO",
        "§5.4",
        "BWT 0.0 for each",
        no_forgetting(("scn", "ftn", "pnn", "hispo"), streams_with_every_method),
        "SCN, FTN, PNN and HiSPO on some stream",
    ),
    Claim(
        "The regularisers forget: EWC and L2 have negative BWT",
        "§5.4",
        "BWT EWC -39.0, L2 -34.4",
        forgets(("ewc", "l2"), streams_with_every_method),
        "EWC and L2 on some stream",
    ),
    Claim(
        "FT1 and FTN transfer forward; HiSPO only modestly",
        "§5.4",
        "FWT FT1 3.6, FTN 3.6, HiSPO 2.0",
        fwt_order(streams_with_every_method),
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
        ablation(lambda s: not below(s["hispo"], s["cspo"]) and s["hispo"].mem < s["cspo"].mem),
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
        "PAC: the previous subspace is taken zero-shot where it fits, without expanding",
        "§5.5.3",
        "no figures",
        pac_transfers,
        "a HiSPO-PAC run",
    ),
)


def _both_tests(committed: Committed, *tests: Callable) -> tuple[str, str] | None:
    results = [t(committed) for t in tests]
    if any(r is None for r in results):
        return None
    figures = "; ".join(dict.fromkeys(p for r in results for p in r[0].split("; ")))
    return figures, verdict(all(r[1] == "holds" for r in results))


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
        "with its 95 % stratified bootstrap interval and the mean MEM, BWT or FWT; the paper's: "
        "the mean of its per-stream tables (PER / MEM), or its Table 1 and 2 as printed. "
        "Rules: *nearly matches*, *as well* and *approaches* hold when HiSPO's PER interval "
        "overlaps or lies above the other's; *fail* and *far below* when the interval lies wholly "
        f"below; *perform high* when the mean PER is at most {HIGH:g} points below HiSPO's; "
        "*slightly below with similar memory* when the mean PER is lower and MEM within 25 %; "
        f"*no forgetting* when |BWT| ≤ {ZERO}. The house protocol is hispo-pl's defaults "
        "(docs/results/<stream>/); the paper's is its recipe at its converged budget "
        "(docs/results/paper-protocol/<stream>/).\n"
    )
    return "\n".join(lines) + "\n" + legend


def write_claims_report(folder: Path) -> str:
    """Write ``claims.md`` in a claims folder (its ``claims.json`` names the two roots,
    relative to it); returns the text."""
    import json

    folder = Path(folder)
    roots = json.loads((folder / CLAIMS_FILE).read_text())
    text = claims_markdown(folder / roots["house"], folder / roots["protocol"])
    atomic_write_text(folder / "claims.md", text)
    return text
