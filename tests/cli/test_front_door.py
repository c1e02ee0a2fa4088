"""What a new user meets first: progress that shows every long step the same way, a command
line that answers a mistake in one line, the README's commands and the acting example as
written, and an installed package that finds its own configs."""

from __future__ import annotations

import doctest
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from helpers import TINY_STREAM, checkpoint_of, tiny_stream_args

from hispo_pl.cli import main

ROOT = Path(__file__).resolve().parents[2]
HISPO = ROOT / "configs/methods/hispo.yaml"
STREAM = ROOT / "configs/streams/pointmaze-1.yaml"
STEP_LINE = re.compile(r"^\[hispo-pl\] (.+): (\d+)/(\d+) (\w+) \((\d+) %\), \S+$")


def _progress_lines(text: str, label: str) -> list[tuple[int, int]]:
    """(done, total) of each progress line of ``label`` in ``text``."""
    found = []
    for line in text.splitlines():
        m = STEP_LINE.match(line)
        if m and m.group(1) == label:
            found.append((int(m.group(2)), int(m.group(3))))
    return found


# --- one progress policy ---------------------------------------------------------------------


def test_progress_in_a_pipe_is_a_line_every_tenth():
    import io

    from hispo_pl.progress import ProgressPrinter, tenth_marks

    assert tenth_marks(100) == list(range(10, 101, 10))
    assert tenth_marks(4) == [1, 2, 3, 4] and tenth_marks(0) == []
    out = io.StringIO()
    with ProgressPrinter("eval x", 95, "episodes", bar=False, file=out) as done:
        for _ in range(95):
            done.update()
    lines = _progress_lines(out.getvalue(), "eval x")
    assert [d for d, _ in lines] == tenth_marks(95) and len(lines) == 10
    assert "\r" not in out.getvalue()
    quiet = io.StringIO()
    with ProgressPrinter("eval x", 5, enabled=False, bar=False, file=quiet) as done:
        done.update(5)
    assert quiet.getvalue() == ""


def test_data_generate_into_a_pipe_prints_lines_not_carriage_returns(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert main(["data", "generate", "pointmaze-umaze", "--episodes", "20"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["episodes"] == 20  # stdout keeps the result alone
    assert "\r" not in captured.err
    lines = _progress_lines(captured.err, "collecting pointmaze-umaze")
    assert [d for d, _ in lines] == list(range(2, 21, 2))


def test_evaluate_into_a_pipe_prints_lines_not_carriage_returns(tmp_path, capsys):
    from hispo_pl.config import BackboneConfig
    from hispo_pl.modules import HBC

    module = HBC(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16))
    checkpoint = checkpoint_of(module)
    path = tmp_path / "task_01.ckpt"
    torch.save(checkpoint, path)
    args = ["evaluate", "--ckpt", str(path), "--task", "pointmaze-umaze", "--episodes", "3"]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "\r" not in captured.err + captured.out
    assert _progress_lines(captured.err, "eval pointmaze-umaze-N[500]") == [(1, 3), (2, 3), (3, 3)]


def test_a_streams_task_end_evaluation_and_search_show_their_progress(tiny_umaze, tmp_path, capsys):
    args = tiny_stream_args("hispo", tmp_path, TINY_STREAM, "--trainer.enable_progress_bar", "true")
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "\r" not in captured.out + captured.err
    evaluating = _progress_lines(captured.err, "task 2/2: evaluating 2 tasks")
    assert evaluating[-1] == (4, 4)  # 2 tasks x 2 episodes, in one count
    searching = _progress_lines(captured.err, "task 2: searching high, low")
    assert searching and searching[-1][0] == searching[-1][1]
    assert "Epoch 0" not in captured.out + captured.err  # no Lightning bar in a pipe


def test_on_a_terminal_the_task_end_evaluation_and_search_draw_a_bar(
    tiny_umaze, tmp_path, capsys, monkeypatch
):
    """On a terminal the work at a task's end is a bar that moves, not a silent wait."""
    import hispo_pl.progress

    monkeypatch.setattr(hispo_pl.progress, "interactive", lambda: True)
    args = tiny_stream_args("hispo", tmp_path, TINY_STREAM)
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "\r" in err  # bars redrawn in place (tqdm's, at most ten times a second)
    assert re.search(r"task 2/2: evaluating 2 tasks: +\d+%\|[^|]*\| \d/4 ", err), err[-3000:]
    moved = re.findall(r"task 2: searching high, low: +(\d+)%\|", err)
    assert moved and max(map(int, moved)) > 0, err[-3000:]


@pytest.mark.e2e
def test_a_stream_with_a_from_scratch_reference_records_fwt(tiny_umaze, tmp_path, capsys):
    assert main(tiny_stream_args("scn", tmp_path / "scn")) == 0
    scratch = tmp_path / "scn" / "pointmaze-1" / "seed0" / "results.json"
    assert "FWT" not in json.loads(scratch.read_text())  # no reference: no FWT
    args = tiny_stream_args("hispo", tmp_path / "hispo", TINY_STREAM)
    assert main([*args, "--scratch_results", str(scratch)]) == 0
    results = json.loads(
        (tmp_path / "hispo" / "pointmaze-1" / "seed0" / "results.json").read_text()
    )
    diagonal = [json.loads(scratch.read_text())["R"][k][k] for k in range(2)]
    expected = sum(results["R"][k][k] - diagonal[k] for k in range(2)) / 2
    assert results["FWT"] == pytest.approx(expected)
    assert "FWT" in capsys.readouterr().out


def test_a_plain_lightning_module_is_refused_in_one_line(capsys):
    boring = "lightning.pytorch.demos.boring_classes.BoringModel"
    args = ["fit", "--config", str(STREAM), "--config", str(HISPO), "--model.class_path", boring]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usage:" not in err
    assert f"{boring} is not a hispo-pl method" in err and "GoalConditionedBC" in err


def test_gymnasium_robotics_adroit_notice_is_not_printed():
    """The notice gymnasium-robotics prints on import (about hands no task uses) stays out of
    every command's output, warnings shown."""
    code = "from hispo_pl.envs import make_env; make_env('pointmaze-umaze').close()"
    done = subprocess.run(
        [sys.executable, "-W", "default", "-c", code], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "Adroit" not in done.stdout + done.stderr


def test_a_single_task_fit_into_a_pipe_has_step_lines_and_no_bar(tiny_umaze, tmp_path, capsys):
    args = [
        "fit",
        "--config", str(ROOT / "configs/hbc/pointmaze-umaze.yaml"),
        "--data.task", "pointmaze-umaze-N[6]",
        "--data.batch_size", "64",
        "--trainer.max_steps", "10",
        "--trainer.logger.init_args.save_dir", str(tmp_path),
        "--trainer.callbacks.init_args.episodes", "2",
    ]  # fmt: skip
    assert main(args) == 0
    captured = capsys.readouterr()
    both = captured.out + captured.err
    assert "\r" not in both and "Epoch 0" not in both
    assert "pointmaze-umaze-N[6] step 10/10 (100 %)" in captured.err
    assert _progress_lines(captured.err, "eval pointmaze-umaze-N[6]")[-1] == (2, 2)


def test_lightnings_tips_are_silenced_and_its_notices_kept(caplog):
    import logging

    from lightning.pytorch.utilities.rank_zero import rank_zero_info

    from hispo_pl.cli import _quiet_known_warnings

    _quiet_known_warnings()
    with caplog.at_level(logging.INFO):
        rank_zero_info("💡 Tip: For seamless cloud logging, try installing [litlogger]")
        rank_zero_info("GPU available: False, used: False")
    messages = [r.getMessage() for r in caplog.records]
    assert "GPU available: False, used: False" in messages
    assert not any("Tip" in m for m in messages)


def test_the_bar_over_a_tasks_steps_does_not_show_the_logger_version():
    from types import SimpleNamespace

    from hispo_pl.console import TaskProgressBar

    class Trainer:
        progress_bar_metrics: dict = {"loss": 0.5}
        loggers: list = [SimpleNamespace(version="seed0")]

    bar = TaskProgressBar("task 1/2")
    metrics = bar.get_metrics(Trainer(), None)
    assert metrics == {"loss": 0.5}  # Lightning's own adds v_num: seed0


# --- the command line --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "flag, suggestion",
    [
        ("--trainer.max_stepz", "--trainer.max_steps"),
        ("--data.batchsize", "--data.batch_size"),
        ("--eps_lo", "--eps_low"),
        ("--model.init_args.optim.lrr", "--model.init_args.optim.lr"),
        ("--trainer.callbacks.init_args.episode", "--trainer.callbacks.init_args.episodes"),
    ],
)
def test_an_unknown_flag_is_one_line_with_the_closest_one(flag, suggestion, capsys):
    args = ["fit", "--config", str(STREAM), "--config", str(HISPO), flag, "3"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usage:" not in err, err
    assert f"unknown flag {flag}; did you mean {suggestion}?" in err


def test_print_config_refuses_an_unknown_flag_as_a_run_does(capsys):
    args = ["fit", "--config", str(ROOT / "configs/quickstart.yaml"), "--trainer.max_step", "5"]
    assert main([*args, "--print_config"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1, err
    assert "unknown flag --trainer.max_step; did you mean --trainer.max_steps?" in err


@pytest.mark.parametrize(
    "argv",
    [
        ["evaluate", "--ckpt", "no.ckpt", "--task", "pointmaze-umaze"],
        ["render", "pointmaze-umaze", "--out", "x.png", "--episodes", "0"],
    ],
    ids=["evaluate", "render"],
)
def test_evaluate_and_render_use_one_thread_unless_told(argv, monkeypatch):
    """As fit's configs: one torch thread by default, set before anything else is checked."""
    import hispo_pl.cli_verbs

    asked: list[int] = []
    monkeypatch.setattr(hispo_pl.cli_verbs, "set_num_threads", asked.append)
    assert main(argv) == 2 and main([*argv, "--num_threads", "0"]) == 2
    assert asked == [1, 0]


@pytest.mark.parametrize("dest", ["my.yaml", "my.yml"])
def test_config_copy_refuses_a_destination_named_like_a_file(dest, tmp_path, capsys):
    """``config copy my.yaml`` would make a folder of configs named my.yaml."""
    target = tmp_path / dest
    assert main(["config", "copy", str(target)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{target} names a file; config copy fills a folder" in err
    assert not target.exists()


def test_a_config_that_says_make_demo_runs_it_is_the_demo():
    """A config's header names the command ``make demo`` runs only where it is that command."""
    recipe = (ROOT / "Makefile").read_text().split("\ndemo:", 1)[1]
    demo = re.search(r"hispo-pl (fit .*)", recipe).group(1).strip()
    claim = re.compile(r"^#\s+hispo-pl (fit .*?)\s+\((?:what `make demo` runs|make demo)\)$")
    claimed = [
        m.group(1)
        for path in sorted((ROOT / "configs").rglob("*.yaml"))
        for line in path.read_text().splitlines()
        if (m := claim.match(line))
    ]
    assert claimed == [demo]


@pytest.mark.parametrize(
    "argv, said",
    [
        (["evaluate", "--ckp", "x.ckpt", "--task", "pointmaze-umaze"], "did you mean --ckpt?"),
        (["evaluate", "--taskk", "pointmaze-umaze"], "did you mean --task?"),
        (["data", "generate", "pointmaze-umaze", "--epi", "3"], "did you mean --episodes?"),
        (["render", "amazeville", "--ouut", "x.png"], "did you mean --out?"),
        (["benchmark", "--strea", "pointmaze-1", "--out", "o", "--dry-run"], "--stream?"),
        (["config", "copy", "d", "--forse"], "unknown flag --forse"),
        (["evaluate", "--ckpt", "x.ckpt"], "required: --task (hispo-pl evaluate --help)"),
    ],
    ids=["abbreviation", "typo", "data", "render", "benchmark", "config", "missing"],
)
def test_every_verb_answers_a_bad_flag_in_one_line(argv, said, capsys):
    """No verb takes an abbreviation for a flag, and none answers a bad command line with its
    usage: one line, the closest flag where there is one."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usage:" not in err, err
    assert said in err and err.startswith(f"hispo-pl {argv[0]}"), err


def test_a_missing_config_file_says_how_to_get_the_shipped_ones(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # outside a checkout: no configs/ here
    assert main(["fit", "--config", "configs/demo.yaml", "--config", "methods/hispo.yaml"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usage:" not in err
    assert "--config configs/demo.yaml: a shipped config" in err
    assert "hispo-pl config copy configs" in err


@pytest.mark.parametrize(
    "extra, said",
    [
        (["--optimizer", "SGD"], "--optimizer: hispo-pl methods build their optimiser from optim:"),
        (
            ["--lr_scheduler.class_path", "torch.optim.lr_scheduler.ConstantLR"],
            "--lr_scheduler: hispo-pl methods build their optimiser from optim:",
        ),
    ],
)
def test_lightnings_optimizer_flags_are_refused_for_optim(extra, said, capsys):
    assert main(["fit", "--config", str(STREAM), "--config", str(HISPO), *extra]) == 2
    err = capsys.readouterr().err
    assert said in err and "--model.init_args.optim.lr" in err
    assert err.strip().count("\n") <= 1 and "Traceback" not in err  # at most Lightning's seed


def test_a_checkpoint_callback_in_a_stream_is_refused_with_the_reason(capsys):
    args = ["fit", "--config", str(STREAM), "--config", str(HISPO)]
    assert main([*args, "--trainer.callbacks+=ModelCheckpoint"]) == 2
    err = capsys.readouterr().err
    assert "ModelCheckpoint has no effect in a stream" in err and "task_XX.ckpt" in err


def test_a_checkpoint_callback_of_a_single_task_is_kept():
    from lightning.pytorch.callbacks import ModelCheckpoint

    from hispo_pl.fit import run_lightning_cli

    config = str(ROOT / "configs/hbc/pointmaze-umaze.yaml")
    cli = run_lightning_cli(["--config", config, "--trainer.callbacks+=ModelCheckpoint"], run=False)
    assert any(type(cb) is ModelCheckpoint for cb in cli.trainer.callbacks)


def test_the_benchmark_finds_the_packaged_configs_outside_a_checkout(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    args = ["benchmark", "--stream", "pointmaze-1", "--methods", "hispo", "--seeds", "1"]
    assert main([*args, "--out", str(tmp_path / "out"), "--dry-run"]) == 0
    assert "hispo/seed0 (to run)" in capsys.readouterr().out


# --- the package and the README ---------------------------------------------------------------


def test_the_extras_hold_what_their_commands_need():
    text = (ROOT / "pyproject.toml").read_text()

    def extra(name: str) -> set[str]:
        line = re.search(rf"(?m)^{name} = \[(.*)\]", text).group(1)
        return {re.split(r"[<>=\[ ]", d.strip().strip('"'))[0] for d in line.split(",")}

    assert "minari" in extra("create") and "minari[create]" in text  # minari.DataCollector
    assert "nbconvert" in extra("notebook")  # jupyter nbconvert --execute of the notebook
    assert "ray" not in extra("dev") and "ray" in extra("ray")  # its one test is skipped


def test_the_readme_activates_the_venv_before_its_first_bare_command():
    text = (ROOT / "README.md").read_text()
    activate = text.find(". .venv/bin/activate")
    bare = re.search(r"(?m)(^|`)(hispo-pl|tensorboard) ", text)
    assert activate != -1 and bare is not None and activate < bare.start()
    using = text[text.index("## Using it") :]
    block = re.search(r"```bash\n(.*?)```", using, flags=re.S).group(1)
    assert block.splitlines()[0].startswith(". .venv/bin/activate")


def test_the_readme_says_when_results_json_holds_fwt():
    text = " ".join((ROOT / "README.md").read_text().split())
    claims = [s for s in re.split(r"(?<=\))\. |; ", text) if "`results.json`" in s and "FWT" in s]
    assert claims and all("--scratch_results" in c or "benchmark" in c for c in claims)
    (demo,) = (ROOT / "docs/results/demo").rglob("results.json")
    assert "FWT" not in json.loads(demo.read_text())  # no from-scratch reference: no FWT


def test_make_says_what_it_installs_before_each_pip_step():
    recipe = (ROOT / "Makefile").read_text().splitlines()
    for i, line in enumerate(recipe):
        if "pip install" in line:
            assert recipe[i - 1].strip().startswith("@echo"), line


def test_the_acting_example_runs_as_written(tmp_path, monkeypatch):
    from hispo_pl.config import BackboneConfig
    from hispo_pl.modules import GoalConditionedBC, HiSPO

    # a PointMaze-like policy: its low level reads the goal-space velocity
    module = HiSPO(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16, low_velocity=True))
    module.task_index = 1
    checkpoint = checkpoint_of(module)
    run = tmp_path / "runs/demo/seed0"
    run.mkdir(parents=True)
    torch.save(checkpoint, run / "task_02.ckpt")
    monkeypatch.chdir(tmp_path)
    finder, runner = doctest.DocTestFinder(), doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    (test,) = finder.find(GoalConditionedBC.act, "act", globs={})
    runner.run(test, out=sys.stdout.write)
    assert runner.summarize(verbose=False) == (0, len(test.examples)) and test.examples
    with pytest.raises(ValueError, match="pass velocity="):  # why the example passes it
        obs, pos, goal = torch.zeros(1, 4), torch.zeros(1, 2), torch.ones(1, 2)
        GoalConditionedBC.from_checkpoint_file(str(run / "task_02.ckpt")).act(obs, pos, goal)


def test_the_readmes_test_command_is_the_makefiles():
    """The README names the pytest command `make test` runs, with its default workers."""
    makefile = (ROOT / "Makefile").read_text()
    workers = re.search(r"^TEST_WORKERS \?= (\d+)", makefile, re.M).group(1)
    recipe = re.search(r"^test: .*\n\t\$\(BIN\)/python -m (pytest[^\n]*)", makefile, re.M).group(1)
    command = recipe.replace("$(TEST_WORKERS)", workers)
    assert f"`{command}`" in (ROOT / "README.md").read_text()
