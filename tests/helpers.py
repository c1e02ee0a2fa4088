"""Shared test helpers (imported as ``helpers``: pytest puts this folder on ``sys.path``)."""

from __future__ import annotations

import json
from pathlib import Path

import lightning as L


def quiet_trainer(max_steps: int, **kwargs) -> L.Trainer:
    """A short CPU Trainer that writes nothing and prints nothing unless ``kwargs`` say so."""
    options = {
        "accelerator": "cpu",
        "logger": False,
        "enable_checkpointing": False,
        "enable_progress_bar": False,
        "enable_model_summary": False,
    }
    return L.Trainer(max_steps=max_steps, **{**options, **kwargs})


ROOT = Path(__file__).resolve().parents[1]
TINY_STREAM = ["pointmaze-umaze-N[3]", "pointmaze-umaze-PO[3]"]


def tiny_stream_args(
    method_config: str | Path, save_dir: Path, stream: list[str] = TINY_STREAM, *extra: str
) -> list[str]:
    """``hispo-pl fit`` arguments for a stream of tiny tasks (the ``tiny_umaze`` data): 5 steps
    of batch 64 per task, 2 evaluation episodes, logs under ``save_dir``. ``method_config`` is
    a method name of ``configs/methods`` or a path to a YAML file."""
    config = Path(method_config)
    if not config.suffix:
        config = ROOT / "configs" / "methods" / f"{method_config}.yaml"
    return [
        "fit",
        "--config",
        str(ROOT / "configs/streams/pointmaze-1.yaml"),
        "--config",
        str(config),
        "--data.stream",
        json.dumps(stream),
        "--trainer.max_steps",
        "5",
        "--data.batch_size",
        "64",
        "--trainer.logger.init_args.save_dir",
        str(save_dir),
        "--trainer.callbacks.init_args.episodes",  # the last callback: RolloutEvaluation
        "2",
        "--trainer.enable_progress_bar",
        "false",
        *extra,
    ]


def fit_tiny_stream(
    method_config: str | Path, save_dir: Path, stream: list[str] = TINY_STREAM, *extra: str
) -> tuple[dict, Path]:
    """Run :func:`tiny_stream_args` through ``hispo-pl fit``; its results and run dir."""
    from hispo_pl.cli import main

    assert main(tiny_stream_args(method_config, save_dir, stream, *extra)) == 0
    run_dir = save_dir / "pointmaze-1" / "seed0"  # a stream's version defaults to seed<seed>
    return json.loads((run_dir / "results.json").read_text()), run_dir


class DirlessLogger(L.pytorch.loggers.Logger):
    """A logger without a run directory (``log_dir``), as MLflow's or W&B's: it keeps what it
    receives in ``DirlessLogger.received`` (class-level, since the CLI builds the instance)."""

    received: list[tuple[dict, int | None]] = []

    @property
    def name(self) -> str:
        return "dirless"

    @property
    def version(self) -> str:
        return "0"

    @property
    def save_dir(self) -> str:  # where such a logger keeps its own files (./mlruns for MLflow)
        return "dirless-logs"

    def log_metrics(self, metrics: dict, step: int | None = None) -> None:
        DirlessLogger.received.append((dict(metrics), step))

    def log_hyperparams(self, params, *args, **kwargs) -> None:
        pass
