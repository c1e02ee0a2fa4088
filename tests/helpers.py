"""Shared test helpers (imported as ``helpers``: pytest puts this folder on ``sys.path``)."""

from __future__ import annotations

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
