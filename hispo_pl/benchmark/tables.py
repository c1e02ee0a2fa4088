"""The tables of a benchmark: the paper's table (Markdown and CSV), the decisions, the run
times."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence

import numpy as np

from ..tasks import parse_task
from .records import MethodRow, RunRecord, format_mean_std, results_matrix

SCALED = ("PER", "BWT", "FWT")  # success fractions, reported ×100 like the paper


def _cell(value: tuple[float, float] | None, scale: float, digits: int, seeds: int = 2) -> str:
    """``mean ± std``; one seed's value alone (a spread of one run says nothing)."""
    if value is None:
        return ""
    if seeds == 1:
        return f"{scale * value[0]:.{digits}f}"
    return format_mean_std(*value, scale=scale, digits=digits)


def table_markdown(rows: Sequence[MethodRow], notes: Sequence[str], stream: str = "") -> str:
    """The paper's table: PER, BWT, FWT ×100 and MEM as mean ± std over seeds, anchors."""
    title = f"# Benchmark{': ' + stream if stream else ''}\n\n"
    lines = [
        "| method | seeds | PER | BWT | FWT | MEM | anchors |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for row in rows:
        n = len(row.seeds)
        anchors = ", ".join(f"{k} {_cell(v, 1, 1, n)}" for k, v in row.anchors.items())
        fwt = _cell(row.FWT, 100, 1, n) + ("" if row.FWT is not None or not notes else " ¹")
        lines.append(
            f"| {row.method} | {n} | {_cell(row.PER, 100, 1, n)} | {_cell(row.BWT, 100, 1, n)} "
            f"| {fwt.strip()} | {_cell(row.MEM, 1, 2, n)} | {anchors} |"
        )
    legend = (
        "\nPER, BWT, FWT: success ×100, mean ± std (population) over seeds (one seed: its "
        "value); MEM: stored size "
        "over one single-task model; anchors: per subspace. FWT is measured against the R "
        "diagonal of the from-scratch run of the same seed (scn, else sc1; bc-scn, else bc-sc1 "
        "for bc- methods).\n"
    )
    footnotes = "".join(f"\n¹ {note}" for note in notes)
    return title + "\n".join(lines) + "\n" + legend + footnotes + ("\n" if notes else "")


def table_csv(rows: Sequence[MethodRow]) -> str:
    """Machine-readable table: ``<metric>_mean`` and ``<metric>_std`` columns (PER, BWT, FWT
    ×100; MEM and anchors as ratios / counts), empty where unknown."""
    anchor_names = sorted({k for row in rows for k in row.anchors})
    header = ["method", "seeds"]
    for name in [*SCALED, "MEM", *(f"anchors_{a}" for a in anchor_names)]:
        header += [f"{name}_mean", f"{name}_std"]
    header.append("fwt_reference")
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        cells: list = [row.method, len(row.seeds)]
        values = [row.PER, row.BWT, row.FWT, row.MEM, *(row.anchors.get(a) for a in anchor_names)]
        scales = [100, 100, 100, 1] + [1] * len(anchor_names)
        for value, scale in zip(values, scales, strict=True):
            cells += ["", ""] if value is None else [round(scale * v, 4) for v in value]
        cells.append(row.fwt_reference or "")
        writer.writerow(cells)
    return buf.getvalue()


def _value(value: float | None, digits: int = 4) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def decisions_markdown(records: Sequence[RunRecord], stream: str = "") -> str:
    """Every keep / prune decision of every run: the losses the rule compared (held-out), the
    same points on training episodes, and how much ``L_curr`` still fell over the last steps
    of the task (the convergence diagnostic; above ε the budget decided)."""
    lines = [
        f"# Decisions{': ' + stream if stream else ''}\n",
        "| method | seed | task | subspace | L_prev | L_curr | L_prev / L_curr | ε | "
        "train L_prev / L_curr | convergence | decision | anchors |",
        "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for r in records:
        for d in r.decisions:
            if d.get("decision") not in ("first", "keep", "prune") or d.get("rule") == "critic":
                continue  # zero-shot records carry no losses; CSP decides by its critic
            ratio = d["l_prev"] / d["l_curr"] if d.get("l_prev") is not None else None
            train = (
                d["l_prev_train"] / d["l_curr_train"]
                if d.get("l_prev_train") is not None and d.get("l_curr_train")
                else None
            )
            conv = d.get("improvement")
            lines.append(
                f"| {r.method} | {r.seed} | {d['task'] + 1} | {d['subspace']} | "
                f"{_value(d.get('l_prev'))} | {_value(d['l_curr'])} | "
                f"{'' if ratio is None else f'{ratio:.3f}'} | {d.get('eps', '')} | "
                f"{'' if train is None else f'{train:.3f}'} | "
                f"{'' if conv is None else f'{conv:+.1%}'} | {d['decision']} | {d['anchors']} |"
            )
    if len(lines) == 3:
        return ""
    legend = (
        "\nLosses: squared error of the deterministic prediction on the task's held-out "
        "episodes (train: on its training episodes). The rule prunes iff L_prev / L_curr ≤ "
        "1 + ε. Convergence: relative fall of L_curr over the last 20 % of the task's steps."
    )
    if any(d.get("rule") == "critic" for r in records for d in r.decisions):
        legend += " CSP decides by its critic: its decisions are in critic.md."
    legend += "\n"
    return "\n".join(lines) + "\n" + legend


def critic_markdown(records: Sequence[RunRecord], stream: str = "") -> str:
    """CSP's decisions: the critic's values of the two points its rule compared, the imitation
    losses of the same points (what CSPO's rule would have compared) and how much the learned
    Q depends on the action (docs/csp.md); empty without critic decisions."""
    lines = [
        f"# Critic decisions{': ' + stream if stream else ''}\n",
        "| method | seed | task | W_prev | W_curr | ε | L_prev / L_curr | Q std over actions | "
        "Q std over states | action dependence | decision | anchors |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for r in records:
        for d in r.decisions:
            if d.get("rule") != "critic":
                continue
            ratio = d["l_prev"] / d["l_curr"] if d.get("l_prev") is not None else None
            lines.append(
                f"| {r.method} | {r.seed} | {d['task'] + 1} | {_value(d.get('w_prev'))} | "
                f"{_value(d.get('w_curr'))} | {d.get('eps', '')} | {_value(ratio, 3)} | "
                f"{_value(d.get('q_action_std'))} | {_value(d.get('q_state_std'))} | "
                f"{_value(d.get('action_dependence'), 3)} | {d['decision']} | {d['anchors']} |"
            )
    if len(lines) == 3:
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
    return "\n".join(lines) + "\n" + legend


def before_training_markdown(records: Sequence[RunRecord], stream: str = "") -> str:
    """Each task's success right before it is trained (R[k − 1, k], after the task before
    it), per method: how much of a task an earlier one already solves, e.g. whether an
    observation variant breaks a policy trained on its N task. Empty for one-task streams."""
    specs = next((r.results.get("stream") for r in records if r.results.get("stream")), None)
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
    for method in dict.fromkeys(r.method for r in records):
        mine = [r for r in records if r.method == method and r.results.get("stream") == specs]
        if not mine:
            continue
        before = np.stack([np.diagonal(results_matrix(r.results), offset=1) for r in mine])
        cells = [
            f"{100 * col.mean():.0f} ({100 * col.min():.0f}–{100 * col.max():.0f})"
            if len(mine) > 1
            else f"{100 * col[0]:.0f}"
            for col in before.T
        ]
        lines.append(f"| {method} | {len(mine)} | " + " | ".join(cells) + " |")
    legend = (
        "\nSuccess ×100 on each task evaluated right after the task before it, before any "
        "step on it; mean over seeds (min–max).\n"
    )
    return "\n".join(lines) + "\n" + legend


def run_minutes(record: RunRecord) -> float:
    """A run's wall minutes: the sum of its tasks' ``wall_time_s``."""
    return sum(record.results.get("wall_time_s", [])) / 60


def runtime_csv(records: Sequence[RunRecord]) -> str:
    """One line per run: method, seed, wall minutes (sum of the tasks' ``wall_time_s``),
    steps per task (from ``run.json``; empty for runs the benchmark did not launch)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["method", "seed", "minutes", "steps_per_task"])
    for r in records:
        minutes = run_minutes(r)
        steps = r.meta.get("steps_per_task")
        writer.writerow([r.method, r.seed, round(minutes, 3), "" if steps is None else steps])
    return buf.getvalue()
