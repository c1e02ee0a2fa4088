"""The curves of a grid's long streams after each task, which the growth report writes and
draws (:mod:`.growth_report`, :mod:`.growth_figures`): MEM after each task, measured in the runs
of the methods that decide their memory (HiSPO, CSPO, HiLOW: each run's ``mem_per_task``) and
grown from the structure of those whose memory follows from it (SCN, FTN, PNN: :mod:`.growth`);
PER after each task from each run's success matrix; the anchors held after each task; the
anchors each task's search weighed and the seconds it took; the MEM added on new tasks and on
repeats, and each decision on a repeat beside what the earlier task's own weights score
(:class:`RepeatCheck`); and how a curve grows (:class:`Growth`).

    data = growth_data(grid, Committed(root))
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..results import CriticDecision, Decision, LossDecision, ZeroShotDecision
from ..tasks import parse_random_stream, parse_task, stream_specs

STRUCTURAL = ("scn", "ftn", "pnn")  # memory from the structure alone (grown, not trained)
_ANCHORED = (LossDecision, CriticDecision, ZeroShotDecision)  # records that count anchors


def has_random_streams(streams: Sequence[str]) -> bool:
    """Whether a grid's streams include a random one: a study of long streams, which gets the
    growth report."""
    return any(parse_random_stream(s) is not None for s in streams)


def family_of(stream: str) -> str:
    """The task family a stream draws from: ``random-antmaze-8@3`` → ``antmaze``."""
    random = parse_random_stream(stream)
    return random[0] if random else parse_task(stream_specs(stream)[0]).family


def per_after_each_task(R: Sequence[Sequence[float | None]]) -> list[float]:
    """PER after each task ``k``: the mean success over the tasks seen so far, ``R[k][:k+1]``.

    Example:
        >>> per_after_each_task([[1.0, 0.0], [0.5, 1.0]])
        [1.0, 0.75]
    """
    return [float(np.mean([float(v) for v in row[: k + 1]])) for k, row in enumerate(R)]


def repeats_of(stream: Sequence[str]) -> list[bool]:
    """Whether each task of a stream repeats an earlier one (the same task): a random stream
    draws with replacement, so its later tasks are repeats more often, and a memory that grows
    only on new tasks slows down for that reason alone.

    Example:
        >>> repeats_of(["pointmaze-umaze-N[9]", "pointmaze-large-N[9]", "pointmaze-umaze-N[9]"])
        [False, False, True]
    """
    seen: set[str] = set()
    repeats = []
    for task in stream:
        repeats.append(task in seen)
        seen.add(task)
    return repeats


def memory_added(runs: Sequence[RunCurves]) -> dict[bool, tuple[float, int]]:
    """The MEM a task adds (after the first), pooled over ``runs``: keyed by whether the task
    repeats an earlier one, the mean added and the number of such tasks; a kind no run has is
    left out.

    Example:
        >>> run = RunCurves("s", "m", 0, [1.0, 2.0, 2.0, 2.5], [1.0] * 4, None,
        ...                 repeats=[False, False, True, False])
        >>> memory_added([run])
        {False: (0.75, 2), True: (0.0, 1)}
    """
    added: dict[bool, list[float]] = {False: [], True: []}
    for run in runs:
        if run.memory is None:
            continue
        for k in range(1, min(len(run.memory), len(run.repeats))):
            added[run.repeats[k]].append(run.memory[k] - run.memory[k - 1])
    return {kind: (float(np.mean(v)), len(v)) for kind, v in added.items() if v}


def memory_added_text(runs: Sequence[RunCurves]) -> str:
    """:func:`memory_added` in words ("" when no run measured its MEM after each task).

    Example:
        >>> run = RunCurves("s", "m", 0, [1.0, 2.0, 2.0], [1.0] * 3, None,
        ...                 repeats=[False, False, True])
        >>> memory_added_text([run])
        '1.00 per new task after the first (1) and 0.00 per repeat (1)'
    """
    added = memory_added(runs)
    return " and ".join(
        f"{added[repeat][0]:.2f} per {name} ({added[repeat][1]})"
        for repeat, name in ((False, "new task after the first"), (True, "repeat"))
        if repeat in added
    )


@dataclass(frozen=True)
class RepeatCheck:
    """A subspace's decision on a task that repeats an earlier one, beside the loss the
    earlier task's own weights score there (``own``; None when no earlier decision recorded
    one). The same task gives the same held-out batches and the anchors those weights mix are
    frozen, so they score on the repeat what they scored when they were chosen: ``l_curr`` of
    an earlier task that kept its anchor, ``l_prev`` of one that pruned it (the lowest over
    the task's earlier occurrences)."""

    task: int  # the repeat, 0-based
    earlier: int  # its latest earlier occurrence, 0-based
    subspace: str
    decision: str
    eps: float
    l_curr: float
    l_prev: float | None
    own: float | None

    @property
    def own_prunes(self) -> bool | None:
        """Whether the pruning rule takes the earlier task's own weights (what the search finds
        with ``stored_points``); None without them."""
        from ..decisions import keep_previous

        return None if self.own is None else keep_previous(self.own, self.l_curr, self.eps)


def _chosen_loss(d: LossDecision) -> float | None:
    """The held-out loss of the weights a decision stores for its task."""
    return d.l_prev if d.decision == "prune" else d.l_curr


def repeat_checks(stream: Sequence[str], decisions: Sequence[Decision]) -> list[RepeatCheck]:
    """Every loss decision a run took on a task that repeats an earlier one of ``stream``, in
    task order, each with the loss the earlier task's own weights score on it
    (:class:`RepeatCheck`).

    Example:
        >>> from hispo_pl.results import LossDecision
        >>> d = [LossDecision(task=0, subspace="high", decision="first", l_curr=0.2),
        ...      LossDecision(task=1, subspace="high", decision="keep", eps=0.1, l_curr=0.3,
        ...                   l_prev=0.5)]
        >>> [(c.own, c.own_prunes) for c in repeat_checks(["a", "a"], d)]
        [(0.2, True)]
    """
    occurrences: dict[str, list[int]] = {}
    for k, task in enumerate(stream):
        occurrences.setdefault(task, []).append(k)
    loss = [d for d in decisions if isinstance(d, LossDecision) and d.l_curr is not None]
    checks = []
    for d in loss:
        if not 0 <= d.task < len(stream):
            continue
        earlier = [k for k in occurrences[stream[d.task]] if k < d.task]
        if not earlier or d.eps is None:
            continue
        owns = [
            own
            for e in loss
            if e.task in earlier and e.subspace == d.subspace
            if (own := _chosen_loss(e)) is not None
        ]
        checks.append(
            RepeatCheck(
                d.task,
                earlier[-1],
                d.subspace,
                d.decision,
                float(d.eps),
                float(d.l_curr),
                d.l_prev,
                min(owns) if owns else None,
            )
        )
    return checks


def anchors_after_each_task(decisions: Sequence[Decision], n_tasks: int) -> list[int] | None:
    """The anchors a run holds after each task, summed over its subspaces (each subspace's
    count after its last decision of the task, kept until its next); None for a run that made
    no decision on anchors (SCN, PNN)."""
    counts: dict[str, int] = {}
    after: list[int] = []
    anchored = [d for d in decisions if isinstance(d, _ANCHORED) and d.anchors is not None]
    if not anchored:
        return None
    for task in range(n_tasks):
        for d in anchored:
            if d.task == task:
                counts[d.subspace] = int(d.anchors)
        after.append(sum(counts.values()))
    return after


def anchors_searched_each_task(decisions: Sequence[Decision], n_tasks: int) -> list[int | None]:
    """The anchors each task's search weighed, summed over the subspaces it searched: each
    subspace's grown point (``alpha_curr``) has a weight per anchor. None for a task without a
    search (a method that searches none, a task decided before the search ran).

    Example:
        >>> from hispo_pl.results import LossDecision
        >>> d = [LossDecision(task=1, subspace=s, decision="keep", alpha_curr=[0.5, 0.5])
        ...      for s in ("high", "low")]
        >>> anchors_searched_each_task(d, 2)
        [None, 4]
    """
    searched: list[dict[str, int]] = [{} for _ in range(n_tasks)]
    for d in decisions:
        alpha = getattr(d, "alpha_curr", None)
        if alpha is not None and 0 <= d.task < n_tasks:
            searched[d.task][d.subspace] = len(alpha)
    return [sum(task.values()) if task else None for task in searched]


@dataclass(frozen=True)
class Growth:
    """How a curve of values after each task grows: per task over the first half of the
    stream (tasks 2..h, h = n // 2) and over the last half (tasks h+1..n), the least-squares
    slope over all n tasks, and the last value. Each is linear in the curve, so the growth of
    the mean curve over seeds is the mean of the seeds' growths."""

    first_half: float | None
    last_half: float | None
    slope: float | None
    final: float

    @property
    def slows(self) -> bool:
        """Growth that slows over a finite stream, what sublinear growth looks like there:
        less per task over the last half than over the first (False where a half is undefined).
        """
        halves = (self.first_half, self.last_half)
        return None not in halves and self.last_half < self.first_half

    @classmethod
    def of(cls, values: Sequence[float]) -> Growth:
        """Example:
        >>> Growth.of([1.0, 2.0, 2.5, 3.0])
        Growth(first_half=1.0, last_half=0.5, slope=0.65, final=3.0)
        """
        v = np.asarray(values, dtype=float)
        n, h = len(v), len(v) // 2
        first = float((v[h - 1] - v[0]) / (h - 1)) if h >= 2 else None
        last = float((v[-1] - v[h - 1]) / (n - h)) if h >= 1 else None
        slope = float(np.polyfit(np.arange(1, n + 1), v, 1)[0]) if n >= 2 else None
        return cls(first, last, None if slope is None else round(slope, 12), float(v[-1]))


@dataclass(frozen=True)
class RunCurves:
    """One committed run's curves after each task: MEM (None: not measured after every task),
    PER (from its success matrix) and the anchors it holds (None: it decides none); per task,
    the anchors its search weighed, the search's seconds and the task's wall seconds (None
    where not recorded)."""

    stream: str
    method: str
    seed: int
    memory: list[float] | None
    per: list[float]
    anchors: list[int] | None
    searched: list[int | None] = field(default_factory=list)
    search_seconds: list[float | None] = field(default_factory=list)
    wall_seconds: list[float | None] = field(default_factory=list)
    repeats: list[bool] = field(default_factory=list)  # per task: a repeat of an earlier one
    repeat_checks: list[RepeatCheck] = field(default_factory=list)  # decisions on the repeats


@dataclass
class GrowthData:
    """What the growth report draws from: each committed run's curves, the structural memory of
    SCN / FTN / PNN per (family, method) for the family's longest stream, and the grid's cells
    not committed yet as (stream, method, seed)."""

    runs: list[RunCurves]
    structure: dict[tuple[str, str], list[float]] = field(default_factory=dict)
    missing: list[tuple[str, str, int]] = field(default_factory=list)
    families: dict[str, list[str]] = field(default_factory=dict)  # family -> its streams

    def of(self, family: str, method: str) -> list[RunCurves]:
        streams = self.families.get(family, [])
        return [r for r in self.runs if r.stream in streams and r.method == method]


def growth_data(grid, committed, config_dir: Path | None = None) -> GrowthData:
    """The curves of every committed run of ``grid`` (a :class:`~.grid.Grid`) under
    ``committed`` (a :class:`~.grid_report.Committed`), the structural memory of the methods
    whose memory follows from their structure (grown from ``config_dir``'s configs with the
    grid's fit arguments, as long as the family's longest committed run or, before any, its
    first stream), and the cells not committed yet."""
    from ..config_files import config_root
    from .growth import module_for, structural_memory
    from .plan import stream_config_path, stream_fit_args

    config_dir = Path(config_dir) if config_dir is not None else config_root()
    families: dict[str, list[str]] = {}
    for stream in grid.streams:
        families.setdefault(family_of(stream), []).append(stream)
    runs, missing = [], []
    for stream in grid.streams:
        done = {(r.method, r.seed): r for r in committed.records(stream)}
        for method in grid.methods:
            for seed in grid.seeds:
                record = done.get((method, seed))
                if record is None:
                    missing.append((stream, method, seed))
                    continue
                results = record.results
                memory, n = results.mem_per_task, len(results.stream)
                phases = list(results.phase_time_s or [None] * n)
                runs.append(
                    RunCurves(
                        stream,
                        method,
                        seed,
                        None if not memory or None in memory else [float(m) for m in memory],
                        per_after_each_task(results.R),
                        anchors_after_each_task(record.decisions, n),
                        anchors_searched_each_task(record.decisions, n),
                        [(p or {}).get("search") for p in phases],
                        list(results.wall_time_s or [None] * n),
                        repeats_of(results.stream),
                        repeat_checks(results.stream, record.decisions),
                    )
                )
    structure = {}
    for family, streams in families.items():
        lengths = [len(r.per) for r in runs if r.stream in streams]
        n = max(lengths) if lengths else max(len(stream_specs(s)) for s in streams)
        stream = streams[0]
        for method in STRUCTURAL:
            method_config = config_dir / "methods" / f"{method}.yaml"
            if not method_config.is_file():
                continue
            configs = [stream_config_path(stream, config_dir), method_config]
            module = module_for(configs, *stream_fit_args(stream), *grid.extra)
            structure[(family, method)] = structural_memory(module, n)
    return GrowthData(runs, structure, missing, families)


def _family_title(family: str, streams: Sequence[str]) -> str:
    lengths = sorted({len(stream_specs(s)) for s in streams})
    tasks = "/".join(map(str, lengths))
    return f"{family} ({len(streams)} stream{'s' * (len(streams) > 1)} of {tasks} tasks)"


def mean_curve(curves: Sequence[Sequence[float]]) -> list[float]:
    """The mean over runs of curves after each task, as long as the shortest."""
    n = min(len(c) for c in curves)
    return [float(v) for v in np.mean([list(c)[:n] for c in curves], axis=0)]
