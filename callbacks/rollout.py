"""Periodic rollout evaluation of the policy being trained."""

from __future__ import annotations

import lightning as L
from typing_extensions import override

from ..evaluation import RolloutEvaluator, module_policy


class RolloutEvaluation(L.Callback):
    """Evaluates the policy on the current task every ``eval_every`` steps and at train end.

    Logs ``eval/success`` and ``eval/episode_length`` at the global step; the last result is
    kept in ``last`` for whoever drives the run (the CLI prints it).

    Args:
        eval_every: steps between evaluations (0: only at the end of training).
        episodes: seeded evaluation episodes (random distinct start and goal cells).
        seed: evaluation seed (fixes start/goal cells and reset noise).
        progress: show a progress bar per evaluation.
    """

    def __init__(
        self, eval_every: int = 0, episodes: int = 100, seed: int = 0, progress: bool = False
    ):
        self.eval_every, self.episodes, self.seed, self.progress = (
            eval_every,
            episodes,
            seed,
            progress,
        )
        self._evaluator: RolloutEvaluator | None = None
        self.last: dict[str, float] | None = None

    def _evaluate(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        task = trainer.datamodule.task
        if self._evaluator is None or self._evaluator.task != task:
            self._evaluator = RolloutEvaluator(task, self.episodes, self.seed)
        result = self._evaluator.run(module_policy(pl_module), progress=self.progress)
        self.last = {
            "success": result.success,
            "episode_length": result.episode_length,
            "step": trainer.global_step,
        }
        if trainer.logger is not None:
            trainer.logger.log_metrics(
                {"eval/success": result.success, "eval/episode_length": result.episode_length},
                step=trainer.global_step,
            )

    @override
    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        step = trainer.global_step
        if self.eval_every > 0 and step % self.eval_every == 0 and step < (trainer.max_steps or 0):
            self._evaluate(trainer, pl_module)

    @override
    def on_train_end(self, trainer, pl_module) -> None:
        self._evaluate(trainer, pl_module)
