"""Rollout evaluation of the policy being trained: periodic on the current task, and at the end
of a task on every task of the stream (one row of the success matrix R)."""

from __future__ import annotations

import lightning as L
from typing_extensions import override

from ..evaluation import RolloutEvaluator, RolloutResult, module_policy
from ..nn import eval_mode
from ..progress import ProgressPrinter
from ..rundir import task_label
from ..tasks import Task, parse_task
from .state import KeyedState


class RolloutEvaluation(KeyedState):
    """Evaluates the policy with deterministic, seeded rollouts.

    - every ``eval_every`` steps on the current task, logged as ``eval/success`` in % (single task)
      or ``task_XX/eval/success`` (in a stream) at the global step;
    - at the end of training on the current task, or, when the datamodule belongs to a stream,
      on every task of the stream. That row goes to the module's ``task_record.success_row``
      for the ContinualLoop, which logs it (``stream/success/T01``... at step = tasks trained).

    The latest evaluation of the current task goes to ``task_record.evaluation`` (the CLI
    prints it).

    Environments are built once per task and reused for the whole run.

    Args:
        eval_every: steps between evaluations on the current task (0: only at the end).
        episodes: seeded evaluation episodes (random distinct start and goal cells).
        seed: evaluation seed (fixes start/goal cells and reset noise).
        progress: also show the progress of each periodic evaluation; the one at a task's
            end always shows (:mod:`hispo_pl.progress`: a bar, or a line every tenth).
    """

    # the arguments that tell two instances apart: its checkpoint entry's key
    state_args = ("eval_every", "episodes", "seed")

    def __init__(
        self, eval_every: int = 0, episodes: int = 100, seed: int = 0, progress: bool = False
    ):
        self.eval_every, self.episodes, self.seed, self.progress = (
            eval_every,
            episodes,
            seed,
            progress,
        )
        self._evaluators: dict[Task, RolloutEvaluator] = {}

    def _run(
        self,
        task: str | Task,
        pl_module: L.LightningModule,
        task_index: int | None,
        record: bool = False,
        progress: bool | ProgressPrinter = False,
    ) -> RolloutResult:
        task = parse_task(task)
        with pl_module.task_record.timed("evaluation"), eval_mode(pl_module):
            if task not in self._evaluators:
                self._evaluators[task] = RolloutEvaluator(task, self.episodes, self.seed)
            policy = module_policy(pl_module, task=task_index)
            return self._evaluators[task].run(policy, progress=progress, record=record)

    def _evaluate_current(
        self, trainer: L.Trainer, pl_module: L.LightningModule, at_end: bool = False
    ) -> None:
        task, i = trainer.datamodule.task, pl_module.task_index
        result = self._run(task, pl_module, i, progress=at_end or self.progress)
        self._record(
            pl_module,
            {
                "success": result.success,
                "episode_length": result.episode_length,
                "flip_rate": result.flip_rate,
                "step": trainer.global_step,
            },
        )
        if trainer.logger is not None:
            prefix = pl_module.log_prefix
            trainer.logger.log_metrics(
                {
                    f"{prefix}eval/success": 100 * result.success,  # %, as the console
                    f"{prefix}eval/episode_length": result.episode_length,
                    f"{prefix}eval/flip_rate": result.flip_rate,
                },
                step=trainer.global_step,
            )

    def _evaluate_stream(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        i, tasks = pl_module.task_index, trainer.datamodule.tasks
        label = f"task {task_label(i)}/{len(tasks)}: evaluating {len(tasks)} tasks"
        with ProgressPrinter(label, len(tasks) * self.episodes, "episodes") as done:
            results = [
                self._run(task, pl_module, j, record=j == i, progress=done)
                for j, task in enumerate(tasks)
            ]
        row = [r.success for r in results]
        pl_module.task_record.success_row = row
        pl_module.task_record.rollouts = results[i]  # the current task's, with their paths
        self._record(pl_module, {"success": row[i], "step": trainer.global_step})

    def evaluate_task(
        self, task: str | Task, pl_module: L.LightningModule, task_index: int
    ) -> RolloutResult:
        """One entry of a row of R as a task's end measures it: ``pl_module`` acting as task
        ``task_index`` on ``task``, timed as evaluation (a derived run re-measures with it)."""
        return self._run(task, pl_module, task_index)

    def _record(self, pl_module: L.LightningModule, evaluation: dict[str, float]) -> None:
        pl_module.task_record.evaluation = evaluation
        pl_module.task_record.curve.append(evaluation)
        pl_module.task_record.episodes = self.episodes

    @override
    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        step = trainer.global_step
        if self.eval_every > 0 and step % self.eval_every == 0 and step < (trainer.max_steps or 0):
            self._evaluate_current(trainer, pl_module)

    @override
    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.datamodule.tasks:
            self._evaluate_stream(trainer, pl_module)
        else:
            self._evaluate_current(trainer, pl_module, at_end=True)
