"""Gradient steps per second through a Lightning Trainer, what ``hispo-pl fit`` runs: shared by
``throughput.py`` and ``step_speed.py`` (not a script of its own)."""

from __future__ import annotations

import time

import lightning as L

from hispo_pl.data.datamodule import TaskDataModule


class StepTimer(L.Callback):
    """Times the steps after the first ``warmup``, so the Trainer's start-up is not counted."""

    def __init__(self, warmup: int):
        self.warmup, self.start, self.end = warmup, 0.0, 0.0

    def on_train_batch_start(self, trainer, *args) -> None:
        if trainer.global_step == self.warmup:
            self.start = time.perf_counter()

    def on_train_batch_end(self, trainer, *args) -> None:
        self.end = time.perf_counter()


def trainer_steps_per_s(model, task: str, steps: int, warmup: int, logger=False) -> float:
    """Steps/s of ``model`` trained on ``task`` by a CPU Trainer: ``steps`` timed after
    ``warmup`` untimed ones, no progress bar, checkpoint or summary."""
    timer = StepTimer(warmup)
    trainer = L.Trainer(
        callbacks=[timer],
        max_steps=warmup + steps,
        max_epochs=-1,
        logger=logger,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        accelerator="cpu",
    )
    trainer.fit(model, TaskDataModule(task, steps_per_epoch=warmup + steps))
    return steps / (timer.end - timer.start)
