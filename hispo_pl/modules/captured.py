"""The training step of ``optim.captured`` (:mod:`hispo_pl.nn.program`), as
:class:`~hispo_pl.modules.hbc.GoalConditionedBC` runs it: each update one run of the module's
:class:`~hispo_pl.nn.program.TrainingProgram`, its losses read from the device only when a
logger writes them."""

from __future__ import annotations

from torch import Tensor

from ..errors import TrainingDivergedError
from ..nn.program import TrainingProgram


class CapturedSteps:
    """What :class:`~hispo_pl.modules.hbc.GoalConditionedBC` adds to a LightningModule to
    train a captured step: :meth:`_program_step` (its ``training_step`` under
    ``optim.captured``) and the hooks that start and release the task's program. The module
    builds :attr:`_program` in ``configure_optimizers`` and provides ``_divergence_message``."""

    _program: TrainingProgram | None

    def _program_step(self, batch: dict[str, Tensor]) -> Tensor | None:
        """The training step of ``optim.captured``: one update per batch of a group
        (``[N, B, ...]`` tensors, ``--data.group N``; one plain batch is one update), each a
        run of the module's :class:`~hispo_pl.nn.program.TrainingProgram` through the
        Trainer's optimiser, so ``global_step`` and ``max_steps`` count updates. Losses are
        read from the device only on the updates the logger writes (and a task's last)."""
        grouped = batch["action"].dim() > 2
        parts = [batch]
        if grouped:  # the group's batches in turn, as views of its tensors
            rows = zip(*(v.unbind(0) for v in batch.values()), strict=True)
            parts = [dict(zip(batch, row, strict=True)) for row in rows]
        trainer = self._trainer
        budget = trainer.max_steps if trainer is not None else -1
        if budget is not None and budget > 0:  # a group never trains past the budget
            parts = parts[: max(1, budget - self.global_step)]
        optimizer = self.optimizers()
        for part in parts:
            if self._program is None:  # nothing trains on this task: the step is counted
                optimizer.step()
                continue
            optimizer.optimizer.load(part)
            optimizer.step()
            update = self.global_step - 1  # 0-based, as the logger numbers steps
            last = budget is not None and budget > 0 and update + 1 >= budget
            if grouped and (self._update_reaches_logger(update) or last):
                self._write_program_losses(update, len(part["action"]))
            elif not grouped and (self._step_after_update_reaches_logger() or last):
                self._check_program_finite()
                self.log_dict(
                    {
                        f"{self.log_prefix}train/{k}": v.clone()
                        for k, v in self._program.losses.items()
                    },
                    prog_bar=True,
                    batch_size=len(part["action"]),
                )
        # the last update's loss, on the device (a callback that prints it reads it then)
        return None if self._program is None else self._program.losses["loss"].clone()

    def _update_reaches_logger(self, update: int) -> bool:
        """Whether the logger writes update ``update`` (0-based): every
        ``log_every_n_steps`` updates, as it writes single steps."""
        trainer = self._trainer
        every = trainer.log_every_n_steps if trainer is not None else 1
        return every > 0 and (update + 1) % every == 0

    def _step_after_update_reaches_logger(self) -> bool:
        """:meth:`_step_reaches_logger` asked after the update (``global_step`` counts it)."""
        trainer = self._trainer
        if trainer is None or trainer.fast_dev_run:
            return True
        return self._update_reaches_logger(self.global_step - 1) or trainer.should_stop

    def _check_program_finite(self) -> None:
        update = self._program.nonfinite_update()
        if update is not None:
            loss = self._program.losses["loss"]
            raise TrainingDivergedError(self._divergence_message(loss, step=update + 1))

    def _write_program_losses(self, update: int, batch_size: int) -> None:
        """A group's update: its losses go to the loggers at its own step (Lightning writes a
        Trainer step's values at the count of Trainer steps, here N updates each), and to
        the progress bar."""
        self._check_program_finite()
        values = {f"{self.log_prefix}train/{k}": v for k, v in self._program.read_losses().items()}
        for logger in self.loggers:
            logger.log_metrics({**values, "epoch": self.current_epoch}, step=update)
        self.log_dict(values, prog_bar=True, logger=False, batch_size=batch_size)

    def on_train_start(self) -> None:
        """A resumed task's program goes on from the restored update (its schedule's place)."""
        if self._program is not None:
            self._program.count.fill_(self.global_step)

    def on_train_end(self) -> None:
        """Release the task's captured step (its graph and buffers)."""
        if self._program is not None:
            self._program.release()
