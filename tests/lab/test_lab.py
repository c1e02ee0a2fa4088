"""The repository's tools (``lab/``, never shipped): the paper's figures read from data, the
tables that set ours beside them, the reports embedded in a page, the manifests read from each
run's ``run.json`` alone, and launches that record the checkout's commit."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest
from helpers import ROOT, write_run_files

from hispo_pl.benchmark import grid as gr
from hispo_pl.benchmark import grid_report as gp
from hispo_pl.benchmark import plan
from hispo_pl.results import LaunchRecord
from lab import beside_paper, paper
from lab.__main__ import main as lab_main
from lab.embed import EMBED_BEGIN, EMBED_END, embed_reports
from lab.manifest import MANIFEST, folder_provenance, write_manifests
from lab.provenance import checkout_commit

RESULTS = ROOT / "docs" / "results"
GRID = {"streams": ["pointmaze-1", "pointmaze-2"], "methods": ["scn", "hispo"], "seeds": 3}


def test_the_papers_figures_are_read_from_data_as_printed():
    assert paper.paper_row("pointmaze-1", "hispo")["PER"] == (98.0, 0.4)  # its Table 7
    assert paper.paper_row("pointmaze-1", "csp") is None  # it ran no CSP per stream
    assert paper.AGGREGATE["hispo"] == (87.7, 0.0, 2.0) and paper.METRICS[-1] == "MEM"
    assert paper.ANTMAZE_ABLATION["csp"] == ((42.4, 5.7), (2.7, 0.1))
    assert paper.mean_per("hispo", ["pointmaze-1", "pointmaze-2"]) == pytest.approx(98.9)
    assert paper.mean_per("csp", ["pointmaze-1"]) is None


def test_the_aggregate_gets_the_papers_columns_and_a_page_embeds_it(tmp_path):
    pytest.importorskip("rliable")
    root = tmp_path / "results"
    for stream in GRID["streams"]:
        shutil.copytree(RESULTS / stream, root / stream)
    grid = gr.grid_from_dict(GRID, "g")
    gp.write_grid_report(grid, root, figures=False)  # the product's: no paper in it
    lines = (root / "grid-g/aggregate.md").read_text().splitlines()
    (product,) = [line for line in lines if line.startswith("| hispo |")]
    assert re.fullmatch(r"\| hispo \| 2 of 2 \|.* \| [\d.]+ \[[\d.]+, [\d.]+\] \|", product)
    gp.write_grid_report(grid, root, figures=False, reports=beside_paper.grid_reports)
    aggregate = (root / "grid-g/aggregate.md").read_text()
    # the paper's PER on the same two streams (its Table 7: 98.0 and 99.8), then its Table 1
    (hispo,) = [line for line in aggregate.splitlines() if line.startswith("| hispo |")]
    assert hispo.startswith(product[:-1]) and hispo.endswith("| 98.9 | 87.7 | 0.0 | 2.0 |")
    assert "FZ there is frz here" in aggregate and (root / "grid-g/beside-paper.md").is_file()
    page = tmp_path / "page.md"
    page.write_text(f"x\n{EMBED_BEGIN}{root / 'grid-g/aggregate.md'} -->\nstale\n{EMBED_END}\n")
    rebuilt = embed_reports(page, Path("/"))
    assert "stale" not in rebuilt and hispo in rebuilt
    assert rebuilt == embed_reports(page, Path("/"))  # the intervals are seeded


def test_a_grid_of_random_streams_gets_no_paper_column_summary_or_beside_paper(tmp_path):
    grid = gr.load_grid("random-streams", ROOT / "configs")
    written = gp.write_grid_report(grid, tmp_path, figures=False, reports=beside_paper.grid_reports)
    names = {p.name for p in written}
    assert {"aggregate.md", "growth.md", "grid.json"} <= names
    assert not names & {"summary.md", "beside-paper.md"}
    assert "paper PER" not in (tmp_path / "grid-random-streams/aggregate.md").read_text()


def test_the_papers_point_beside_ours_is_its_mean_over_the_rows_streams(tmp_path):
    from types import SimpleNamespace

    streams = ["pointmaze-1", "pointmaze-2"]
    rows = [SimpleNamespace(method=m, streams=streams) for m in ("hispo", "scn", "cspo")]
    points = beside_paper.paper_points(rows)
    assert set(points) == {"hispo", "scn"}  # the paper has no per-stream CSPO
    mem, per = points["hispo"]
    assert per == pytest.approx((98.0 + 99.8) / 2) and mem == pytest.approx((2.3 + 1.9) / 2)
    assert per == pytest.approx(paper.mean_per("hispo", streams))
    # a grid's committed runs give the figure beside the paper's, in its report folder
    root = tmp_path / "results"
    for stream in streams:
        for seed in range(3):
            src = ROOT / f"docs/results/paper-protocol/{stream}/hispo/seed{seed}"
            shutil.copytree(src, root / stream / "hispo" / f"seed{seed}")
    grid = gr.grid_from_dict({"streams": streams, "methods": ["hispo"], "seeds": 3}, "g")
    path = beside_paper.write_beside_paper_figure(grid, root)
    assert path == root / "grid-g" / beside_paper.BESIDE_FIGURE and path.stat().st_size > 0


# the house grid's aggregate over its four first streams (aggregate-four-streams.md, as
# committed when the beside-paper figure was added): method -> MEM, (IQM, low, high)
FOUR_STREAMS = {
    "sc1": (1.0, (53.5, 52.3, 55.8)), "scn": (4.0, (98.4, 98.1, 98.7)),
    "ft1": (1.0, (53.8, 50.9, 57.8)), "ftn": (4.0, (98.2, 97.6, 98.6)),
    "frz": (1.0, (42.2, 40.6, 44.5)), "l2": (2.0, (50.1, 47.5, 53.2)),
    "ewc": (3.0, (57.2, 54.2, 59.5)), "pnn": (9.15, (99.0, 98.8, 99.4)),
    "hispo": (3.37, (98.2, 97.5, 99.3)), "csp": (1.08, (41.2, 40.5, 42.1)),
    "cspo": (3.5, (98.9, 98.5, 99.3)), "hilow": (1.28, (93.4, 90.8, 96.0)),
}  # fmt: skip


def test_no_name_of_the_crowd_sits_nearer_a_hollow_marker_than_its_own_point():
    """The house grid beside the paper: around MEM 3.4–4.0 HiSPO, CSPO, FTN and SCN crowd with
    the paper's hollow HiSPO, FTN and SCN; CSPO's name once sat under FTN's hollow marker and
    read as its."""
    from types import SimpleNamespace

    import numpy as np

    from hispo_pl.perf_memory_figures import iqm_vs_memory_figure

    streams = ["pointmaze-1", "pointmaze-2", "videogame-1", "videogame-2"]
    rows = [SimpleNamespace(method=m, streams=streams, means={"MEM": mem}, iqm=iqm)
            for m, (mem, iqm) in FOUR_STREAMS.items()]  # fmt: skip
    points = beside_paper.paper_points(rows)
    fig = iqm_vs_memory_figure(rows, "beside", points, "the paper's")
    (ax,) = fig.axes
    fig.draw_without_rendering()
    scale = 72 / fig.dpi

    def distance(point, box) -> float:
        dx = max(box[0] - point[0], 0.0, point[0] - box[2])
        return float(np.hypot(dx, max(box[1] - point[1], 0.0, point[1] - box[3])))

    hollow = ax.transData.transform(list(points.values())) * scale
    crowd = [t for t in ax.texts if t.get_text() in ("hispo", "cspo", "ftn", "scn")]
    assert len(crowd) == 4 and {"hispo", "ftn", "scn"} <= set(points)
    for text in crowd:
        mem, (per, _, _) = FOUR_STREAMS[text.get_text()]
        box = text.get_window_extent().extents * scale
        mine = distance(ax.transData.transform((mem, per)) * scale, box)
        assert all(distance(h, box) >= mine for h in hollow), text.get_text()


def test_beside_paper_puts_the_papers_figure_next_to_ours(tmp_path):
    shutil.copytree(RESULTS / "pointmaze-1/frz", tmp_path / "pointmaze-1/frz")
    text = beside_paper.beside_paper_markdown(gp.Committed(tmp_path))
    frz = next(line for line in text.splitlines() if line.startswith("| frz | 3 |"))
    assert frz.startswith("| frz | 3 | 34.2 ± 2.6 | 37.8 ± 0.8 |")  # the paper's FZ, Table 7
    assert "| pnn |  | 99.4 ± 0.8 |  | 0.0 ± 0.0 |" in text  # not run here: an empty cell
    assert "| videogame-2 |" not in text and "### videogame-2 (the paper's Table 9)" in text


def test_beside_paper_of_a_grid_shows_its_streams_and_those_with_runs(tmp_path):
    shutil.copytree(RESULTS / "pointmaze-1/frz", tmp_path / "pointmaze-1/frz")
    streams = ["pointmaze-1", "pointmaze-2"]
    text = beside_paper.beside_paper_markdown(gp.Committed(tmp_path), streams)
    assert "### pointmaze-2 (the paper's Table 7)" in text  # the grid's, not run yet
    assert "### videogame-1" not in text and "AntMaze ablation" not in text
    shutil.copytree(RESULTS / "antmaze-1/hispo", tmp_path / "antmaze-1/hispo")
    text = beside_paper.beside_paper_markdown(gp.Committed(tmp_path), streams)
    assert "### antmaze-1 (the paper's Table 8)" in text and "AntMaze ablation" in text


def test_summary_bolds_the_best_and_counts_seeds_other_than_three(tmp_path):
    for method in ("hispo", "scn"):
        shutil.copytree(RESULTS / f"pointmaze-1/{method}", tmp_path / f"pointmaze-1/{method}")
    shutil.copytree(RESULTS / "pointmaze-1/scn/seed0", tmp_path / "pointmaze-2/scn/seed0")
    text = beside_paper.summary_markdown(gp.Committed(tmp_path))
    assert "| PointMaze-1 | **99.4 ± 0.1 / 3.37** | 98.8 ± 0.4 / 4.00 | – |" in text
    assert "| PointMaze-2 | – | **99.0 / 4.00 (1 seed)** | – |" in text
    assert text.rstrip().splitlines()[-3].startswith("| VideoGame-2 | – |")


def _finished_run(out: Path, method: str, seed: int) -> Path:
    run = out / "runs" / method / f"seed{seed}"
    run.mkdir(parents=True)
    tasks = ["pointmaze-umaze-N[500]", "pointmaze-large-N[500]"]
    R = [[0.9, None], [0.9, 0.9]]
    write_run_files(run, {"stream": tasks, "R": R, "MEM": 1.0}, {"method": method, "seed": seed})
    return run


@pytest.mark.parametrize(
    "embed, said",
    [
        ("<!-- report: {tmp}/none/table.md -->\nold\n<!-- end report -->", "no runs"),
        ("<!-- report: {tmp}/x/runs/table.md -->\nold\n", "has no closing"),
        ("<!-- report: {tmp}/x/runs/nothing.md -->\nold\n<!-- end report -->", "nothing.md"),
    ],
    ids=["no-runs", "not-closed", "no-such-report"],
)
def test_a_page_whose_embed_cannot_be_built_is_one_line(tmp_path, capsys, embed, said):
    _finished_run(tmp_path / "x", "scn", 0)  # x/runs: an exported stream's layout
    page = tmp_path / "page.md"
    page.write_text("# page\n" + embed.replace("{tmp}", str(tmp_path)) + "\n")
    before = page.read_text()
    assert lab_main(["rebuild-docs", str(page)]) == 2
    err = capsys.readouterr().err.strip()
    assert said in err and str(page) in err and len(err.splitlines()) == 1, err
    assert page.read_text() == before


def test_a_benchmark_flag_to_fix_is_one_line(tmp_path, capsys):
    args = ["--grid", "paper", "--out", str(tmp_path / "w"), "--export", str(tmp_path / "r")]
    assert lab_main(["benchmark", *args, "--seeds", "0", "--dry-run"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "python -m lab benchmark: --seeds as a count must be >= 1, got '0' " + (
        "(seed 0 alone: --seeds 1, or a list such as 0,) (hispo-pl benchmark --help)"
    )


def test_a_page_that_does_not_exist_is_one_line(tmp_path, capsys):
    assert lab_main(["rebuild-docs", str(tmp_path / "no.md")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"python -m lab rebuild-docs: {tmp_path / 'no.md'}: no such page"
    assert not (tmp_path / "no.md").exists()


def test_a_manifest_row_reads_the_runs_own_run_json(tmp_path):
    made = tmp_path / "hispo" / "seed0"
    made.mkdir(parents=True)
    (made / "results.json").write_text("{}")
    argv = ["-m", "hispo_pl.cli", "fit", "--config", "/work/x/configs/streams/pointmaze-1.yaml"]
    machine = {"platform": "Linux-6", "cpus": 2, "torch": "2.13.0+cpu", "mujoco": "4.0.1"}
    record = {"commit": "89f9f6fab9ca098775c946e85840a779acbebc32+dirty", "machine": machine}
    write_run_files(made, launch={**record, "argv": argv})
    older = tmp_path / "scn" / "seed0"
    older.mkdir(parents=True)
    (older / "results.json").write_text("{}")
    (older / "config.yaml").write_text("seed_everything: 0\n")
    write_run_files(older, launch={"committed_in": "abc1234"})
    bare = tmp_path / "sc1" / "seed0"
    bare.mkdir(parents=True)
    (bare / "results.json").write_text("{}")
    rows = [(r.run, r.commit, r.machine, r.command) for r in folder_provenance(tmp_path)]
    assert rows == [
        (
            "hispo/seed0",
            "89f9f6f+dirty",
            "Linux-6, 2 CPUs, torch 2.13.0+cpu, MuJoCo 4.0.1",
            "`hispo-pl fit --config configs/streams/pointmaze-1.yaml`",
        ),
        ("sc1/seed0", "not recorded", "not recorded", "not recorded"),
        (
            "scn/seed0",
            "abc1234 (committed)",
            "not recorded",
            "not recorded; its settings: `scn/seed0/config.yaml`",
        ),
    ]


def test_a_manifest_replaces_its_link_and_escapes_what_run_json_says(tmp_path):
    folder = tmp_path / "pointmaze-1"
    run = _finished_run(folder, "scn", 0)
    crafted = ["-m", "hispo_pl.cli", "fit", "x |\n| injected | row | here | `code` |\n"]
    crafted += [  # a run directory with a cell's end and a code span in its name
        *("--trainer.logger.init_args.save_dir", "/w/results/a|b`c`/runs"),
        *("--trainer.logger.init_args.name", "scn", "--trainer.logger.init_args.version", "s0"),
    ]
    record = {"argv": crafted, "commit": "abc|def", "machine": {"platform": "a\nb"}}
    write_run_files(run, launch=record)
    victim = tmp_path / "victim"
    victim.write_text("victim\n")
    (folder / MANIFEST).symlink_to(victim)
    write_manifests(tmp_path)
    assert victim.read_text() == "victim\n" and not (folder / MANIFEST).is_symlink()
    rows = [ln for ln in (folder / MANIFEST).read_text().splitlines() if ln.startswith("|")]
    assert len(rows) == 3 and "injected" in rows[2]  # the header, its rule, the run
    assert rows[2].replace("\\|", "").count("|") == 6 and "\\`code\\`" in rows[2]
    assert "results/a\\|b\\`c\\`/runs/scn/s0" in rows[2]  # the run directory, escaped too


def test_a_launch_records_the_checkout_commit_only_through_the_lab(monkeypatch):
    made = plan.provenance()  # the product's: the machine and hispo-pl's version, no git
    assert not made.holds("commit") and made.machine["cpus"] >= 1
    assert plan.provenance_problem(made) is None  # nothing recorded, nothing to warn about
    commit = checkout_commit()["commit"]
    assert commit is None or re.fullmatch(r"[0-9a-f]{40}(\+dirty)?", commit)
    monkeypatch.setattr(plan, "CODE_RECORDERS", [lambda: {"commit": "c" * 40}])
    assert plan.provenance().commit == "c" * 40
    assert "no commit" in plan.provenance_problem(LaunchRecord.from_json({"commit": None}))
    assert "uncommitted changes" in plan.provenance_problem(
        LaunchRecord(commit="a" * 40 + "+dirty")
    )


def test_a_terminated_benchmark_stops_as_an_interrupt(monkeypatch, capsys):
    """SIGTERM reaches the benchmark's runner as Ctrl-C does (it then terminates its runs),
    not as the default death that would leave them running."""
    import os
    import signal
    import time

    from hispo_pl.benchmark import command_line
    from lab.__main__ import benchmark

    def terminated(argv):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the signal arrives before this ends
        raise AssertionError("SIGTERM did not stop the benchmark")

    monkeypatch.setattr(command_line, "main", terminated)
    before = signal.getsignal(signal.SIGTERM)
    assert benchmark(["--grid", "paper", "--dry-run"]) == 128 + signal.SIGTERM
    assert "python -m lab benchmark: interrupted" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGTERM) == before  # restored afterwards
