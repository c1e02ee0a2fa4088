"""``--preset paper``: a run configured as the paper specifies its methods, whatever the
method and stream configs say, and kept on resume like any other setting."""

from __future__ import annotations

import yaml
from helpers import TINY_STREAM, fit_tiny_stream, tiny_stream_args

from hispo_pl.cli import main
from hispo_pl.methods import method_spec
from hispo_pl.modules import HiSPO
from hispo_pl.presets import PAPER_COMMON, apply_preset


def _get(config: dict, key: str):
    for part in key.split("."):
        config = config[part]
    return config


def _callback(config: dict, name: str) -> dict:
    (callback,) = [c for c in config["trainer"]["callbacks"] if c["class_path"].endswith(name)]
    return callback["init_args"]


def test_a_hispo_stream_runs_with_the_paper_preset(tiny_umaze, tmp_path):
    results, run_dir = fit_tiny_stream("hispo", tmp_path, TINY_STREAM, "--preset", "paper")
    assert len(results["R"]) == 2
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    for key, value in PAPER_COMMON:
        assert _get(config, key) == value, key
    backbone = config["model"]["init_args"]["backbone"]
    assert (backbone["high_hidden"], backbone["low_hidden"]) == (64, 256)  # PointMaze
    assert config["model"]["init_args"]["anchor_init"] == "random"
    for callback, settings in method_spec(HiSPO).paper.callbacks.items():
        assert settings.items() <= _callback(config, callback.__name__).items()


def test_the_paper_widens_hispo_only_on_antmaze_and_the_game_mazes():
    def widths(method: str, stream: str) -> tuple[int, int, int]:
        config = {
            "model": {"class_path": f"hispo_pl.modules.{method}", "init_args": {}},
            "data": {"stream": stream},
            "trainer": {"callbacks": []},
        }
        apply_preset(config, "paper")
        backbone = config["model"]["init_args"]["backbone"]
        return backbone["high_hidden"], backbone["low_hidden"], config["data"]["batch_size"]

    assert widths("HiSPO", "antmaze-1") == (70, 300, 1024)
    assert widths("HiSPO", "videogame-1") == (70, 300, 64)
    assert widths("HiSPO", "pointmaze-2") == (64, 256, 1024)
    assert widths("NetworkPerTask", "antmaze-1") == (64, 256, 1024)
    assert widths("CSPO", "antmaze-1") == (64, 256, 1024)  # a subclass with its own entry


def test_an_unknown_preset_is_one_line(tmp_path, capsys):
    assert (
        main(tiny_stream_args("scn", tmp_path, ["pointmaze-umaze-N[3]"], "--preset", "papr")) == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--preset papr: unknown preset; the presets are paper" in err[0]
