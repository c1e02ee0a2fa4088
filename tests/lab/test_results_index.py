"""docs/results: the index parts the reference results from the studies, and each reference
folder's MANIFEST.md (commit, command, machine per run) is the one its runs' run.json give."""

from __future__ import annotations

import re

import pytest
from helpers import ROOT, write_run_files

from hispo_pl.benchmark import PlannedRun, export_runs, plan
from hispo_pl.results import LaunchRecord
from hispo_pl.rundir import RunDir
from lab.manifest import MANIFEST, REFERENCE_FOLDERS, commit_text, manifest_markdown

RESULTS = ROOT / "docs" / "results"


@pytest.mark.parametrize("name", REFERENCE_FOLDERS)
def test_each_reference_manifest_is_the_one_its_runs_give(name):
    committed = (RESULTS / name / MANIFEST).read_text()
    assert committed == manifest_markdown(RESULTS / name), (
        f"docs/results/{name}/{MANIFEST} is stale: python -m lab manifests"
    )


def _folders_in(section: str) -> set[str]:
    return set(re.findall(r"`([\w.-]+)/`", section))


def test_the_index_parts_the_reference_results_from_the_studies():
    index = (RESULTS / "README.md").read_text()
    reference = index[index.index("## Reference results") : index.index("## Studies")]
    studies = index[index.index("## Studies") :]
    folders = {p.name for p in RESULTS.iterdir() if p.is_dir()}
    top = {name.split("/")[0] for name in REFERENCE_FOLDERS}  # paper-protocol/<stream>: its root
    assert _folders_in(reference) == top
    assert _folders_in(studies) == folders - top


def test_a_run_without_a_clean_commit_is_named_loudly_at_launch_and_export(tmp_path, capsys):
    assert plan.provenance_problem(LaunchRecord(commit="a" * 40)) is None
    assert "no commit" in plan.provenance_problem(LaunchRecord.from_json({"commit": None}))
    assert "uncommitted changes" in plan.provenance_problem(
        LaunchRecord(commit="a" * 40 + "+dirty")
    )
    run = tmp_path / "out" / "scn" / "seed0"
    write_run_files(run, {"stream": ["a"], "R": [[1.0]]}, {"commit": "b" * 40 + "+dirty"})
    export_runs(tmp_path / "out", tmp_path / "dest")
    err = capsys.readouterr().err
    assert "WARNING: exporting" in err and "uncommitted changes" in err
    planned = PlannedRun("scn", 0, tmp_path / "new", ("-m", "hispo_pl.cli", "fit"))
    plan.pending_runs([planned], "pointmaze-1", LaunchRecord.from_json({"commit": None}))
    assert "WARNING: launching 1 run(s): no commit recorded" in capsys.readouterr().err


def test_a_resumed_run_names_every_commit_it_trained_under(tmp_path):
    """A run that spans checkouts (interrupted on one commit, resumed on another) keeps the
    earlier launches' commits in its run.json, its manifest row names them, and an earlier
    dirty launch is a provenance problem as the last one would be."""
    planned = PlannedRun("scn", 0, tmp_path / "run", ("-m", "hispo_pl.cli", "fit"))
    first, second = LaunchRecord(commit="a" * 40), LaunchRecord(commit="b" * 40)
    plan.pending_runs([planned], "pointmaze-1", first)
    plan.pending_runs([planned], "pointmaze-1", second)  # nothing trained yet: a fresh start
    assert RunDir(planned.run_dir).read_run_record().earlier_commits is None
    RunDir(planned.run_dir).progress_file.write_text("{}")  # the first launch trained a part
    plan.pending_runs([planned], "pointmaze-1", second)  # resumed on the same checkout
    assert RunDir(planned.run_dir).read_run_record().earlier_commits is None
    plan.pending_runs([planned], "pointmaze-1", first)
    record = RunDir(planned.run_dir).read_run_record()
    assert (record.commit, record.earlier_commits) == ("a" * 40, ["b" * 40])
    # a record written before that rule, naming its own commit as earlier, reads as one commit
    assert commit_text(LaunchRecord(commit="a" * 40, earlier_commits=["a" * 40])) == "aaaaaaa"
    plan.pending_runs([planned], "pointmaze-1", second)
    record = RunDir(planned.run_dir).read_run_record()
    assert (record.commit, record.earlier_commits) == ("b" * 40, ["b" * 40, "a" * 40])
    assert commit_text(record) == "bbbbbbb (resumed; earlier: bbbbbbb, aaaaaaa)"
    assert plan.provenance_problem(record) is None
    dirty = record.replace(earlier_commits=["c" * 40 + "+dirty"])
    assert "cccccccccccc with uncommitted changes" in plan.provenance_problem(dirty)
