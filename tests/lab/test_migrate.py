"""``python -m lab migrate``: every earlier form of each run file becomes the current one, the
numbers as they were, idempotently; a live run's folder is skipped; a file of no known form is
named. The earlier forms below are those committed runs had before the format number."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from hispo_pl.results import Decision, LaunchRecord, Progress, StreamResults
from hispo_pl.rundir import RunDir
from lab.__main__ import main as lab_main
from lab.migrate import (
    MigrationError,
    class_keyed_callbacks,
    migrate,
    migrate_tree,
    migrated_text,
    nested_model_keys,
)

STREAM = ["pointmaze-umaze-N[500]", "pointmaze-large-N[500]"]
R = [[1.0, 0.18], [1.0, 0.75]]
WALL = [497.0140816490002, 467.2353852010001]
TABLE = "| after \\ on | 1 | 2 |"

EARLIER = {
    "before-phase-times/results.json": {  # no phase times, datasets or MEM per task
        "stream": STREAM,
        "R": R,
        "wall_time_s": WALL,
        "PER": 0.875,
        "BWT": 0.0,
        "stored_bytes": 1241256,
        "MEM": 2.134032954639232,
        "anchors": {"high": 2, "low": 1},
        "alphas": {"high": [[1.0, 0.0], [0.3, 0.7]], "low": [[1.0], [1.0]]},
        "table": TABLE,
    },
    "before-datasets/results.json": {
        "stream": STREAM,
        "R": R,
        "wall_time_s": WALL,
        "phase_time_s": [{"training": 400.5, "evaluation": 90.25}, None],
        "PER": 0.875,
        "BWT": 0.0,
        "stored_bytes": 620628,
        "MEM": 1.0,
        "table": TABLE,
    },
    "before-curves/result.json": {
        "method": "HBC",
        "task": "antmaze-large-N[500]",
        "episodes": 100,
        "seconds": 213.4,
        "success": 0.35,
        "episode_length": 678.16,
        "flip_rate": 0.14,
        "step": 6000.0,
    },
    "derived/run.json": {
        "derived_from": "pointmaze-1/ftn/seed0",
        "method": "ft1",
        "seed": 0,
        "stream": "pointmaze-1",
        "steps_per_task": 6000,
        "argv": ["fit"],
        "command": "python -m hispo_pl fit",
        "committed_in": "abc1234",
    },
    "before-fingerprints/progress.json": {
        "stream": STREAM,
        "rows": [[0.93, 0.15]],
        "wall_time_s": [611.2621885469999],
    },
    "positional/progress.json": {
        "stream": STREAM,
        "rows": [[0.93, 0.15], [0.9, 0.26]],
        "wall_time_s": WALL,
        "fingerprint": {
            "model.init_args.high_hidden": 64,
            "model.init_args.lr": 0.001,
            "model.init_args.backbone": "bc",
            "trainer.callbacks[0].class_path": "hispo_pl.callbacks.AnchorExtension",
            "trainer.callbacks[1].class_path": "hispo_pl.callbacks.SubspacePruning",
            "trainer.callbacks[1].init_args.eps_low": 0.1,
            "trainer.callbacks[2].class_path": "hispo_pl.callbacks.RolloutEvaluation",
            "trainer.callbacks[3].class_path": "hispo_pl.callbacks.RolloutEvaluation",
            "trainer.callbacks[3].init_args.episodes": 2,
            "trainer.max_steps": 5,
        },
    },
}
DECISIONS = [  # a record written before the search recorded its convergence, then a cut line
    json.dumps({"task": 0, "subspace": "low", "decision": "first", "eps": 0.1, "anchors": 1}),
    '{"task": 1, "subs',
]


def _earlier_tree(root: Path) -> dict[str, str]:
    """The earlier forms under ``root``, as committed files had them; their texts by path."""
    texts = {}
    for name, record in EARLIER.items():
        indent = 2 if name.endswith("result.json") else 1
        texts[name] = json.dumps(record, indent=indent) + ("\n" if indent == 2 else "")
    texts["before-phase-times/decisions.jsonl"] = "\n".join(DECISIONS) + "\n"
    for name, text in texts.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return texts


def _same_numbers(before: dict, after: dict) -> None:
    """Every key of ``before`` holds the same value after (JSON text, so 1.0 stays 1.0); a key
    it did not have is the format number or null (per task or whole)."""
    for key, value in before.items():
        assert json.dumps(after[key]) == json.dumps(value), key
    for key in set(after) - set(before):
        value = after[key]
        nothing = value is None or (isinstance(value, list) and set(map(str, value)) == {"None"})
        assert key == "format" or nothing, (key, value)


def test_each_earlier_form_becomes_current_keeping_every_number(tmp_path):
    texts = _earlier_tree(tmp_path)
    done = migrate_tree(tmp_path)
    assert sum(done.rewritten.values()) == len(texts) and not done.problems
    for name, record in EARLIER.items():
        after = json.loads((tmp_path / name).read_text())
        assert list(after)[0] == "format" and after["format"] == 1
        if "fingerprint" in record:  # keyed anew (the next test), its values the same
            assert list(after["fingerprint"].values()) == list(record["fingerprint"].values())
            record, after = (
                {k: v for k, v in d.items() if k != "fingerprint"} for d in (record, after)
            )
        _same_numbers(record, after)
    old = RunDir(tmp_path / "before-phase-times").stream_results()
    assert old.phase_time_s is None and old.datasets is None and old.mem_per_task is None
    assert RunDir(tmp_path / "before-datasets").stream_results().phase_time_s[1] is None
    result = RunDir(tmp_path / "before-curves").read_result()
    assert result.curve is None and result.dataset is None and result.success == 0.35
    launch = RunDir(tmp_path / "derived").read_run_record()
    assert list(launch.to_json())[:2] == ["derived_from", "method"]
    assert launch.committed_in == "abc1234"
    bare = RunDir(tmp_path / "before-fingerprints").read_progress()
    assert bare.fingerprint is None and bare.mem_per_task is None
    assert bare.phase_time_s == [None] and bare.datasets == [None]
    decisions = (tmp_path / "before-phase-times/decisions.jsonl").read_text().splitlines()
    assert decisions[1] == DECISIONS[1]  # no record: kept as it was
    first = json.loads(decisions[0])
    assert first["improvement"] is None and first == Decision.from_json(first).to_json()


def test_an_earlier_fingerprint_is_keyed_as_run_fingerprint_keys_it(tmp_path):
    _earlier_tree(tmp_path)
    migrate_tree(tmp_path)
    fingerprint = RunDir(tmp_path / "positional").read_progress().fingerprint
    assert fingerprint == {
        "model.init_args.backbone.high_hidden": 64,
        "model.init_args.optim.lr": 0.001,
        "model.init_args.backbone.kind": "bc",
        "trainer.callbacks[AnchorExtension].class_path": "hispo_pl.callbacks.AnchorExtension",
        "trainer.callbacks[SubspacePruning].class_path": "hispo_pl.callbacks.SubspacePruning",
        "trainer.callbacks[SubspacePruning].init_args.eps_low": 0.1,
        "trainer.callbacks[RolloutEvaluation].class_path": "hispo_pl.callbacks.RolloutEvaluation",
        "trainer.callbacks[RolloutEvaluation#2].class_path": (
            "hispo_pl.callbacks.RolloutEvaluation"
        ),
        "trainer.callbacks[RolloutEvaluation#2].init_args.episodes": 2,
        "trainer.max_steps": 5,
    }
    assert class_keyed_callbacks(fingerprint) == fingerprint
    assert nested_model_keys(fingerprint) == fingerprint


def test_a_second_migration_changes_nothing(tmp_path):
    _earlier_tree(tmp_path)
    migrate_tree(tmp_path)
    first = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    done = migrate_tree(tmp_path)
    assert not done.rewritten and sum(done.current.values()) == len(first)
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == first


def test_a_file_the_current_writer_wrote_is_its_own_migration(tmp_path):
    run = RunDir(tmp_path)
    progress = Progress(stream=STREAM, fingerprint={"seed": 0})
    progress.finish_task(R[0], WALL[0], {"training": 1.5}, {"id": "d", "episodes": 3}, 1.25)
    run.write_progress(progress)
    run.write_results(StreamResults(stream=STREAM, R=R, wall_time_s=WALL, table=TABLE))
    run.write_run_record(LaunchRecord.from_json(EARLIER["derived/run.json"]))
    run.append_decisions([Decision.from_json(json.loads(DECISIONS[0]))])
    for path in (run.progress_file, run.results_file, run.run_record_file, run.decisions_file):
        assert migrated_text(path.name, path.read_text()) == path.read_text(), path.name


def test_a_live_run_is_skipped_and_a_dead_one_migrated(tmp_path, capsys):
    _earlier_tree(tmp_path)
    host = socket.gethostname()
    live = tmp_path / "derived" / "run.lock"
    live.write_text(f"pid {os.getpid()} on {host}, started 2026-12-04 10:00:00: fit\n")
    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], stdout=-1)
    dead = tmp_path / "before-curves" / "run.lock"
    dead.write_text(f"pid {int(ended.stdout)} on {host}, started 2026-12-04 10:00:00: fit\n")
    (tmp_path / "positional" / "run.lock").write_text("")  # released
    before = (tmp_path / "derived" / "run.json").read_text()
    assert migrate(tmp_path) == 0
    out = capsys.readouterr().out
    assert f"skipped {tmp_path / 'derived'}: a live run holds it (pid {os.getpid()}" in out
    assert (tmp_path / "derived" / "run.json").read_text() == before
    assert json.loads((tmp_path / "before-curves" / "result.json").read_text())["format"] == 1
    assert json.loads((tmp_path / "positional" / "progress.json").read_text())["format"] == 1


def test_check_says_what_would_change_and_writes_nothing(tmp_path, capsys):
    texts = _earlier_tree(tmp_path)
    assert lab_main(["migrate", str(tmp_path), "--check"]) == 1
    assert "to migrate under" in capsys.readouterr().out
    assert all((tmp_path / n).read_text() == t for n, t in texts.items())
    assert lab_main(["migrate", str(tmp_path)]) == 0
    assert lab_main(["migrate", str(tmp_path), "--check"]) == 0


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ('{"format": 2, "stream": []}', "it is of format 2; this lab knows up to 1"),
        ("{", "it is not readable JSON"),
        ("[1]", "it holds a JSON list, not an object"),
    ],
)
def test_a_file_of_no_known_form_is_named_in_one_line(tmp_path, capsys, text, why):
    with pytest.raises(MigrationError, match=why):
        migrated_text("results.json", text)
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "results.json").write_text(text)
    assert lab_main(["migrate", str(tmp_path)]) == 2
    captured = capsys.readouterr()
    assert f"cannot migrate {tmp_path / 'run' / 'results.json'}: {why}" in captured.out
    assert captured.err.count("\n") == 1 and "python -m lab migrate:" in captured.err
    assert (tmp_path / "run" / "results.json").read_text() == text
