"""Callbacks of the per-task-network baselines (SC1, SCN, FT1, FTN, FRZ, L2, EWC): make each
task's network at task start, record which network a finished task acts with, and fold a
finished task's weights into the L2 / EWC penalty."""

from __future__ import annotations

from typing import Literal

import lightning as L
from typing_extensions import override

from ..modules.columns import GrowingPolicy
from ..modules.regularized import ConsolidatingPolicy
from .protocols import require
from .state import KeyedState


def _require_growing_policy(pl_module: L.LightningModule, who: str) -> GrowingPolicy:
    needs = "a module that makes a network per task"
    return require(pl_module, GrowingPolicy, who, needs, "NetworkPerTask")


def trains_on(task: int, train: Literal["all", "first"]) -> bool:
    """Whether a method trains on task ``task`` (0-based): FRZ trains on the first only."""
    return train == "all" or task == 0


class TaskNetworks(KeyedState):
    """At task start (before the optimiser exists) the module makes the task's network; at
    task end it records the network the task acts with.

    Args:
        train: ``all`` tasks, or only the ``first`` (FRZ: later tasks are not trained at all;
            their fit ends before the first step and goes straight to the evaluation).
    """

    # the arguments that tell two instances apart: its checkpoint entry's key
    state_args = ("train",)

    def __init__(self, train: Literal["all", "first"] = "all"):
        if train not in ("all", "first"):
            raise ValueError(f"train must be 'all' or 'first', got {train!r}")
        self.train = train

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        module = _require_growing_policy(pl_module, type(self).__name__)
        if stage != "fit":
            return
        if trains_on(module.task_index, self.train):
            module.start_task(module.task_index)
        else:
            module.freeze_all()

    @override
    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not trains_on(pl_module.task_index, self.train):
            trainer.should_stop = True  # no gradient step on this task

    @override
    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        pl_module.finish_task(pl_module.task_index)


class WeightConsolidation(KeyedState):
    """At a task's end, the module folds the task's weights into its penalty (L2, EWC); EWC's
    empirical Fisher is measured on ``fisher_batches`` fresh batches of the task.

    Args:
        fisher_batches: batches of the finished task the Fisher is averaged over (EWC only).
        batch_size: samples per batch (per-sample gradients are taken in chunks of 256).
        seed: seeds those batches.
    """

    # the arguments that tell two instances apart: its checkpoint entry's key
    state_args = ("fisher_batches", "batch_size", "seed")

    def __init__(self, fisher_batches: int = 16, batch_size: int = 256, seed: int = 0):
        if fisher_batches < 1:
            raise ValueError(f"fisher_batches must be >= 1, got {fisher_batches}")
        self.fisher_batches, self.batch_size, self.seed = fisher_batches, batch_size, seed

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        needs, example = "a module with a weight penalty", "RegularizedFineTuning"
        require(pl_module, ConsolidatingPolicy, type(self).__name__, needs, example)

    @override
    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        batches = []
        if pl_module.needs_fisher:
            batches = trainer.datamodule.fixed_batches(
                self.fisher_batches, self.seed, self.batch_size, pl_module.device, split="train"
            )
        pl_module.consolidate(batches)
