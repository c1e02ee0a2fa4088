"""Resuming a stream across versions and edits: callbacks keep their own checkpoint entries
(``state_key``), and the run fingerprint names callbacks by class, so a reordered callback list
resumes while a changed argument is refused. Tiny budgets."""

from __future__ import annotations

import json

import pytest
import torch
from helpers import quiet_trainer, tiny_stream_args
from lightning.pytorch.trainer import call
from probes import TINY_HISPO, stream_dir

from hispo_pl.callbacks import DirichletEvaluation, RolloutEvaluation
from hispo_pl.cli import main
from hispo_pl.resume import stored_fingerprint
from hispo_pl.run_checks import callback_labels, run_fingerprint, upgrade_callback_keys

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


def test_a_fingerprint_keyed_by_position_reads_as_the_class_keyed_one():
    old = {  # as progress.json of an earlier hispo-pl holds it
        "trainer.callbacks[0].class_path": "hispo_pl.callbacks.AnchorExtension",
        "trainer.callbacks[1].class_path": "hispo_pl.callbacks.SubspacePruning",
        "trainer.callbacks[1].init_args.eps_low": None,
        "trainer.callbacks[2].class_path": "hispo_pl.callbacks.RolloutEvaluation",
        "trainer.callbacks[2].init_args.episodes": 2,
        "trainer.max_steps": 5,
        "model.init_args.lr": 0.001,
    }
    assert stored_fingerprint(old) == {
        "trainer.callbacks[AnchorExtension].class_path": "hispo_pl.callbacks.AnchorExtension",
        "trainer.callbacks[SubspacePruning].class_path": "hispo_pl.callbacks.SubspacePruning",
        "trainer.callbacks[SubspacePruning].init_args.eps_low": None,
        "trainer.callbacks[RolloutEvaluation].class_path": "hispo_pl.callbacks.RolloutEvaluation",
        "trainer.callbacks[RolloutEvaluation].init_args.episodes": 2,
        "trainer.max_steps": 5,
        "model.init_args.optim.lr": 0.001,
    }
    assert upgrade_callback_keys(stored_fingerprint(old)) == stored_fingerprint(old)


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


def test_a_run_with_the_earlier_positional_fingerprint_resumes(hispo_run, capsys):
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
    progress_file.write_text(json.dumps({**progress, "fingerprint": positional}))
    capsys.readouterr()
    assert main(args) == 0
    assert "tasks 1..2 already trained" in capsys.readouterr().out


def test_a_checkpoint_keyed_by_class_name_still_loads_the_callback_state(hispo_run):
    """A task checkpoint of this run, with the callback entry under the bare class name as
    checkpoints before ``state_key`` held it, restores the search's state."""
    save, _, _ = hispo_run
    checkpoint = torch.load(stream_dir(save) / "task_02.ckpt", weights_only=True)
    search = DirichletEvaluation(n_candidates=8, n_batches=1, survivors=None)
    saved = checkpoint["callbacks"].pop(search.state_key)
    assert saved["l_window"]  # L_curr when the convergence window opened, per subspace
    checkpoint["callbacks"]["DirichletEvaluation"] = saved
    trainer = quiet_trainer(1, callbacks=[search])
    call._call_callbacks_on_load_checkpoint(trainer, checkpoint)
    call._call_callbacks_load_state_dict(trainer, checkpoint)
    assert search._l_window == saved["l_window"]


def test_the_task_checkpoint_keys_callbacks_by_class_and_arguments(hispo_run):
    save, _, _ = hispo_run
    states = torch.load(stream_dir(save) / "task_02.ckpt", weights_only=True)["callbacks"]
    search = DirichletEvaluation(n_candidates=8, n_batches=1, survivors=None)
    assert search.state_key in states
