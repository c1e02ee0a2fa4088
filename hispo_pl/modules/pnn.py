"""PNN (Progressive Neural Networks) on the HBC backbone: a new column per task for each of
the two policies (high and low), lateral adapters from every earlier column at every layer,
only the newest column (and its laterals) trainable. On the flat BC backbone
(``backbone="bc"``) the one policy grows the same way.

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

from typing import Literal

import torch
from torch import Tensor

from ..nn.mlp import feature_dim
from ..nn.progressive import ProgressivePolicy
from .columns import record_task
from .hbc import (
    Backbone,
    GoalConditionedBC,
    HierarchicalNet,
    flat_losses,
    hierarchical_losses,
    low_input_dim,
    low_velocity_input,
)


class PNN(GoalConditionedBC):
    """Progressive columns for the high and the low policy of the HBC backbone (or for the one
    policy of flat BC).

    Args:
        obs_dim, action_dim, goal_dim: sizes (linked from the data by the CLI).
        backbone: ``hbc`` (columns for ``high`` and ``low``) or ``bc`` (columns for one flat
            ``policy``, ``low_hidden`` wide, on the high policy's inputs), for the BC-vs-HBC table.
        high_hidden, low_hidden, dropout, high_log_std, low_obs, binary_actions, low_log_std,
            low_velocity: each
            column's, as :class:`HBC`.
        lr, lr_schedule: Adam over the newest column and its laterals, restarted at every task.

    Example:
        >>> m = PNN(4, 2, high_hidden=8, low_hidden=16)
        >>> for k in range(3):
        ...     m.start_task(k)
        ...     m.finish_task(k)
        >>> m.n_columns, m.task_column.tolist()
        (3, [0, 1, 2])
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        goal_dim: int = 2,
        backbone: Backbone = "hbc",
        high_hidden: int = 64,
        low_hidden: int = 256,
        dropout: float = 0.1,
        high_log_std: float | None = None,
        low_obs: bool = True,
        lr: float = 3e-4,
        lr_schedule: Literal["cosine", "constant"] = "cosine",
        binary_actions: int = 0,
        low_log_std: float | None = None,
        low_velocity: bool = False,
    ):
        super().__init__(lr=lr, lr_schedule=lr_schedule)
        self.save_hyperparameters()
        f = feature_dim(goal_dim)
        if backbone == "hbc":
            self.high = ProgressivePolicy(
                f + obs_dim + 2 * goal_dim,
                high_hidden,
                goal_dim,
                dropout,
                fixed_log_std=high_log_std,
            )
            self.low = ProgressivePolicy(
                low_input_dim(obs_dim, goal_dim, low_obs, low_velocity),
                low_hidden,
                action_dim,
                dropout,
                fixed_log_std=low_log_std,
                binary=binary_actions,
            )
            self.policy_names: tuple[str, ...] = ("high", "low")
        elif backbone == "bc":
            self.policy = ProgressivePolicy(
                f + obs_dim + 2 * goal_dim, low_hidden, action_dim, dropout, binary=binary_actions
            )
            self.policy_names = ("policy",)
        else:
            raise ValueError(f"unknown backbone {backbone!r}; expected 'hbc' or 'bc'")
        # column each finished task acts with (one entry per finished task)
        self.register_buffer("task_column", torch.zeros(0, dtype=torch.long))

    @property
    def n_columns(self) -> int:
        return self._policies()[0].net.n_columns

    @property
    def n_tasks(self) -> int:
        return len(self.task_column)

    def _policies(self) -> tuple[ProgressivePolicy, ...]:
        return tuple(getattr(self, name) for name in self.policy_names)

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
        if self.hparams.backbone == "bc":
            return flat_losses(self.policy, batch)
        hp = self.hparams
        return hierarchical_losses(self.high, self.low, batch, hp.low_obs, hp.low_velocity)

    @torch.no_grad()
    def act(
        self,
        observation: Tensor,
        position: Tensor,
        goal: Tensor,
        task: int | None = None,
        velocity: Tensor | None = None,
    ) -> Tensor:
        column = self.column_for(self.task_index if task is None else task)
        x = HierarchicalNet.high_input(observation, position, goal)
        if self.hparams.backbone == "bc":
            return self.policy.act(self.policy(x, column)[0])
        offset, _ = self.high(x, column)
        velocity = low_velocity_input(self.hparams.low_velocity, velocity)
        low_x = HierarchicalNet.low_input(observation, offset, self.hparams.low_obs, velocity)
        return self.low.act(self.low(low_x, column)[0])

    # --- checkpoints ----------------------------------------------------------------------

    def restore_structure(self, state_dict: dict[str, Tensor]) -> None:
        """As many columns and mapped tasks as the state dict holds, before it loads."""
        prefix = f"{self.policy_names[0]}.net.columns."
        columns = {int(k[len(prefix) :].split(".")[0]) for k in state_dict if k.startswith(prefix)}
        while self.n_columns < len(columns):
            for policy in self._policies():
                policy.net.add_column()
        self.task_column = torch.zeros_like(state_dict["task_column"])
