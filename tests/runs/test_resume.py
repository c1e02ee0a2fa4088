"""Resuming a stream across edits: callbacks keep their own checkpoint entries (``state_key``),
and the run fingerprint names callbacks by class, so a reordered callback list resumes while a
changed argument is refused; a progress file of an earlier format is refused until migrated.
Tiny budgets."""

from __future__ import annotations

import json

import pytest
import torch
from helpers import quiet_trainer, tiny_stream_args
from lightning.pytorch.trainer import call
from probes import TINY_HISPO, stream_dir

from hispo_pl.callbacks import DirichletEvaluation, RolloutEvaluation
from hispo_pl.cli import main
from hispo_pl.run_checks import callback_labels, run_fingerprint

REORDERED = TINY_HISPO.replace(
    "    - class_path: hispo_pl.callbacks.AnchorExtension\n", ""
).replace(
    "    - class_path: hispo_pl.callbacks.SubspacePruning\n",
    "    - class_path: hispo_pl.callbacks.AnchorExtension\n"
    "    - class_path: hispo_pl.callbacks.SubspacePruning\n",
)


def test_two_instances_of_a_callback_keep_their_own_checkpoint_entries():
    searches = [DirichletEvaluation(n_candidates=8), DirichletEvaluation(n_candidates=16)]
    searches[0]._l_window, searches[1]._l_window = {"high": 1.0}, {"high": 2.0}
    trainer = quiet_trainer(1, callbacks=[*searches, RolloutEvaluation(episodes=2)])
    states = call._call_callbacks_state_dict(trainer)
    assert sorted(s["l_window"]["high"] for s in states.values() if "l_window" in s) == [1, 2]
    assert RolloutEvaluation(episodes=2).state_key != RolloutEvaluation(episodes=3).state_key


def test_callbacks_are_named_by_class_and_instance_not_position():
    assert callback_labels(["x.A", "x.B", "x.A"]) == ["A", "B", "A#2"]
    config = {
        "trainer": {
            "callbacks": [
                {"class_path": "hispo_pl.callbacks.SubspacePruning", "init_args": {"eps_low": 0.2}},
                {"class_path": "hispo_pl.callbacks.RolloutEvaluation", "init_args": {}},
            ]
        }
    }
    swapped = {"trainer": {"callbacks": config["trainer"]["callbacks"][::-1]}}
    assert run_fingerprint(config) == run_fingerprint(swapped)
    assert run_fingerprint(config)["trainer.callbacks[SubspacePruning].init_args.eps_low"] == 0.2


@pytest.fixture(scope="module")
def hispo_run(tiny_umaze, tmp_path_factory):
    """A finished tiny HiSPO stream: its save dir, arguments and results."""
    save = tmp_path_factory.mktemp("hispo_run")
    config = save / "hispo.yaml"
    config.write_text(TINY_HISPO)
    args = tiny_stream_args(config, save)
    assert main(args) == 0
    return save, args, json.loads((stream_dir(save) / "results.json").read_text())


def _with_config(args: list[str], config) -> list[str]:
    i = args.index("--config", args.index("--config") + 1)  # the method's, after the stream's
    return [*args[: i + 1], str(config), *args[i + 2 :]]


def test_reordered_callbacks_resume_and_a_changed_argument_is_refused(hispo_run, capsys):
    save, args, results = hispo_run
    reordered = save / "reordered.yaml"
    reordered.write_text(REORDERED)
    assert REORDERED != TINY_HISPO
    capsys.readouterr()
    assert main(_with_config(args, reordered)) == 0
    assert "tasks 1..2 already trained" in capsys.readouterr().out
    assert json.loads((stream_dir(save) / "results.json").read_text())["R"] == results["R"]

    changed = save / "changed.yaml"
    changed.write_text(REORDERED.replace("n_candidates: 8", "n_candidates: 4"))
    assert main(_with_config(args, changed)) == 2
    err = capsys.readouterr().err
    assert "trainer.callbacks[DirichletEvaluation].init_args.n_candidates: 8 -> 4" in err


def test_an_earlier_progress_file_is_refused_until_migrated(hispo_run, capsys):
    """progress.json as an earlier hispo-pl wrote it (no format number, callbacks keyed by list
    position) stops the rerun with one line naming the file and the migration; migrated, the
    run resumes."""
    from lab.migrate import migrate

    save, args, results = hispo_run
    progress_file = stream_dir(save) / "progress.json"
    progress = json.loads(progress_file.read_text())
    labels = {}
    for key in progress["fingerprint"]:
        if key.startswith("trainer.callbacks[") and key.endswith("].class_path"):
            labels[key[len("trainer.callbacks[") : -len("].class_path")]] = len(labels)
    positional = {}
    for key, value in progress["fingerprint"].items():
        for label, i in labels.items():
            key = key.replace(f"trainer.callbacks[{label}].", f"trainer.callbacks[{i}].")
        positional[key] = value
    assert positional != progress["fingerprint"] and len(labels) == 4
    earlier = {k: v for k, v in progress.items() if k != "format"} | {"fingerprint": positional}
    progress_file.write_text(json.dumps(earlier, indent=1))
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "progress.json has no format number" in err and "python -m lab migrate" in err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert migrate(stream_dir(save)) == 0
    assert json.loads(progress_file.read_text()) == progress
    capsys.readouterr()
    assert main(args) == 0
    assert "tasks 1..2 already trained" in capsys.readouterr().out


def test_the_task_checkpoint_keys_callbacks_by_class_and_arguments(hispo_run):
    save, _, _ = hispo_run
    states = torch.load(stream_dir(save) / "task_02.ckpt", weights_only=True)["callbacks"]
    search = DirichletEvaluation(n_candidates=8, n_batches=1, survivors=None)
    assert search.state_key in states
