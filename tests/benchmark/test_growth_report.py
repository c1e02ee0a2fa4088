"""The growth report of a grid of random streams (the paper's Figure 2d beside): MEM, anchors
and PER after each task read from small real runs, the structure checked against SCN's runs,
the runs not committed yet named, the figures written and embedded in a page, and a page that
embeds the report of a grid before any of its runs."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from helpers import fit_tiny_stream

from hispo_pl.benchmark.grid import grid_from_dict, load_grid
from hispo_pl.benchmark.grid_report import Committed, grid_reports, write_grid_report
from hispo_pl.benchmark.growth_curves import (
    Growth,
    GrowthData,
    RunCurves,
    growth_data,
    memory_added,
    per_after_each_task,
    repeat_checks,
    repeats_of,
)
from hispo_pl.benchmark.growth_report import (
    findings_markdown,
    growth_markdown,
    repeats_markdown,
    search_time_markdown,
)
from hispo_pl.rundir import RunDir
from lab.embed import EMBED_BEGIN, EMBED_END, embed_reports

ROOT = Path(__file__).resolve().parents[2]
STREAM = "random-pointmaze-4@0"  # the folder the runs are committed under
TASKS = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]", "pointmaze-umaze-IA[3]"]
TASKS.append("pointmaze-umaze-IO[3]")  # four tiny tasks of the tiny_umaze data
METHODS = ["hispo", "hilow", "scn"]


def _grid(methods=METHODS) -> object:
    spec = {"streams": [STREAM], "methods": methods, "seeds": [0]}
    return grid_from_dict({**spec, "extra": ["--data.stream", json.dumps(TASKS)]}, "tiny")


@pytest.fixture(scope="module")
def committed_runs(tiny_umaze, tmp_path_factory) -> Path:
    """A results root with one small real run per method, exported as the grid exports."""
    root = tmp_path_factory.mktemp("growth") / "results"
    for method in METHODS:
        _, run_dir = fit_tiny_stream(method, tmp_path_factory.mktemp(method), TASKS)
        target = root / STREAM / method / "seed0"
        target.mkdir(parents=True)
        for name in RunDir.EXPORTED:
            if (run_dir / name).is_file():
                shutil.copy(run_dir / name, target / name)
    return root


def _results(root: Path, method: str) -> dict:
    return json.loads((root / STREAM / method / "seed0/results.json").read_text())


def _row(text: str, method: str) -> list[str]:
    (line,) = [x for x in text.splitlines() if x.startswith(f"| {method} | {STREAM} |")]
    return [c.strip() for c in line.strip("|").split("|")]


def test_growth_halves_and_per_after_each_task():
    line = Growth.of([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    assert line.first_half == line.last_half == pytest.approx(line.slope) == pytest.approx(1.0)
    slowing = Growth.of([1.0, 2.0, 2.8, 3.4, 3.8, 4.0])
    assert slowing.last_half < slowing.first_half and slowing.final == 4.0
    assert Growth.of([2.0]) == Growth(None, None, None, 2.0)
    assert per_after_each_task([[0.5, None], [1.0, 0.0]]) == [0.5, 0.5]


def test_growth_slows_when_the_last_half_adds_less_per_task():
    def halves(first: float, last: float) -> Growth:
        return Growth(first, last, None, 0.0)

    assert halves(1.0, 0.5).slows and not halves(0.5, 0.5).slows
    assert not halves(0.45, 0.49).slows and not Growth.of([2.0]).slows


def test_memory_added_on_repeats_is_told_from_that_on_new_tasks():
    """A random stream draws with replacement: MEM that grows on new tasks only slows down as
    repeats come, so what a task adds is pooled apart for the two kinds."""
    stream = ["pointmaze-umaze-N[9]", "pointmaze-large-N[9]", "pointmaze-umaze-N[9]"]
    assert repeats_of([*stream, "pointmaze-large-N[9]"]) == [False, False, True, True]
    runs = [
        RunCurves("s", "hispo", seed, memory, [1.0] * 4, None, repeats=repeats_of(stream))
        for seed, memory in ((0, [1.0, 2.0, 2.0]), (1, [1.0, 1.5, 2.5]))
    ]
    assert memory_added(runs) == {False: (0.75, 2), True: (0.5, 2)}
    assert memory_added(runs[:1] + [RunCurves("s", "scn", 0, None, [1.0], None)]) == {
        False: (1.0, 1),
        True: (0.0, 1),
    }


@pytest.mark.e2e
def test_the_report_reads_each_run_s_files(committed_runs):
    grid = _grid()
    data = growth_data(grid, Committed(committed_runs))
    text = growth_markdown(grid, data)
    for method in METHODS:
        results, cells = _results(committed_runs, method), _row(text, method)
        assert cells[2] == "1" and cells[-1] == f"{100 * results['PER']:.1f}"
        assert per_after_each_task(results["R"])[-1] == pytest.approx(results["PER"])
        assert cells[-2] == f"{results['mem_per_task'][-1]:.2f}" == f"{results['MEM']:.2f}"
        if method == "scn":  # no anchors: one network per task
            assert cells[3:6] == ["", "", ""] and cells[-2] == "4.00"
        else:  # the anchors after the last decision equal what results.json stores
            assert cells[5] == str(sum(results["anchors"].values()))
    # SCN's memory grown from its structure is what its run measured after every task
    assert "equals the measured MEM of its 1 committed run(s) after every task" in text
    structure = {m: _structure_row(text, m) for m in ("scn", "ftn", "pnn")}
    assert structure["scn"] == structure["ftn"] == ["1.00", "1.00", "1.00", "4.00"]
    assert float(structure["pnn"][1]) > float(structure["pnn"][0]) > 1.0  # columns: faster
    assert "not committed" not in text and "](memory_growth.png)" in text
    findings = findings_markdown(grid, data)
    for method in METHODS:
        assert f"{method} (1 run)" in findings
    # the tiny stream's four tasks are all new: what each added after the first, no repeat
    hispo_mem = _results(committed_runs, "hispo")["mem_per_task"]
    added = (hispo_mem[-1] - hispo_mem[0]) / 3
    assert f"{added:.2f} per new task after the first (3)" in findings
    assert "per repeat" not in findings
    assert f"pnn {float(structure['pnn'][3]):.2f} after 4 tasks" in findings


@pytest.mark.e2e
def test_the_search_time_report_reads_each_task_s_search(committed_runs):
    """Per task, the anchors the search weighed are the grown points' weights in the run's
    decisions and its seconds the run's recorded search phase; SCN searches nothing."""
    grid = _grid()
    data = growth_data(grid, Committed(committed_runs))
    for method in ("hispo", "hilow"):
        (run,) = [r for r in data.runs if r.method == method]
        results = _results(committed_runs, method)
        assert run.search_seconds == [p.get("search") for p in results["phase_time_s"]]
        assert run.wall_seconds == results["wall_time_s"]
        lines = (committed_runs / STREAM / method / "seed0/decisions.jsonl").read_text()
        decisions = [json.loads(line) for line in lines.splitlines()]
        for k, searched in enumerate(run.searched):
            grown = {d["subspace"]: len(d["alpha_curr"]) for d in decisions
                     if d["task"] == k and d.get("alpha_curr")}  # fmt: skip
            assert searched == sum(grown.values()) > 0
    (scn,) = [r for r in data.runs if r.method == "scn"]
    assert set(scn.searched) == {None}
    text = search_time_markdown(grid, data)
    largest = max(n for r in data.runs for n in r.searched if n is not None)
    assert f"The largest search weighed {largest} anchors" in text
    assert "| hispo | pointmaze | 2 |" in text and "| scn |" not in text


def _structure_row(text: str, method: str) -> list[str]:
    (line,) = [x for x in text.splitlines() if x.startswith(f"| {method} (structure) |")]
    return [c.strip() for c in line.strip("|").split("|")][6:10]


def test_runs_not_committed_yet_are_named(committed_runs, tmp_path):
    root = tmp_path / "results"
    shutil.copytree(committed_runs, root)
    shutil.rmtree(root / STREAM / "hilow")
    grid = _grid()
    data = growth_data(grid, Committed(root))
    text = growth_markdown(grid, data)
    assert "Runs not committed yet (1 of 3):" in text
    assert f"- {STREAM}: hilow (seed 0)" in text
    assert "From 2 of the grid's 3 runs" in findings_markdown(grid, data)
    shutil.rmtree(root / STREAM)
    empty = growth_data(grid, Committed(root))
    assert "](memory_growth.png)" not in growth_markdown(grid, empty)
    assert "No run of the grid tiny is committed yet (0 of 3)" in findings_markdown(grid, empty)


def test_the_grid_report_writes_the_figures_a_page_embeds(committed_runs, tmp_path):
    pytest.importorskip("rliable")
    root = tmp_path / "results"
    shutil.copytree(committed_runs, root)
    written = {p.name for p in write_grid_report(_grid(), root)}
    assert {"growth.md", "growth-findings.md", "memory_growth.png", "per_after_task.png"} <= written
    page = tmp_path / "docs" / "page.md"
    page.parent.mkdir()
    page.write_text(f"{EMBED_BEGIN}results/grid-tiny/growth.md -->\nold\n{EMBED_END}\n")
    rebuilt = embed_reports(page, tmp_path)
    link = "![MEM against tasks, per stream family](../results/grid-tiny/memory_growth.png)"
    assert link in rebuilt and (page.parent / "../results/grid-tiny/memory_growth.png").is_file()
    # a grid without a random stream has no growth report
    named = grid_from_dict({"streams": ["pointmaze-1"], "methods": ["scn"], "seeds": [0]}, "n")
    assert "growth.md" not in grid_reports(named, root)[0]


def test_the_memory_figure_draws_one_line_for_structures_that_grow_alike(committed_runs):
    pytest.importorskip("matplotlib")
    from hispo_pl.benchmark.growth_figures import memory_growth_figure

    grid = _grid()
    data = growth_data(grid, Committed(committed_runs))
    _, labels = memory_growth_figure(grid, data).axes[0].get_legend_handles_labels()
    # one network per task: SCN and FTN grow alike, so one dashed line names both
    assert "scn = ftn (structure)" in labels and "pnn (structure)" in labels
    assert not {"scn (structure)", "ftn (structure)"} & set(labels)
    assert "scn measured (1 run)" in labels


def test_a_page_embeds_the_report_of_a_grid_before_its_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)  # the shipped grid definitions, as from a checkout
    grid = load_grid("random-streams", ROOT / "configs")
    folder = tmp_path / "results" / "grid-random-streams"
    page = tmp_path / "page.md"
    embeds = [f"{EMBED_BEGIN}{folder / n} -->\n{EMBED_END}\n" for n in ("growth.md",)]
    embeds.append(f"{EMBED_BEGIN}{folder / 'growth-findings.md'} -->\n{EMBED_END}\n")
    page.write_text("".join(embeds))
    rebuilt = embed_reports(page, Path("/"))
    cells = len(grid.streams) * len(grid.methods) * len(grid.seeds)
    assert f"Runs not committed yet ({cells} of {cells}):" in rebuilt
    assert all(f"- {stream}: hispo (seed 0)" in rebuilt for stream in grid.streams)
    assert f"No run of the grid random-streams is committed yet (0 of {cells})" in rebuilt
    assert not folder.exists()  # embedding writes nothing


def test_memory_after_each_task_of_a_fixed_stream(committed_runs, tmp_path):
    """The memory-per-task table of a grid without random streams (the paper's Figure 3
    beside): a run's measured MEM and its anchors after each task, a run made before MEM was
    measured per task counted for its anchors only."""
    from hispo_pl.benchmark.growth_report import memory_per_task_markdown

    root = tmp_path / "results"
    shutil.copytree(committed_runs / STREAM, root / "tiny")
    old = root / "tiny/hispo/seed1"  # the same run as an older hispo-pl wrote it
    shutil.copytree(root / "tiny/hispo/seed0", old)
    results = RunDir(old).stream_results()  # migrated: no MEM per task is an explicit null
    assert results.mem_per_task is not None
    results.mem_per_task = None
    RunDir(old).write_results(results)
    grid = grid_from_dict({"streams": ["tiny"], "methods": ["hispo", "hilow", "scn"]}, "t")
    text = memory_per_task_markdown(grid, Committed(root))
    for method, seeds, measuring in (("hispo", 2, 1), ("hilow", 1, 1)):
        ours = _results(committed_runs, method)
        (line,) = [x for x in text.splitlines() if x.startswith(f"| tiny | {method} |")]
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[2:4] == [str(seeds), str(measuring)]
        assert cells[4] == " → ".join(f"{m:.2f}" for m in ours["mem_per_task"])
        assert cells[5].split(" → ")[-1] == str(sum(ours["anchors"].values()))
    assert "| tiny | scn |" not in text  # its memory follows from its structure


def _loss(task, decision, l_curr, l_prev=None, subspace="high", eps=0.1):
    from hispo_pl.results import LossDecision

    return LossDecision(task=task, subspace=subspace, decision=decision, eps=eps,
                        l_curr=l_curr, l_prev=l_prev)  # fmt: skip


def test_a_repeat_is_set_beside_the_loss_of_the_earlier_tasks_own_weights():
    from hispo_pl.results import CriticDecision

    stream = ["a", "b", "a", "c", "a"]
    decisions = [
        _loss(0, "first", 0.20),
        _loss(0, "first", 0.90, subspace="low"),
        _loss(1, "keep", 0.30, 0.60),
        _loss(2, "prune", 0.25, 0.18),  # the first repeat pruned: it acts with L_prev's point
        _loss(2, "keep", 0.50, 2.00, subspace="low", eps=0.6),
        _loss(3, "keep", 0.30, 0.90),
        _loss(4, "keep", 0.10, 0.40),  # kept, though task 2's point scores 0.18
        CriticDecision(task=4, subspace="policy", decision="keep", eps=0.1, anchors=3),
    ]
    checks = repeat_checks(stream, decisions)
    assert [(c.task, c.earlier, c.subspace, c.decision) for c in checks] == [
        (2, 0, "high", "prune"),
        (2, 0, "low", "keep"),
        (4, 2, "high", "keep"),
    ]
    first, low, last = checks
    assert (first.own, first.own_prunes) == (0.20, True)  # 0.20 <= 1.1 * 0.25
    assert (low.own, low.own_prunes) == (0.90, False)  # 0.90 > 1.6 * 0.50
    assert last.own == 0.18 and last.own_prunes is False  # the lowest of tasks 0 and 2
    assert repeat_checks(["a", "b"], decisions[:3]) == []  # no repeat, nothing to check

    grid = _grid(["hispo"])
    run = RunCurves(STREAM, "hispo", 0, None, [1.0] * 5, None, repeat_checks=checks)
    text = repeats_markdown(grid, GrowthData([run]))
    assert f"| {STREAM} | hispo | 0 | 3 | 1 | high | prune | 0.72 | 0.80 | 1.10 | yes |" in text
    assert f"| {STREAM} | hispo | 0 | 5 | 3 | high | keep | 4.00 | 1.80 | 1.10 | no |" in text
    assert "Of 3 decisions on a repeated task, 2 kept a new anchor; the earlier task's own " in text
    assert "would have pruned 0 of those 2." in text
    assert "No committed run has decided" in repeats_markdown(grid, GrowthData([]))
