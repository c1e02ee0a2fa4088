"""The zero-shot transfer of a grid's HiSPO-PAC runs beside HiSPO's, per stream: how often the
PAC criterion took a subspace (or a whole task) without training, and what it cost in PER and
saved in memory. The paper's zero-shot section (5.5.3) states the criterion and reports no
measurement of it, so this report is what stands beside that section."""

from __future__ import annotations

from collections.abc import Sequence

from ..results import ZeroShotDecision
from .tables import metric_cell

PAC_METHOD, BASE_METHOD = "hispo-pac", "hispo"


def zero_shot_counts(decisions: Sequence) -> tuple[dict[str, tuple[int, int]], int]:
    """Per subspace, (tests that took the subspace zero-shot, tests made); and the number of
    tasks every subspace of which was taken, so the task trained no step.

    Example:
        >>> from hispo_pl.results import Decision
        >>> d = [Decision.from_json({"task": 1, "subspace": s, "decision": v})
        ...      for s, v in (("high", "zero-shot"), ("low", "train"))]
        >>> zero_shot_counts(d)
        ({'high': (1, 1), 'low': (0, 1)}, 0)
    """
    tests = [d for d in decisions if isinstance(d, ZeroShotDecision)]
    counts: dict[str, tuple[int, int]] = {}
    by_task: dict[int, list[bool]] = {}
    for d in tests:
        taken, made = counts.get(d.subspace, (0, 0))
        counts[d.subspace] = (taken + (d.decision == "zero-shot"), made + 1)
        by_task.setdefault(d.task, []).append(d.decision == "zero-shot")
    return counts, sum(all(taken) for taken in by_task.values())


def zero_shot_markdown(committed, streams: Sequence[str]) -> str:
    """The table of HiSPO-PAC's zero-shot decisions and its PER / MEM beside HiSPO's on each of
    ``streams`` (a stream without a HiSPO-PAC run says so), from ``committed`` (a
    :class:`~.grid_report.Committed`)."""
    lines = []
    for stream in streams:
        runs = [r for r in committed.records(stream) if r.method == PAC_METHOD]
        rows = committed.methods(stream)
        pac, base = rows.get(PAC_METHOD), rows.get(BASE_METHOD)
        if not runs:
            per, mem = metric_cell(base, "PER"), metric_cell(base, "MEM")
            lines.append(f"| {stream} | 0 | not run yet | | | {per} | | {mem} |")
            continue
        totals: dict[str, list[int]] = {}
        skipped = 0
        for run in runs:
            counts, whole = zero_shot_counts(run.decisions)
            skipped += whole
            for name, (taken, made) in counts.items():
                total = totals.setdefault(name, [0, 0])
                total[0], total[1] = total[0] + taken, total[1] + made
        taken = ", ".join(f"{name} {t} of {m}" for name, (t, m) in totals.items()) or "no test"
        lines.append(
            f"| {stream} | {len(runs)} | {taken} | {skipped} | {metric_cell(pac, 'PER')} | "
            f"{metric_cell(base, 'PER')} | {metric_cell(pac, 'MEM')} | {metric_cell(base, 'MEM')} |"
        )
    head = [
        "# Zero-shot transfer: HiSPO-PAC beside HiSPO\n",
        "| stream | seeds | subspaces taken zero-shot (of the tests) | tasks not trained | "
        "PER hispo-pac | PER hispo | MEM hispo-pac | MEM hispo |",
        "|---|---:|---|---:|---:|---:|---:|---:|",
    ]
    legend = (
        "\nBefore each task after the first, the PAC criterion tests each subspace: its best "
        "point on the new task's data is taken without a new anchor when it predicts within ε "
        "on a share ≥ 1 − δ of that data (`configs/methods/hispo-pac.yaml`). Counts are summed "
        "over the seeds; a task not trained had every subspace taken. PER ×100 and MEM as mean "
        "± std over seeds. The paper's zero-shot section states the criterion and reports no "
        "measurement of it; each test's rate is in the stream's decisions table.\n"
    )
    return "\n".join(head + lines) + "\n" + legend
