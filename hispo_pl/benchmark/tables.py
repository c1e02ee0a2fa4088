"""The tables of a benchmark: the paper's table (Markdown and CSV), the decisions, the run
times."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence

import numpy as np

from ..metrics import METRIC, METRICS
from ..results import CriticDecision, Decision, LossDecision, decisions_table
from ..tasks import parse_task
from .finished_runs import MethodRow, RunRecord, format_mean_std

DERIVED = "†"  # marks a method some of whose runs were derived, not trained


def derived_footnote(method: str, derived: Sequence[tuple[str, int, str]], runs: int) -> str:
    """The footnote of a method marked :data:`DERIVED`: which of its ``runs`` runs were
    derived from another method's instead of trained, each ``derived`` as (stream, seed, source
    method), the stream empty in one stream's table. ``derived_footnote("ft1", [("", 0,
    "ftn")], 3)`` reads "† ft1: seed 0 derived from ftn's run of the same stream and seed,
    not trained; its other 2 runs trained (docs/results.md)."."""
    by_source: dict[str, dict[str, list[int]]] = {}
    for stream, seed, source in derived:
        by_source.setdefault(source, {}).setdefault(stream, []).append(seed)
    parts = []
    for source, streams in by_source.items():
        each = [
            f"{stream + ' ' if stream else ''}seed{'s' if len(seeds) > 1 else ''} "
            + ", ".join(str(s) for s in sorted(seeds))
            for stream, seeds in streams.items()
        ]
        where = " and ".join([", ".join(each[:-1]), each[-1]] if len(each) > 1 else each)
        parts.append(f"{where} derived from {source}'s run of the same stream and seed")
    rest = runs - len(derived)
    trained = f"; its other {rest} run{'s' if rest > 1 else ''} trained" if rest else ""
    return f"{DERIVED} {method}: {'; '.join(parts)}, not trained{trained} (docs/results.md)."


def derived_method(method: str, derived: Sequence) -> str:
    """``method``, marked :data:`DERIVED` where any of its runs is ``derived``."""
    return f"{method}{DERIVED}" if derived else method


def _cell(value: tuple[float, float] | None, scale: float, digits: int, seeds: int = 2) -> str:
    """``mean ± std``; one seed's value alone (a spread of one run says nothing)."""
    if value is None:
        return ""
    if seeds == 1:
        return f"{scale * value[0]:.{digits}f}"
    return format_mean_std(*value, scale=scale, digits=digits)


def table_markdown(rows: Sequence[MethodRow], notes: Sequence[str], stream: str = "") -> str:
    """The paper's table: each metric of :data:`~hispo_pl.metrics.METRICS` as mean ± std over
    seeds (PER, BWT, FWT ×100, MEM a ratio), anchors."""
    title = f"# Benchmark{': ' + stream if stream else ''}\n\n"
    lines = [
        "| method | seeds | " + " | ".join(m.name for m in METRICS) + " | anchors |",
        "|---|---:|" + "---:|" * len(METRICS) + "---|",
    ]
    for row in rows:
        n = len(row.seeds)
        anchors = ", ".join(f"{k} {_cell(v, 1, 1, n)}" for k, v in row.anchors.items())
        cells = []
        for m in METRICS:
            cell = _cell(row.metrics.get(m.name), m.scale, m.digits, n)
            if m.name == "FWT" and "FWT" not in row.metrics and notes:
                cell = (cell + " ¹").strip()
            cells.append(cell)
        name = derived_method(row.method, row.derived)
        lines.append(f"| {name} | {n} | " + " | ".join(cells) + f" | {anchors} |")
    legend = (
        "\nPER, BWT, FWT: success ×100, mean ± std (population) over seeds (one seed: its "
        "value); MEM: stored size "
        "over one single-task model; anchors: per subspace. FWT is measured against the R "
        "diagonal of the from-scratch run of the same seed (scn, else sc1; bc-scn, else bc-sc1 "
        "for bc- methods).\n"
    )
    footnotes = "".join(f"\n¹ {note}" for note in notes)
    derived = [
        derived_footnote(row.method, [("", s, m) for s, m in row.derived.items()], len(row.seeds))
        for row in rows
        if row.derived
    ]
    footnotes += "".join(f"\n{note}" for note in derived)
    return title + "\n".join(lines) + "\n" + legend + footnotes + ("\n" if footnotes else "")


def table_csv(rows: Sequence[MethodRow]) -> str:
    """Machine-readable table: ``<metric>_mean`` and ``<metric>_std`` columns (PER, BWT, FWT
    ×100; MEM and anchors as ratios / counts), empty where unknown."""
    anchor_names = sorted({k for row in rows for k in row.anchors})
    header = ["method", "seeds"]
    for name in [*(m.name for m in METRICS), *(f"anchors_{a}" for a in anchor_names)]:
        header += [f"{name}_mean", f"{name}_std"]
    header.append("fwt_reference")
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        cells: list = [row.method, len(row.seeds)]
        values = [
            *((row.metrics.get(m.name), m.scale) for m in METRICS),
            *((row.anchors.get(a), 1) for a in anchor_names),
        ]
        for value, scale in values:
            cells += ["", ""] if value is None else [round(scale * v, 4) for v in value]
        cells.append(row.fwt_reference or "")
        writer.writerow(cells)
    return buf.getvalue()


def _runs(records: Sequence[RunRecord]) -> list[tuple[tuple[str, ...], list[Decision]]]:
    return [((r.method, str(r.seed)), r.decisions) for r in records]


RUN_COLUMNS = (("method", "---"), ("seed", "---:"))


def loss_decisions_markdown(records: Sequence[RunRecord], stream: str = "") -> str:
    """Every keep / prune decision of HiSPO's rule in every run: the losses the rule compared
    (held-out), the same points on training episodes, and how much ``L_curr`` still fell over
    the last steps of the task (the convergence diagnostic; above ε the budget decided)."""
    table = decisions_table(LossDecision, _runs(records), RUN_COLUMNS)
    if not table:
        return ""
    legend = (
        "\nLosses: squared error of the deterministic prediction on the task's held-out "
        "episodes (train: on its training episodes). The rule prunes iff L_prev / L_curr ≤ "
        "1 + ε. Convergence: relative fall of L_curr over the last 20 % of the task's steps."
    )
    if any(isinstance(d, CriticDecision) for r in records for d in r.decisions):
        legend += " CSP decides by its critic: its decisions are in critic.md."
    title = f"# Decisions{': ' + stream if stream else ''}\n"
    return "\n".join([title, *table]) + "\n" + legend + "\n"


def critic_markdown(records: Sequence[RunRecord], stream: str = "") -> str:
    """CSP's decisions: the critic's values of the two points its rule compared, the imitation
    losses of the same points (what CSPO's rule would have compared) and how much the learned
    Q depends on the action (docs/csp.md); empty without critic decisions."""
    table = decisions_table(CriticDecision, _runs(records), RUN_COLUMNS)
    if not table:
        return ""
    legend = (
        "\nW: the critic's value E_s[Q(s, g, π_α(s, g), α)] of the best point of the old "
        "(W_prev) and of the grown subspace (W_curr) on the task's held-out episodes; the rule "
        "keeps the new anchor iff W_curr > W_prev + ε·|W_prev|. L_prev / L_curr: the imitation "
        "losses of the same two points (read out, not decided on). Q std over actions: the "
        "spread of Q over the data's, the policy's and uniform actions at a state, averaged "
        "over states; over states: the spread of Q(s, g, a_data); action dependence: their "
        "ratio (near 0: the critic values states, not actions).\n"
    )
    title = f"# Critic decisions{': ' + stream if stream else ''}\n"
    return "\n".join([title, *table]) + "\n" + legend


def before_training_markdown(records: Sequence[RunRecord], stream: str = "") -> str:
    """Each task's success right before it is trained (R[k − 1, k], after the task before
    it), per method: how much of a task an earlier one already solves, e.g. whether an
    observation variant breaks a policy trained on its N task. Empty for one-task streams."""
    specs = next((r.results.stream for r in records if r.results.stream), None)
    if not records or not specs or len(specs) < 2:
        return ""
    names = [
        f"T{k + 1:02d} {parse_task(s).maze}-{parse_task(s).variant}" for k, s in enumerate(specs)
    ]
    lines = [
        f"# Success before training{': ' + stream if stream else ''}\n",
        "| method | seeds | " + " | ".join(names[1:]) + " |",
        "|---|---:|" + "---:|" * (len(names) - 1),
    ]
    notes = []
    for method in dict.fromkeys(r.method for r in records):
        mine = [r for r in records if r.method == method and r.results.stream == specs]
        if not mine:
            continue
        derived = [("", r.seed, r.derived_from) for r in mine if r.derived_from]
        if derived:
            notes.append(derived_footnote(method, derived, len(mine)))
        before = np.stack([np.diagonal(r.results.matrix, offset=1) for r in mine])
        cells = [
            f"{100 * col.mean():.0f} ({100 * col.min():.0f}–{100 * col.max():.0f})"
            if len(mine) > 1
            else f"{100 * col[0]:.0f}"
            for col in before.T
        ]
        name = derived_method(method, derived)
        lines.append(f"| {name} | {len(mine)} | " + " | ".join(cells) + " |")
    legend = (
        "\nSuccess ×100 on each task evaluated right after the task before it, before any "
        "step on it; mean over seeds (min–max).\n"
    )
    return "\n".join(lines) + "\n" + legend + "".join(f"\n{note}\n" for note in notes)


def memory_markdown(records: Sequence[RunRecord], stream: str = "") -> str:
    """MEM after each task, per method (mean over the seeds that measured it, min–max where
    they differ): how a method's memory grows with the stream. Empty when no run measured it."""
    measured = [r for r in records if r.results.mem_per_task and None not in r.results.mem_per_task]
    if not measured:
        return ""
    n = max(len(r.results.mem_per_task) for r in measured)
    lines = [
        f"# Memory after each task{': ' + stream if stream else ''}\n",
        "| method | seeds | " + " | ".join(f"T{k + 1:02d}" for k in range(n)) + " |",
        "|---|---:|" + "---:|" * n,
    ]
    for method in dict.fromkeys(r.method for r in measured):
        mine = np.array([r.results.mem_per_task for r in measured if r.method == method])
        cells = [
            f"{col.mean():.2f}" + (f" ({col.min():.2f}–{col.max():.2f})" if np.ptp(col) else "")
            for col in mine.T
        ]
        lines.append(f"| {method} | {len(mine)} | " + " | ".join(cells) + " |")
    legend = (
        "\nMEM (stored size over one single-task model) after each task's decisions, mean over "
        "the seeds (min–max where they differ); runs made before MEM was recorded per task are "
        "left out.\n"
    )
    return "\n".join(lines) + "\n" + legend


def run_minutes(record: RunRecord) -> float:
    """A run's wall minutes: the sum of its tasks' ``wall_time_s``."""
    return sum(record.results.wall_time_s or []) / 60


def runtime_csv(records: Sequence[RunRecord]) -> str:
    """One line per run: method, seed, wall minutes (sum of the tasks' ``wall_time_s``),
    steps per task (from ``run.json``; empty for runs the benchmark did not launch)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["method", "seed", "minutes", "steps_per_task"])
    for r in records:
        minutes = run_minutes(r)
        steps = r.meta.steps_per_task
        writer.writerow([r.method, r.seed, round(minutes, 3), "" if steps is None else steps])
    return buf.getvalue()


def metric_cell(row: MethodRow | None, name: str) -> str:
    """Our metric ``name`` of a method's row as the paper prints its own: mean ± std ×100 (a
    ratio for MEM), one seed's value alone; empty where not run."""
    value = None if row is None else row.metrics.get(name)
    if value is None:
        return ""
    metric = METRIC[name]
    if len(row.seeds) == 1:
        return metric.format(value[0])
    return f"{metric.format(value[0])} ± {metric.format(value[1])}"
