"""PNN (Progressive Neural Networks) on the HBC backbone: a new column per task for each of
the two policies (high and low), lateral adapters from every earlier column at every layer,
only the newest column (and its laterals) trainable. On the flat BC backbone
(``backbone.kind="bc"``) the one policy grows the same way.

The module owns everything inference needs: the columns and laterals of both policies and the
buffer mapping every finished task to the column it acts with, so a checkpoint alone acts on
every task seen. Task ``j`` acts with column ``j`` (reading the frozen columns ``< j`` through
its laterals); the current or an unseen task acts with the newest column. Later columns never
feed earlier ones, so a finished task's actions stay bit-identical (BWT = 0). Growth is carried
out by the :class:`~hispo_pl.callbacks.TaskNetworks` callback through the
:class:`~hispo_pl.modules.columns.GrowingPolicy` protocol. See :mod:`hispo_pl.nn.progressive`
for the lateral design (linear, bias-free, zero-initialised).
"""

from __future__ import annotations

import re

import torch
from torch import Tensor

from ..nn.hierarchy import Forward, HierarchicalPolicy
from ..nn.progressive import ProgressivePolicy
from .columns import record_task
from .hbc import GoalConditionedBC

# a column's own tensors (``columns.<k>.``) and its laterals (``laterals.<k - 1>.``)
_COLUMN = re.compile(r"(?:^|\.)(columns|laterals)\.(\d+)\.")


def _column_of(match: re.Match) -> int:
    """The column a state entry belongs to, from :data:`_COLUMN`'s match."""
    return int(match.group(2)) + (match.group(1) == "laterals")


class PNN(GoalConditionedBC):
    """Progressive columns for the high and the low policy of the HBC backbone (or for the one
    policy of flat BC).

    Args:
        obs_dim, action_dim, goal_dim: sizes (linked from the data by the CLI).
        backbone: each column's network (:class:`~hispo_pl.config.BackboneConfig`): ``hbc``
            grows columns for ``high`` and ``low``, ``bc`` for one flat ``policy``.
        optim: Adam over the newest column and its laterals, restarted at every task.

    Example:
        >>> from hispo_pl.config import BackboneConfig
        >>> m = PNN(4, 2, backbone=BackboneConfig(high_hidden=8, low_hidden=16))
        >>> for k in range(3):
        ...     m.start_task(k)
        ...     m.finish_task(k)
        >>> m.n_columns, m.task_column.tolist()
        (3, [0, 1, 2])
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.save_hyperparameters()
        self.net = self.make_policy(ProgressivePolicy)
        # column each finished task acts with (one entry per finished task)
        self.register_buffer("task_column", torch.zeros(0, dtype=torch.long))

    @property
    def n_columns(self) -> int:
        return self._policies()[0].net.n_columns

    @property
    def n_tasks(self) -> int:
        return len(self.task_column)

    def _policies(self) -> tuple[ProgressivePolicy, ...]:
        return tuple(self.net.heads().values())

    # --- the GrowingPolicy protocol -------------------------------------------------------

    def start_task(self, task: int) -> None:
        """Make column ``task`` the one that trains (before the optimiser is built): add it
        when it does not exist yet, freeze every other. Idempotent (a second setup of the same
        task does not grow again), and right after a resume from a checkpoint."""
        if task > self.n_columns:
            raise ValueError(
                f"task {task} started with {self.n_columns} columns (tasks 0..{self.n_columns - 1})"
                "; PNN needs its tasks in stream order"
            )
        if task < self.n_columns - 1:
            raise ValueError(
                f"task {task} already has a frozen column (newest: {self.n_columns - 1}); PNN "
                "trains only its newest column, so earlier tasks cannot be trained again"
            )
        if task == self.n_columns:
            for policy in self._policies():
                policy.net.add_column()
        self.freeze_all()  # every earlier column and lateral, also after a resume
        for policy in self._policies():
            for p in policy.net.column_parameters(task):
                p.requires_grad_(True)

    def finish_task(self, task: int) -> None:
        """Record the column task ``task`` acts with from now on (the newest)."""
        self.task_column = record_task(self.task_column, task, self.n_columns - 1)

    # --- training and acting --------------------------------------------------------------

    def column_for(self, task: int | None) -> int:
        """A finished task's column; the newest one for the current or an unseen task."""
        if task is not None and task < self.n_tasks:
            return int(self.task_column[task])
        return self.n_columns - 1

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """The backbone's losses of the newest column (the earlier ones run without gradients)."""
        return self.net.losses(batch)

    def acting_policy(self, task: int) -> tuple[HierarchicalPolicy, Forward]:
        """Every head runs its columns up to task ``task``'s."""
        column = self.column_for(task)
        return self.net, lambda name, x: self.net[name](x, column)

    def acting_state(self, task: int) -> dict[str, Tensor]:
        """The columns up to task ``task``'s and their laterals (a later column is not run),
        and which column acts."""
        column = self.column_for(task)
        state = {"column": torch.tensor(column)}
        for name, tensor in self.net.state_dict().items():
            own = _COLUMN.search(name)
            if own is None or _column_of(own) <= column:
                state[name] = tensor
        return state

    # --- checkpoints ----------------------------------------------------------------------

    def restore_structure(self, state_dict: dict[str, Tensor]) -> None:
        """As many columns and mapped tasks as the state dict holds, before it loads."""
        found = (_COLUMN.search(k) for k in state_dict if k.startswith("net."))
        columns = 1 + max((_column_of(m) for m in found if m is not None), default=0)
        while self.n_columns < columns:
            for policy in self._policies():
                policy.net.add_column()
        self.task_column = torch.zeros_like(state_dict["task_column"])
