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

    Environments are built once per task and reused for the whole run. Rollouts are seeded and
    deterministic, so a task evaluated again with the very tensors it acted with before (the
    module's :meth:`~hispo_pl.modules.GoalConditionedBC.acting_digest`: a network per task that
    did not train again, a subspace that pruned what it grew) repeats the earlier result,
    which is reused instead of rolled out: a row of R costs the tasks whose policy changed.

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
        self._measured: dict[tuple[Task, str], RolloutResult] = {}  # by task and acting state

    def _run(
        self,
        task: str | Task,
        pl_module: L.LightningModule,
        task_index: int | None,
        record: bool = False,
        progress: bool | ProgressPrinter = False,
        reuse: bool = False,
    ) -> RolloutResult:
        """``task``'s rollouts with ``pl_module`` acting as task ``task_index``; ``reuse``: an
        earlier result with the same acting state stands for them (and is kept for later)."""
        task = parse_task(task)
        known = reuse and task_index is not None
        digest = pl_module.acting_digest(task_index) if known else None
        earlier = self._measured.get((task, digest)) if digest is not None else None
        if earlier is not None and (earlier.trajectories is not None or not record):
            if isinstance(progress, ProgressPrinter):
                progress.update(self.episodes)
            return earlier
        with pl_module.task_record.timed("evaluation"), eval_mode(pl_module):
            if task not in self._evaluators:
                self._evaluators[task] = RolloutEvaluator(task, self.episodes, self.seed)
            policy = module_policy(pl_module, task=task_index)
            result = self._evaluators[task].run(policy, progress=progress, record=record)
        if digest is not None:
            self._measured[(task, digest)] = result
        return result

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
        results = self.evaluate_row(tasks, pl_module, i)
        row = [r.success for r in results]
        pl_module.task_record.success_row = row
        pl_module.task_record.rollouts = results[i]  # the current task's, with their paths
        self._record(pl_module, {"success": row[i], "step": trainer.global_step})

    def evaluate_row(
        self, tasks: list[str | Task], pl_module: L.LightningModule, i: int
    ) -> list[RolloutResult]:
        """Row ``i`` of R as task ``i``'s end measures it: ``pl_module`` acting as each task of
        ``tasks`` on it, reusing this instance's earlier rollouts of an unchanged policy; task
        ``i``'s keep their paths (for its picture)."""
        label = f"task {task_label(i)}/{len(tasks)}: evaluating {len(tasks)} tasks"
        with ProgressPrinter(label, len(tasks) * self.episodes, "episodes") as done:
            return [
                self._run(task, pl_module, j, record=j == i, progress=done, reuse=True)
                for j, task in enumerate(tasks)
            ]

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
