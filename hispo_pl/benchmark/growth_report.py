"""Memory and performance against tasks on a grid's long streams (the paper's Figure 2d).

MEM after each task is measured in the runs of the methods that decide their memory (HiSPO,
CSPO, HiLOW: each run's ``mem_per_task``) and grown from the structure of those whose memory
follows from it (SCN, FTN, PNN: :mod:`.growth`), with the structure checked against the SCN
runs; PER after each task comes from each run's success matrix. The grid report writes them for
a grid with a random stream (:func:`~.growth_curves.has_random_streams`): ``growth.md`` (the
fitted growth per method and stream, the check, the runs not committed yet), ``growth-findings.md``
(what the runs show, in sentences filled from them), ``search-time.md`` (the seconds a task's
search takes against the anchors it weighs), ``repeats.md`` (the decisions on repeated tasks
beside the earlier task's own weights), ``memory_growth.png`` and ``per_after_task.png``.
Here: the report's text; the curves it reads are :mod:`.growth_curves`'s, its figures
:mod:`.growth_figures`'s.

    data = growth_data(grid, Committed(root))  # from .growth_curves
    print(growth_markdown(grid, data))
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .growth_curves import (
    STRUCTURAL,
    Growth,
    GrowthData,
    RunCurves,
    _family_title,
    anchors_after_each_task,
    has_random_streams,
    mean_curve,
    memory_added_text,
)

# --- the report's text --------------------------------------------------------------------------


def _num(value: float | None, digits: int = 2) -> str:
    return "" if value is None else f"{value:.{digits}f}"


def _row(method: str, stream: str, seeds: str, runs: Sequence[RunCurves]) -> str | None:
    memory = [r.memory for r in runs if r.memory is not None]
    anchors = [r.anchors for r in runs if r.anchors is not None]
    per = float(np.mean([r.per[-1] for r in runs])) * 100
    cells = ["", "", ""]
    if anchors:
        anc = Growth.of(mean_curve(anchors))
        cells = [_num(anc.first_half), _num(anc.last_half), f"{anc.final:.0f}"]
    cells += ["", "", "", ""]
    if memory:
        mem = Growth.of(mean_curve(memory))
        cells[3:] = [_num(v) for v in (mem.first_half, mem.last_half, mem.slope, mem.final)]
    cells.append(f"{per:.1f}")
    return f"| {method} | {stream} | {seeds} | " + " | ".join(cells) + " |"


def structure_check(data: GrowthData) -> str:
    """A sentence on how SCN's structural memory compares with its committed runs' measured
    MEM after each task; empty when no SCN run measured it."""
    gaps = []
    for family in data.families:
        grown = data.structure.get((family, "scn"))
        for run in data.of(family, "scn"):
            if grown is None or run.memory is None:
                continue
            ours = np.asarray(grown[: len(run.memory)])
            gaps.append((float(np.max(np.abs(ours / np.asarray(run.memory) - 1))), run))
    if not gaps:
        return ""
    worst, run = max(gaps, key=lambda g: g[0])
    if worst <= 1e-6:
        return (
            f"SCN's memory grown from its structure equals the measured MEM of its {len(gaps)} "
            f"committed run(s) after every task (largest relative gap {worst:.1e})."
        )
    return (
        f"SCN's memory grown from its structure differs from its committed runs' measured MEM "
        f"(largest relative gap {worst:.1%}, {run.stream} seed {run.seed}): the runs' "
        "configuration is not the one the structure was grown from."
    )


def missing_lines(data: GrowthData) -> list[str]:
    """One line per stream with cells not committed yet: which methods and seeds."""
    by_stream: dict[str, dict[str, list[int]]] = {}
    for stream, method, seed in data.missing:
        by_stream.setdefault(stream, {}).setdefault(method, []).append(seed)
    return [
        f"- {stream}: "
        + ", ".join(f"{m} (seed {', '.join(map(str, s))})" for m, s in methods.items())
        for stream, methods in by_stream.items()
    ]


def growth_markdown(grid, data: GrowthData) -> str:
    """The fitted growth per method and stream (measured runs, then the structural methods per
    family), the structure's check against SCN's runs, the figures and the runs missing."""
    lines = [
        f"# Memory growth: grid {grid.name}\n",
        "| method | stream | seeds | anchors / task, first half | anchors / task, last half | "
        "anchors at the end | MEM / task, first half | MEM / task, last half | MEM slope | "
        "final MEM | final PER |",
        "|---|---|---:|" + "---:|" * 8,
    ]
    for family, streams in data.families.items():
        for stream in streams:
            for method in grid.methods:
                runs = [r for r in data.runs if r.stream == stream and r.method == method]
                if runs:
                    lines.append(_row(method, stream, str(len(runs)), runs))
        for method in STRUCTURAL:
            grown = data.structure.get((family, method))
            if grown is None:
                continue
            mem = Growth.of(grown)
            cells = ["", "", "", *(_num(v) for v in (mem.first_half, mem.last_half, mem.slope))]
            name = f"random-{family}-{len(grown)}" if has_random_streams(streams) else family
            lines.append(
                f"| {method} (structure) | {name} | | "
                + " | ".join([*cells, _num(mem.final), ""])
                + " |"
            )
    legend = (
        "\nAfter each task of a stream of n tasks (h = n // 2): anchors held (summed over a "
        "method's subspaces) and MEM (stored size over one single-task model), each per task "
        "over the first half (tasks 2..h) and the last half (tasks h+1..n); the MEM slope is a "
        "least-squares line through MEM after every task; final PER is the mean success ×100 "
        "over the stream's tasks after its last. Means over the committed seeds. Rows "
        "'(structure)' are grown from the method's configuration without training "
        "(`hispo_pl.benchmark.growth`): they hold for any stream of the family of that length.\n"
    )
    lines.append(legend)
    check = structure_check(data)
    if check:
        lines.append(check + "\n")
    if data.runs:
        lines += [
            "![MEM against tasks, per stream family](memory_growth.png)\n",
            "![PER after each task, per stream family](per_after_task.png)\n",
        ]
    gaps = missing_lines(data)
    if gaps:
        total = len(data.missing) + len(data.runs)
        lines += [f"Runs not committed yet ({len(data.missing)} of {total}):\n", *gaps, ""]
    return "\n".join(lines)


def _sentence(method: str, family: str, data: GrowthData) -> str | None:
    runs = data.of(family, method)
    memory = [r.memory for r in runs if r.memory is not None]
    if not runs:
        return None
    per = 100 * float(np.mean([r.per[-1] for r in runs]))
    text = f"{method} ({len(runs)} run{'s' * (len(runs) > 1)})"
    if method in STRUCTURAL or not memory:
        return f"{text}: PER after the last task {per:.1f}."
    mem = Growth.of(mean_curve(memory))
    if mem.first_half is None or mem.last_half is None:
        shape = f"ends at MEM {mem.final:.2f}"
    else:
        slowing = "slowing" if mem.slows else "not slowing"
        shape = (
            f"adds {mem.last_half:.2f} MEM per task over the last half of a stream against "
            f"{mem.first_half:.2f} over the first ({slowing}) and ends at {mem.final:.2f}"
        )
    added = memory_added_text(runs)
    if added:
        shape += ": " + added
    return f"{text} {shape}; PER after the last task {per:.1f}."


def findings_markdown(grid, data: GrowthData) -> str:
    """What the committed runs show, per family, in sentences filled from them; which runs are
    missing when some are, and no figure at all before any run."""
    lines = ["# What the runs show\n"]
    total = len(data.missing) + len(data.runs)
    if not data.runs:
        lines.append(
            f"No run of the grid {grid.name} is committed yet (0 of {total}): nothing is "
            "measured, so nothing is set beside the paper here; the runs still to make are "
            "listed under the table.\n"
        )
        return "\n".join(lines)
    if data.missing:
        lines.append(
            f"From {len(data.runs)} of the grid's {total} runs (the others are listed under the "
            "table), so each line holds only for the runs it counts.\n"
        )
    for family, streams in data.families.items():
        structure = []
        for method in STRUCTURAL:
            grown = data.structure.get((family, method))
            if grown is not None:
                last = Growth.of(grown).last_half
                structure.append(
                    f"{method} {grown[-1]:.2f} after {len(grown)} tasks"
                    + ("" if last is None else f" ({last:.2f} per task over the last half)")
                )
        sentences = [s for m in grid.methods if (s := _sentence(m, family, data))]
        if not sentences:
            continue
        with_runs = len({r.stream for r in data.runs if r.stream in streams})
        head = f"- **{_family_title(family, streams)}**, {with_runs} with runs: "
        lines.append(head + " ".join(sentences))
        if structure:
            lines.append(f"  From their structure: {'; '.join(structure)}.")
    lines.append("")
    return "\n".join(lines)


def search_time_markdown(grid, data: GrowthData) -> str:
    """Whether the search stays cheap as a subspace grows: per method and family, the seconds a
    task's search took against the anchors it weighed (summed over the subspaces searched),
    over every committed run and task, with its share of the task's wall time."""
    lines = [f"# Search time against anchors: grid {grid.name}\n"]
    cells: dict[tuple[str, str, int], list[tuple[float, float | None]]] = {}
    for family, streams in data.families.items():
        for r in data.runs:
            if r.stream not in streams:
                continue
            for k, (n, sec) in enumerate(zip(r.searched, r.search_seconds, strict=False)):
                if n is not None and sec is not None:
                    wall = r.wall_seconds[k] if k < len(r.wall_seconds) else None
                    cells.setdefault((r.method, family, n), []).append((sec, wall))
    if not cells:
        lines.append("No committed run has searched a subspace yet.\n")
        return "\n".join(lines)
    lines += [
        "| method | family | anchors searched | tasks | search s / task | share of the task's "
        "wall time |",
        "|---|---|---:|---:|---:|---:|",
    ]
    order = {m: i for i, m in enumerate(grid.methods)}
    for method, family, n in sorted(cells, key=lambda c: (order.get(c[0], 99), c[1], c[2])):
        found = cells[(method, family, n)]
        seconds = float(np.mean([sec for sec, _ in found]))
        shares = [sec / wall for sec, wall in found if wall]
        share = f"{100 * float(np.mean(shares)):.2f} %" if shares else ""
        lines.append(f"| {method} | {family} | {n} | {len(found)} | {seconds:.1f} | {share} |")
    method, family, n = max(cells, key=lambda c: (c[2], np.mean([x for x, _ in cells[c]])))
    most = float(np.mean([sec for sec, _ in cells[(method, family, n)]]))
    lines += [
        "",
        f"The largest search weighed {n} anchors ({method}, {family}): {most:.1f} s per task.",
        "",
        "Seconds of the Dirichlet search (or the critic's) after a task's training, mean over "
        "the committed runs' tasks that searched that many anchors; its share of the task's "
        "wall time (training, search, evaluation). Anchors searched: the weights of the grown "
        "subspace's best point, summed over the subspaces searched.\n",
    ]
    return "\n".join(lines)


def repeats_markdown(grid, data: GrowthData) -> str:
    """Whether the methods recognise a task they met before: every decision the committed runs
    took on a repeated task, the best point the search found and the earlier task's own
    weights each against ``L_curr``, and how many of the new anchors kept on a repeat those
    weights would have pruned (:class:`~.growth_curves.RepeatCheck`)."""
    lines = [f"# Repeated tasks: grid {grid.name}\n"]
    order = {m: i for i, m in enumerate(grid.methods)}
    runs = sorted(data.runs, key=lambda r: (r.stream, order.get(r.method, 99), r.seed))
    checks = [(r, c) for r in runs for c in r.repeat_checks]
    if not checks:
        lines.append("No committed run has decided on a repeated task yet.\n")
        return "\n".join(lines)
    lines += [
        "| stream | method | seed | task | repeats task | subspace | decision | L_prev / L_curr "
        "| own / L_curr | 1 + ε | own prunes |",
        "|---|---|---:|---:|---:|---|---|---:|---:|---:|---|",
    ]
    for r, c in checks:
        found = _num(c.l_prev / c.l_curr) if c.l_prev is not None and c.l_curr else ""
        own = _num(c.own / c.l_curr) if c.own is not None and c.l_curr else ""
        prunes = {None: "", True: "yes", False: "no"}[c.own_prunes]
        lines.append(
            f"| {r.stream} | {r.method} | {r.seed} | {c.task + 1} | {c.earlier + 1} | "
            f"{c.subspace} | {c.decision} | {found} | {own} | {1 + c.eps:.2f} | {prunes} |"
        )
    kept = [c for _, c in checks if c.decision == "keep"]
    saved = sum(bool(c.own_prunes) for c in kept)
    lines += [
        "",
        f"Of {len(checks)} decisions on a repeated task, {len(kept)} kept a new anchor; the "
        f"earlier task's own weights would have pruned {saved} of those {len(kept)}.",
        "",
        "Each row is one subspace's decision on a task that repeats an earlier one of its "
        "stream (tasks numbered from 1). L_prev / L_curr: the best point the search found over "
        "the previous anchors, against the grown subspace's best; the rule prunes when it is at "
        "most 1 + ε. Own / L_curr: the weights the earlier task acts with, scored on the same "
        "held-out batches (the same task gives the same batches and those weights mix only "
        "frozen anchors, so they score what they scored when chosen: that task's L_curr, or its "
        "L_prev if it pruned). Dirichlet(1) draws over many anchors rarely come near them; "
        "`--search_stored_points true` races them too.\n",
    ]
    return "\n".join(lines)


# --- memory after each task on a grid's fixed streams (the paper's Figure 3) ---------------------

DECIDING = ("hispo", "hispo-pac", "hilow", "cspo", "csp")  # methods whose memory is decided


def memory_per_task_markdown(grid, committed) -> str:
    """MEM and anchors after each task of every stream of ``grid``, for the methods that decide
    their memory, mean over the committed seeds (MEM over the seeds that measured it after each
    task); empty when no such method has a run. The paper's Figure 3 draws this for HiLOW on an
    AntMaze stream."""
    lines = []
    for stream in grid.streams:
        for method in (m for m in DECIDING if m in grid.methods):
            runs = [r for r in committed.records(stream) if r.method == method]
            if not runs:
                continue
            n = len(runs[0].results.stream)
            mems = [r.results.mem_per_task for r in runs]
            mems = [m for m in mems if m and None not in m and len(m) == n]
            anchors = [anchors_after_each_task(r.decisions, n) for r in runs]
            anchors = [a for a in anchors if a is not None]
            mem = " → ".join(f"{v:.2f}" for v in mean_curve(mems)) if mems else "not measured"
            held = " → ".join(f"{round(v, 2):g}" for v in mean_curve(anchors)) if anchors else ""
            lines.append(f"| {stream} | {method} | {len(runs)} | {len(mems)} | {mem} | {held} |")
    if not lines:
        return ""
    head = [
        f"# Memory after each task: grid {grid.name}\n",
        "| stream | method | seeds | seeds measuring MEM per task | MEM after each task | "
        "anchors after each task |",
        "|---|---|---:|---:|---|---|",
    ]
    legend = (
        "\nMEM (stored size over one single-task model) and anchors held (summed over a "
        "method's subspaces, from its decisions) after each task, mean over seeds. Runs made "
        "before MEM was recorded after each task count for the anchors only. The paper's "
        "Figure 3 plots memory usage on an AntMaze stream to show that HiLOW's low-rank anchors "
        "make smaller updates than HiSPO's; its values are not in the paper's text, so this "
        "table stands beside its claim, not its numbers.\n"
    )
    return "\n".join(head + lines) + "\n" + legend
