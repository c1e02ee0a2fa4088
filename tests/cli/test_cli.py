"""End to end through the ``hispo-pl`` command: one short fit, config handling, data commands."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from hispo_pl.cli import main

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "configs" / "demo.yaml"  # a two-task stream, combined with a method config
CONFIGS = sorted(
    p
    for p in (ROOT / "configs").rglob("*.yaml")
    if p.parent.name not in ("streams", "methods", "grids") and p != DEMO
)
STREAM_CONFIGS = sorted((ROOT / "configs/streams").glob("*.yaml"))
METHOD_CONFIGS = sorted((ROOT / "configs/methods").glob("*.yaml"))


def _fit_args(tmp_path: Path, *extra: str) -> list[str]:
    return [
        "fit",
        "--config",
        str(ROOT / "configs/hbc/pointmaze-umaze.yaml"),
        "--data.task",
        "pointmaze-umaze-N[6]",
        "--data.batch_size",
        "256",
        "--trainer.max_steps",
        "40",
        "--trainer.logger.init_args.save_dir",
        str(tmp_path),
        "--trainer.callbacks.init_args.eval_every",
        "20",
        "--trainer.callbacks.init_args.episodes",
        "4",
        "--trainer.log_every_n_steps",
        "10",
        "--trainer.enable_progress_bar",
        "false",
        *extra,
    ]


def test_fit_trains_evaluates_logs_and_prints_success(tiny_umaze, tmp_path, capsys):
    main(_fit_args(tmp_path))
    out, err = capsys.readouterr()
    assert "[hispo-pl] HBC on pointmaze-umaze-N[6]: success" in out
    assert "over 4 episodes" in out and "after 40 steps (" in out and "s with evaluations)" in out
    # not a terminal: progress as a line every tenth of the steps, on stderr
    assert "[hispo-pl] pointmaze-umaze-N[6] step 4/40 (10 %), loss " in err
    assert "[hispo-pl] pointmaze-umaze-N[6] step 40/40 (100 %), loss " in err

    events = list(tmp_path.rglob("events.out.tfevents.*"))
    assert events, "no TensorBoard event file written"
    acc = EventAccumulator(str(events[0].parent))
    acc.Reload()
    tags = acc.Tags()["scalars"]
    assert {"train/loss_high", "train/loss_low", "eval/success"} <= set(tags)
    success = acc.Scalars("eval/success")
    assert [s.step for s in success] == [20, 40]  # periodic, then at the end of training
    assert all(0.0 <= s.value <= 100.0 for s in success)  # in %, as the console prints it
    checkpoints = list(tmp_path.rglob("*.ckpt"))
    assert checkpoints, "no checkpoint written"
    (result_file,) = tmp_path.rglob("result.json")
    result = json.loads(result_file.read_text())
    assert result["method"] == "HBC" and result["task"] == "pointmaze-umaze-N[6]"
    assert result["step"] == 40 and result["episodes"] == 4
    assert 100 * result["success"] == pytest.approx(success[-1].value)

    # the checkpoint alone rebuilds the policy; evaluate it on a task it never saw
    capsys.readouterr()
    args = ["evaluate", "--ckpt", str(checkpoints[0]), "--task", "pointmaze-umaze-IA[6]"]
    assert main([*args, "--episodes", "3", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["method"] == "HBC" and report["task"] == "pointmaze-umaze-IA[6]"
    assert report["episodes"] == 3 and 0.0 <= report["success"] <= 1.0
    assert 0 < report["episode_length"] <= 300


def test_evaluate_rejects_a_missing_checkpoint(tmp_path, capsys):
    assert (
        main(["evaluate", "--ckpt", str(tmp_path / "nope.ckpt"), "--task", "pointmaze-umaze"]) == 2
    )
    assert "no checkpoint at" in capsys.readouterr().err


@pytest.mark.skipif(__import__("torch").cuda.is_available(), reason="this machine has a GPU")
def test_a_gpu_trainer_without_a_gpu_is_one_line(tiny_umaze, tmp_path, capsys):
    assert main([*_fit_args(tmp_path), "--trainer.accelerator", "gpu"]) == 2
    err = capsys.readouterr().err
    assert "the Trainer cannot be made as configured: No supported gpu backend" in err
    assert "Traceback" not in err


def test_flat_bc_config_runs(tiny_umaze, tmp_path, capsys):
    args = _fit_args(tmp_path)
    args[2] = str(ROOT / "configs/bc/pointmaze-umaze.yaml")
    main(args)
    assert "[hispo-pl] BC on pointmaze-umaze-N[6]: success" in capsys.readouterr().out


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_shipped_config_parses(config, capsys):
    with pytest.raises(SystemExit) as done:
        main(["fit", "--config", str(config), "--print_config"])
    assert done.value.code == 0
    printed = capsys.readouterr().out
    task = yaml.safe_load(config.read_text())["data"]["task"]
    assert "class_path: hispo_pl.modules." in printed and f"task: {task}" in printed


def test_the_demo_is_a_two_task_hispo_stream(capsys):
    with pytest.raises(SystemExit) as done:
        main(
            [
                "fit",
                "--config",
                str(DEMO),
                "--config",
                str(ROOT / "configs/methods/hispo.yaml"),
                "--print_config",
            ]
        )
    assert done.value.code == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["data"]["stream"] == ["pointmaze-umaze-N[500]", "pointmaze-umaze-PA[500]"]
    assert printed["model"]["class_path"] == "hispo_pl.modules.HiSPO"


def _stream_method_pairs():
    """Every stream config with one method and every method config with one stream run by
    default (what differs: each file's own keys, each method's knobs on a stream); the rest of
    the matrix, every other pair, is ``slow``."""
    for stream in STREAM_CONFIGS:
        for method in METHOD_CONFIGS:
            default = stream == PAIR_STREAM or method == PAIR_METHOD
            marks = () if default else (pytest.mark.slow,)
            yield pytest.param(stream, method, id=f"{method.stem}-{stream.stem}", marks=marks)


PAIR_STREAM = ROOT / "configs/streams/pointmaze-1.yaml"
PAIR_METHOD = ROOT / "configs/methods/hispo.yaml"


@pytest.mark.parametrize(("stream", "method"), list(_stream_method_pairs()))
def test_every_stream_and_method_config_pair_parses(stream, method, capsys):
    with pytest.raises(SystemExit) as done:
        main(["fit", "--config", str(stream), "--config", str(method), "--print_config"])
    assert done.value.code == 0
    printed = capsys.readouterr().out
    model = yaml.safe_load(method.read_text())["model"]["class_path"]
    assert f"stream: {stream.stem}" in printed and f"class_path: {model}" in printed


def test_the_default_pairs_cover_every_stream_and_method_config():
    default = [
        p.values for p in _stream_method_pairs() if not any(m.name == "slow" for m in p.marks)
    ]
    assert {s for s, _ in default} == set(STREAM_CONFIGS) and PAIR_STREAM in STREAM_CONFIGS
    assert {m for _, m in default} == set(METHOD_CONFIGS) and PAIR_METHOD in METHOD_CONFIGS
    assert len(default) == len(STREAM_CONFIGS) + len(METHOD_CONFIGS) - 1


def test_dotted_override_shows_in_printed_config(capsys):
    with pytest.raises(SystemExit):
        main(["fit", "--config", str(CONFIGS[0]), "--trainer.max_steps", "123", "--print_config"])
    assert "max_steps: 123" in capsys.readouterr().out


def test_config_typo_is_rejected_with_its_name(capsys):
    assert main(["fit", "--config", str(CONFIGS[0]), "--trainer.max_stepz", "5"]) == 2
    assert "max_stepz" in capsys.readouterr().err


def test_malformed_task_in_config_shows_the_grammar(tmp_path, capsys):
    assert main(_fit_args(tmp_path, "--data.task", "pointmaze-umaz-PO[5]")) == 2
    err = capsys.readouterr().err
    assert "task spec grammar" in err and "Traceback" not in err


def test_data_generate_and_list(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert main(["data", "generate", "pointmaze-umaze", "--episodes", "2"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["id"] == "hispo/pointmaze-umaze-expert-v0"
    assert stats["episodes"] == 2 and stats["steps"] == 2 * 300
    assert "seed 0" in stats["description"]
    assert main(["data", "list"]) == 0
    assert '"id": "hispo/pointmaze-umaze-expert-v0"' in capsys.readouterr().out


def test_data_generate_rejects_unknown_maze(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert main(["data", "generate", "pointmaze-hexagon", "--episodes", "1"]) == 2
    assert "unknown maze" in capsys.readouterr().err


# --- the command's map and the shipped configs ---------------------------------------------


@pytest.mark.parametrize("argv", [[], ["--help"]])
def test_help_is_the_map_of_verbs(argv, capsys):
    from hispo_pl.cli import VERBS

    assert main(argv) == 0
    out = capsys.readouterr().out
    for verb in ("fit", "evaluate", "data", "render", "benchmark", "config"):
        assert verb in VERBS
        assert f"\n  {verb} " in out


@pytest.mark.parametrize("verb", ["validate", "test", "predict", "frobnicate"])
def test_verbs_that_do_not_exist_here_say_what_to_use(verb, capsys):
    assert main([verb]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert ("evaluate" in err) if verb != "frobnicate" else ("fit, evaluate" in err)


def test_config_list_show_and_copy(tmp_path, capsys):
    assert main(["config", "list"]) == 0
    names = capsys.readouterr().out.splitlines()[1:]
    shipped = sorted(
        p.relative_to(ROOT / "configs").with_suffix("").as_posix()
        for p in (ROOT / "configs").rglob("*.yaml")
    )
    assert names == shipped
    assert main(["config", "show", "pointmaze-1"]) == 0
    assert capsys.readouterr().out == (ROOT / "configs/streams/pointmaze-1.yaml").read_text()
    assert main(["config", "show", "pointmaze-umaze"]) == 2  # bc/ and hbc/ both have it
    assert "hbc/pointmaze-umaze" in capsys.readouterr().err
    assert main(["config", "copy", str(tmp_path / "mine")]) == 0
    copied = sorted(p.relative_to(tmp_path / "mine").as_posix() for p in tmp_path.rglob("*.yaml"))
    assert copied == sorted(f"{n}.yaml" for n in shipped)


def test_packaged_configs_are_found_outside_a_checkout(tmp_path, monkeypatch):
    from hispo_pl.config_files import config_names, config_root

    monkeypatch.chdir(tmp_path)  # no ./configs here: the package's own copy
    root = config_root()
    assert (root / "methods" / "hispo.yaml").is_file()
    assert "streams/pointmaze-1" in config_names(root)


def test_stream_help_names_every_stream(capsys):
    from hispo_pl.tasks import STREAMS

    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    help_text = out[out.index("--data.stream STREAM, ") :]
    for name in STREAMS:
        assert name in help_text[:800], name


def _instantiated(args: list[str]):
    from hispo_pl.fit import run_lightning_cli

    return run_lightning_cli(args, run=False)


def test_method_knobs_reach_their_callbacks(tmp_path):
    from hispo_pl.callbacks import DirichletEvaluation, RolloutEvaluation, SubspacePruning

    args = [
        "--config", str(ROOT / "configs/streams/pointmaze-1.yaml"),
        "--config", str(ROOT / "configs/methods/hispo.yaml"),
        "--trainer.logger.init_args.save_dir", str(tmp_path),
        "--eps_low", "0.25", "--search_candidates", "64", "--eval_episodes", "7",
        "--search_stored_points", "true",
    ]  # fmt: skip
    cli = _instantiated(args)
    by_type = {type(cb): cb for cb in cli.trainer.callbacks}
    assert by_type[SubspacePruning].eps == {"low": 0.25}  # the high one: the family's
    assert by_type[DirichletEvaluation].n_candidates == 64
    assert by_type[DirichletEvaluation].stored_points is True
    assert by_type[RolloutEvaluation].episodes == 7
    # the saved configuration holds the effective values, not the flags
    assert cli.config["eps_low"] is None
    assert cli.config["trainer"]["callbacks"][2]["init_args"]["eps_low"] == 0.25


def test_output_into_a_pipe_closed_early_is_not_an_error():
    """``hispo-pl config list | head -1``: the reader leaves, the command stays quiet."""
    source = "import sys\nfrom hispo_pl.cli import main\nsys.exit(main(['config', 'list']))"
    proc = subprocess.Popen(
        [sys.executable, "-c", source], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    proc.stdout.close()  # the reader is gone before anything is written
    err = proc.stderr.read()
    assert proc.wait(timeout=60) == 1
    assert "Traceback" not in err and "BrokenPipe" not in err, err


def test_a_knob_the_method_lacks_is_refused(capsys):
    args = [
        "fit",
        "--config", str(ROOT / "configs/streams/pointmaze-1.yaml"),
        "--config", str(ROOT / "configs/methods/scn.yaml"),
        "--eps_low", "0.2",
    ]  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "--eps_low: no callback of this method takes it" in err and "SubspacePruning" in err
    assert main([*args[:-2], "--search_stored_points", "true"]) == 2
    assert "--search_stored_points: no callback" in capsys.readouterr().err


def test_acting_on_another_task_than_the_policys_own_is_named(tmp_path):
    from hispo_pl.cli_verbs import other_task_note
    from hispo_pl.results import Progress
    from hispo_pl.rundir import RunDir
    from hispo_pl.tasks import parse_task

    ckpt = str(tmp_path / "task_02.ckpt")
    umaze, umaze_pa = parse_task("pointmaze-umaze[5]"), parse_task("pointmaze-umaze-PA")
    assert other_task_note(ckpt, 1, [umaze]) is None  # no stream run: nothing to compare with
    RunDir(tmp_path).write_progress(
        Progress(stream=["pointmaze-umaze-N[500]", "pointmaze-umaze-PA[500]"])
    )
    assert other_task_note(ckpt, 0, [umaze]) is None  # the same maze and variant, other episodes
    assert other_task_note(ckpt, 1, [umaze_pa]) is None
    note = other_task_note(ckpt, 1, [umaze_pa, umaze])
    assert "task 2 was trained on pointmaze-umaze-PA[500]" in note
    assert note.endswith("acting on pointmaze-umaze-N[5]")
    assert other_task_note(ckpt, 2, [umaze]) is None  # a task the stream does not have


def test_an_abbreviated_flag_is_a_typo_not_the_flag_it_starts(capsys):
    config = str(Path(__file__).parents[2] / "configs" / "hbc" / "pointmaze-umaze.yaml")
    assert main(["fit", "--config", config, "--trainer.max_step", "5"]) == 2
    assert "unknown flag --trainer.max_step;" in capsys.readouterr().err
