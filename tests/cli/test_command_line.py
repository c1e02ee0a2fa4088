"""The command line's spellings and one-line errors: the thread count under one name (and
its other spelling) in every verb, and a configured class that cannot be made (a logger whose
package is not installed) said in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from lightning.pytorch.loggers import Logger

from hispo_pl.cli import main
from hispo_pl.cli_errors import class_key, class_problem_line

ROOT = Path(__file__).resolve().parents[2]
HBC = str(ROOT / "configs/hbc/pointmaze-umaze.yaml")


@pytest.mark.parametrize("flag", ["--num_threads", "--num-threads"])
@pytest.mark.parametrize(
    "argv",
    [
        ["evaluate", "--ckpt", "no.ckpt", "--task", "pointmaze-umaze"],
        ["render", "pointmaze-umaze", "--out", "x.png", "--episodes", "0"],
    ],
    ids=["evaluate", "render"],
)
def test_evaluate_and_render_take_both_spellings_of_the_thread_count(argv, flag, monkeypatch):
    import hispo_pl.cli_verbs

    asked: list[int] = []
    monkeypatch.setattr(hispo_pl.cli_verbs, "set_num_threads", asked.append)
    assert main([*argv, flag, "3"]) == 2  # no such checkpoint / no episodes: after the threads
    assert asked == [3]


@pytest.mark.parametrize("flag", ["--num_threads", "--num-threads"])
def test_benchmark_and_fit_take_both_spellings_of_the_thread_count(flag, capsys):
    from hispo_pl.benchmark import build_parser

    args = build_parser().parse_args(["--stream", "pointmaze-1", "--out", "o", flag, "3"])
    assert args.num_threads == 3
    with pytest.raises(SystemExit) as stopped:
        main(["fit", "--config", HBC, flag, "3", "--print_config"])
    assert stopped.value.code in (0, None)
    assert "\nnum_threads: 3\n" in capsys.readouterr().out


def test_every_verbs_help_names_the_thread_count_the_same_way(capsys):
    for verb in ("evaluate", "render", "benchmark"):
        with pytest.raises(SystemExit):
            main([verb, "--help"])
        assert "--num_threads NUM_THREADS, --num-threads NUM_THREADS" in capsys.readouterr().out


MLFLOW_MESSAGE = """Does not validate against any of the Union subtypes
Subtypes: [<class 'lightning.pytorch.loggers.logger.Logger'>, <class 'bool'>]
Errors:
  - Problem with given class_path 'lightning.pytorch.loggers.MLFlowLogger':
      Requirement 'mlflow>=1.0.0' not met. HINT: Try running `pip install -U 'mlflow>=1.0.0'`
  - Expected a <class 'bool'>
Given value type: <class 'jsonargparse._namespace.Namespace'>"""


def test_a_class_that_cannot_be_made_is_one_line():
    config = {
        "trainer": {
            "logger": {"class_path": "lightning.pytorch.loggers.MLFlowLogger"},
            "callbacks": [{"class_path": "a.Callback"}],
        }
    }
    assert class_problem_line(MLFLOW_MESSAGE, config) == (
        "--trainer.logger lightning.pytorch.loggers.MLFlowLogger cannot be made: Requirement "
        "'mlflow>=1.0.0' not met. HINT: Try running `pip install -U 'mlflow>=1.0.0'`"
    )
    assert class_key(config, "a.Callback") == "trainer.callbacks"
    assert class_problem_line("something else", config) is None


class LoggerOfAMissingPackage(Logger):
    """A logger whose package is not installed, as Lightning's MLFlowLogger without mlflow."""

    def __init__(self, save_dir: str = "runs"):
        raise ModuleNotFoundError("Requirement 'somelogger>=1.0' not met. HINT: pip install it")

    name = version = "never made"

    def log_hyperparams(self, params, *args, **kwargs) -> None: ...

    def log_metrics(self, metrics, step=None) -> None: ...


def test_a_logger_whose_package_is_missing_stops_fit_in_one_line(tmp_path, capsys):
    logger = {"class_path": f"{__name__}.LoggerOfAMissingPackage"}
    argv = ["fit", "--config", HBC, "--trainer.logger", json.dumps(logger)]
    assert main([*argv, "--trainer.default_root_dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"hispo-pl: error: --trainer.logger {__name__}.LoggerOfAMissingPackage cannot be "
        "made: Requirement 'somelogger>=1.0' not met. HINT: pip install it"
    )
