"""The verdict rules of the paper's claims, on one protocol's committed runs: a method's figures
over a set of streams (:class:`Stats`, PER's IQM with its interval drawn when first asked
for), and the small pure functions that say what "nearly matches", "fails" or "no forgetting"
mean here. A verdict is ``holds``, ``does not hold`` or, where a claim's runs are missing,
``None`` (not tested).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from hispo_pl.benchmark.grid_report import Committed, iqm_interval

FAMILY_STREAMS = {
    "pointmaze": ("pointmaze-1", "pointmaze-2"),
    "antmaze": ("antmaze-1", "antmaze-2"),
    "videogame": ("videogame-1", "videogame-2"),
}
TABLE1_ORDER = ("pnn", "hispo", "ftn", "scn", "ft1", "ewc", "l2", "sc1", "frz")  # its PER order
ZERO = 0.5  # a BWT within half a point of 0 is no forgetting
MIN_SEEDS = 3  # the paper's seeds per cell: a verdict on fewer is given as provisional


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
    fwt_seeds: int | None = None  # seeds with an FWT on every stream (None: all of them)

    @property
    def seeds(self) -> int:
        """The seeds behind the IQM: those every stream of the claim has."""
        return len(self.scores)

    def seeds_of(self, what: Sequence[str] = ("per",)) -> int:
        """The seeds behind the figures ``what``: FWT only rests on the seeds that have a
        from-scratch run of their own to be measured against."""
        if "fwt" in what and self.fwt_seeds is not None:
            return self.fwt_seeds
        return self.seeds

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
        if self.seeds < 2:  # a bootstrap over one seed draws no interval
            return f"PER {point:.1f}"
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

    def mean(name: str, scale: float = 100.0, runs=every) -> float:
        values = [scale * m[name] for m in runs if m.get(name) is not None]
        return float(np.mean(values)) if values else float("nan")

    measured = [
        seed for seed in seeds if all(by_stream[s][seed].get("FWT") is not None for s in streams)
    ]
    fwt = mean("FWT", runs=[by_stream[s][seed] for seed in measured for s in streams])
    return Stats(scores, mean("PER"), mean("BWT"), fwt, mean("MEM", 1.0), len(every), len(measured))


def streams_run_by(
    committed: Committed, streams: Sequence[str], methods: Sequence[str]
) -> list[str]:
    """The streams of ``streams`` where every one of ``methods`` has a run: those where each
    has :data:`MIN_SEEDS` seeds, if any stream has, else all of them (a provisional verdict).
    A claim over "some stream" is thus judged as the aggregate counts a method, and a stream's
    first seed does not draw a verdict on full seeds down to one."""
    stats = {s: [method_stats(committed, [s], m) for m in methods] for s in streams}
    ran = [s for s in streams if all(stats[s])]
    full = [s for s in ran if all(x.seeds >= MIN_SEEDS for x in stats[s])]
    return full or ran


# --- the verdict rules: pure -------------------------------------------------------------------


def overlaps(a: Stats, b: Stats) -> bool:
    """The two IQM intervals of PER overlap: neither is separable from the other here."""
    return a.per_iqm[1] <= b.per_iqm[2] and b.per_iqm[1] <= a.per_iqm[2]


def below(a: Stats, b: Stats) -> bool:
    """``a``'s PER interval lies wholly below ``b``'s."""
    return a.per_iqm[2] < b.per_iqm[1]


def verdict(ok: bool) -> str:
    return "holds" if ok else "does not hold"


def judged(stats: Mapping[str, Stats], ok: bool, what: Sequence[str] = ("per",)) -> str:
    """The verdict ``ok`` gives on ``stats``, marked provisional (with the seeds it rests on)
    where a method has fewer than :data:`MIN_SEEDS` seeds behind the figures ``what`` on the
    claim's streams.

    Example:
        >>> one = Stats(((90.0, 91.0),), 90.5, 0.0, 0.0, 1.0, 2)
        >>> judged({"hispo": one}, True)
        'provisionally holds (1 seed of 3)'
    """
    return provisional(ok, min(s.seeds_of(what) for s in stats.values()))


def provisional(ok: bool, seeds: int) -> str:
    """The verdict ``ok`` gives, marked provisional where it rests on fewer than
    :data:`MIN_SEEDS` seeds (``seeds``: the fewest a method has behind it)."""
    if seeds >= MIN_SEEDS:
        return verdict(ok)
    return f"provisionally {verdict(ok)} ({seeds} seed{'s' * (seeds > 1)} of {MIN_SEEDS})"


def seeds_text(stats: Mapping[str, Stats], what: Sequence[str] = ("per",)) -> str:
    """How many seeds the figures ``what`` rest on: once when every method has the same count.

    Example:
        >>> one = Stats(((90.0,),), 90.0, 0.0, 0.0, 1.0, 1)
        >>> seeds_text({"a": one, "b": one})
        '1 seed each'
    """
    counts = {m: s.seeds_of(what) for m, s in stats.items()}
    if len(set(counts.values())) == 1:
        n = next(iter(counts.values()))
        return f"{n} seed{'s' * (n > 1)} each"
    return "seeds " + ", ".join(f"{m} {n}" for m, n in counts.items())


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
    figures = "; ".join(f"{m}: " + ", ".join(s.text(w) for w in what) for m, s in stats.items())
    return f"{figures} ({seeds_text(stats, what)})"


def rule_on_family(
    family: str,
    methods: Sequence[str],
    ok: Callable[[dict[str, Stats]], bool],
    what: Sequence[str] = ("per", "mem"),
) -> Callable:
    """A claim on ``methods`` over a family's streams, judged by ``ok`` on their stats."""

    def test(committed: Committed):
        stats = _stats(committed, family, methods)
        return None if stats is None else (_figures(stats, what), judged(stats, ok(stats), what))

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
        return _figures(found, what), judged(found, ok(found), what)

    return test


def matches_with_less_memory(family: str, *others: str) -> Callable:
    """HiSPO's PER interval overlaps (or lies above) each of ``others``', with less memory."""

    def ok(s: dict[str, Stats]) -> bool:
        h = s["hispo"]
        return all(not below(h, s[o]) and h.mem < s[o].mem for o in others)

    return rule_on_family(family, ("hispo", *others), ok)


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
        figures = f"{text} ({len(streams)} streams, {seeds_text(found)})"
        return figures, judged(found, tuple(ours) == TABLE1_ORDER)

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


def ablation(
    ok: Callable[[dict[str, Stats]], bool], methods: tuple[str, ...] = ("csp", "cspo", "hispo")
) -> Callable:
    """The AntMaze ablation judged by ``ok`` on ``methods`` (of CSP, CSPO, HiSPO: those the
    claim compares, so another's seeds do not make its verdict provisional)."""
    return rule_on_family("antmaze", methods, ok)


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
    from hispo_pl.benchmark.growth import module_for, structural_memory
    from hispo_pl.config_files import config_root

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
    methods = ("hispo-pac", "hispo")
    have = streams_run_by(committed, [s for f in FAMILY_STREAMS.values() for s in f], methods)
    if not have:
        return None
    stats = {m: method_stats(committed, have, m) for m in methods}
    ok = not below(stats["hispo-pac"], stats["hispo"])
    return _figures(stats), judged(stats, ok)


RANDOM_STREAMS = "random-streams"  # the grid of long random streams, committed in this folder


def random_growth(committed: Committed):
    """HiSPO's memory on the random AntMaze streams of the ``random-streams`` grid (committed in
    that folder of the protocol's root) grows sublinearly, and PNN's, grown from its structure,
    faster: HiSPO's mean MEM curve over the streams it ran slows
    (:attr:`~hispo_pl.benchmark.growth_curves.Growth.slows`), and PNN adds more per task than
    HiSPO over the last half."""
    key = ("claims", RANDOM_STREAMS)
    if key not in committed.cache:
        committed.cache[key] = _random_growth(committed.root / RANDOM_STREAMS)
    return committed.cache[key]


def _random_growth(root: Path):
    from hispo_pl.benchmark.grid import load_grid
    from hispo_pl.benchmark.growth_curves import (
        Growth,
        growth_data,
        mean_curve,
        memory_added_text,
    )
    from hispo_pl.config_files import config_root

    if not root.is_dir():
        return None
    whole = load_grid(RANDOM_STREAMS, config_root())
    streams = whole.parts["antmaze"]
    data = growth_data(replace(whole, streams=streams, methods=("hispo",)), Committed(root))
    curves = [r.memory for r in data.runs if r.memory is not None]
    if not curves:
        return None
    mean = mean_curve(curves)
    hispo = Growth.of(mean)
    pnn = Growth.of(data.structure[("antmaze", "pnn")])
    ran = sorted({r.stream for r in data.runs})
    seeds = min(sum(r.stream == s for r in data.runs) for s in ran)
    text = (
        f"hispo: MEM per task {hispo.first_half:.2f} over the first half, {hispo.last_half:.2f} "
        f"over the last, {hispo.final:.2f} after {len(mean)} tasks "
        f"({memory_added_text(data.runs)}); "
        f"pnn (structure): {pnn.first_half:.2f}, {pnn.last_half:.2f}, {pnn.final:.2f} "
        f"({len(ran)} of {len(streams)} random AntMaze streams: {', '.join(ran)})"
    )
    ok = hispo.slows and pnn.last_half > hispo.last_half
    return text, provisional(ok, seeds)
