"""docs/results: the index parts the reference results from the studies, and each reference
folder's MANIFEST.md (commit, command, machine per run) is the one its run files give."""

from __future__ import annotations

import json
import re
import subprocess

import pytest
from helpers import ROOT

from hispo_pl.benchmark import PlannedRun, export_runs, plan
from hispo_pl.benchmark.manifest import (
    MANIFEST,
    REFERENCE_FOLDERS,
    folder_provenance,
    git_commit_of,
    manifest_markdown,
)

RESULTS = ROOT / "docs" / "results"


def full_history() -> bool:
    """Whether this checkout has the whole history, so that ``git log`` names the commit that
    committed a run (a shallow clone, or a copy without git, knows only its own)."""
    done = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--is-shallow-repository"],
        capture_output=True,
        text=True,
    )
    return done.returncode == 0 and done.stdout.strip() == "false"


def without_logged_commits(manifest: str) -> str:
    """A manifest with the commit column blanked where it came from ``git log`` (or found
    none), and kept where the run recorded its commit."""
    logged = re.compile(r"[0-9a-f]{4,40} \(committed\)|not recorded")
    lines = []
    for line in manifest.splitlines():
        cells = line.split(" | ")
        if line.startswith("| ") and len(cells) >= 4 and logged.fullmatch(cells[1]):
            cells[1] = "(git log)"
        lines.append(" | ".join(cells))
    return "\n".join(lines)


@pytest.mark.parametrize("name", REFERENCE_FOLDERS)
def test_each_reference_manifest_is_the_one_its_runs_give(name):
    committed = (RESULTS / name / MANIFEST).read_text()
    rebuilt = manifest_markdown(RESULTS / name, git_commit_of)
    if not full_history():  # every other column still compared
        committed, rebuilt = without_logged_commits(committed), without_logged_commits(rebuilt)
    assert committed == rebuilt, (
        f"docs/results/{name}/{MANIFEST} is stale: python -m hispo_pl.benchmark.manifest "
        "docs/results"
    )


def test_a_run_names_its_recorded_provenance_else_the_commit_that_committed_it(tmp_path):
    recorded = tmp_path / "hispo" / "seed0"
    recorded.mkdir(parents=True)
    (recorded / "results.json").write_text("{}")
    argv = ["-m", "hispo_pl.cli", "fit", "--config", "/work/x/configs/streams/pointmaze-1.yaml"]
    machine = {"platform": "Linux-6", "cpus": 2, "python": "3.11", "torch": "2.13.0+cpu"}
    record = {"commit": "89f9f6fab9ca098775c946e85840a779acbebc32", "machine": machine}
    (recorded / "run.json").write_text(json.dumps({**record, "argv": argv}))
    bare = tmp_path / "scn" / "seed0"
    bare.mkdir(parents=True)
    (bare / "results.json").write_text("{}")
    (bare / "config.yaml").write_text("seed_everything: 0\n")
    asked = []

    def commit_of(path):
        asked.append(path)
        return "abc1234"

    rows = folder_provenance(tmp_path, commit_of)
    assert [(r.run, r.commit, r.machine, r.command) for r in rows] == [
        (
            "hispo/seed0",
            "89f9f6f",
            "Linux-6, 2 CPUs, torch 2.13.0+cpu",
            "`hispo-pl fit --config configs/streams/pointmaze-1.yaml`",
        ),
        (
            "scn/seed0",
            "abc1234 (committed)",
            "not recorded",
            "not recorded; its settings: `scn/seed0/config.yaml`",
        ),
    ]
    assert asked == [bare / "results.json"]


def _folders_in(section: str) -> set[str]:
    return set(re.findall(r"`([\w.-]+)/`", section))


def test_the_index_parts_the_reference_results_from_the_studies():
    index = (RESULTS / "README.md").read_text()
    reference = index[index.index("## Reference results") : index.index("## Studies")]
    studies = index[index.index("## Studies") :]
    folders = {p.name for p in RESULTS.iterdir() if p.is_dir()}
    assert _folders_in(reference) == set(REFERENCE_FOLDERS)
    assert _folders_in(studies) == folders - set(REFERENCE_FOLDERS)


def test_a_run_without_a_clean_commit_is_named_loudly_at_launch_and_export(tmp_path, capsys):
    assert plan.provenance_problem({"commit": "a" * 40}) is None
    assert "no commit" in plan.provenance_problem({"commit": None})
    assert "uncommitted changes" in plan.provenance_problem({"commit": "a" * 40 + "+dirty"})
    run = tmp_path / "out" / "scn" / "seed0"
    run.mkdir(parents=True)
    (run / "results.json").write_text(json.dumps({"stream": ["a"], "R": [[1.0]]}))
    (run / "run.json").write_text(json.dumps({"commit": "b" * 40 + "+dirty"}))
    export_runs(tmp_path / "out", tmp_path / "dest")
    err = capsys.readouterr().err
    assert "WARNING: exporting" in err and "uncommitted changes" in err
    planned = PlannedRun("scn", 0, tmp_path / "new", ("-m", "hispo_pl.cli", "fit"))
    plan.pending_runs([planned], "pointmaze-1", {"commit": None})
    assert "WARNING: launching 1 run(s): no commit recorded" in capsys.readouterr().err
