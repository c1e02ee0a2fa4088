"""Long end-to-end checks (``pytest -m slow``): real data, real training, real success."""

from __future__ import annotations

from pathlib import Path

import pytest

from hispo_pl.cli import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_hbc_learns_the_umaze_from_generated_expert_data(monkeypatch, tmp_path, capsys):
    """The quickstart, shortened: 500 generated expert episodes, 2500 steps, 100 episodes."""
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    main(
        [
            "fit",
            "--config",
            str(ROOT / "configs/quickstart.yaml"),
            "--trainer.max_steps",
            "2500",
            "--trainer.callbacks.init_args.eval_every",
            "0",
            "--trainer.logger.init_args.save_dir",
            str(tmp_path / "runs"),
            "--trainer.enable_progress_bar",
            "false",
        ]
    )
    line = next(x for x in capsys.readouterr().out.splitlines() if "success" in x)
    success = float(line.split("success ")[1].split("%")[0])
    assert success >= 90.0, line
