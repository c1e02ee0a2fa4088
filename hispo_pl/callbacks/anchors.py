"""HiSPO's callbacks: extend the subspaces at task start, and keep or prune the new anchors at
task end after the search of :mod:`.loss_search` (zero-shot transfer before a task:
:mod:`.transfer`). Each hook is thin; the rules live in :mod:`hispo_pl.decisions`; how a
decision is carried out and logged is shared with CSP's :mod:`.critic_pruning`."""

from __future__ import annotations

from collections.abc import Callable

import lightning as L
import torch
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_warn
from typing_extensions import override

from ..decisions import (
    decided_by_budget,
    keep_previous,
    resolved_tolerance,
    tolerance_problem,
)
from ..results import Decision, LossDecision, SearchResult, ZeroShotDecision, rule_metrics
from ..rundir import RunDir, task_label
from ..tasks import Family
from .loss_search import DirichletEvaluation
from .protocols import ExtendableSubspaces, PrunableSubspaces, require_subspaces
from .rollout import RolloutEvaluation
from .state import KeyedState


class AnchorExtension(L.Callback):
    """At the start of every task after the first, add one trainable anchor to each subspace
    (older anchors frozen) before the optimiser is built; stored weights get a 0 appended.
    A module whose ``anchor_init`` is unset starts the anchor as the task family says
    (:attr:`~hispo_pl.tasks.Family.anchor_init`)."""

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        module = require_subspaces(pl_module, ExtendableSubspaces, type(self).__name__)
        if stage != "fit" or module.task_index == 0:
            return
        task = getattr(getattr(trainer, "datamodule", None), "task", None)
        init = task.env_family.anchor_init if task is not None else "mean"
        for name in module.subspace_names:
            if not module.transferred(name) and not module.grown(name):
                module.add_anchor(name, init)  # (transferred: ZeroShotTransfer chose its weights)


def check_task_end_order(callbacks: list[L.Callback], pruning: L.Callback, search_type: type):
    """Task-end hooks run in list order: the search (an instance of ``search_type``), then
    ``pruning``, then the rollout evaluation that must see the pruned policy."""
    pos = {id(cb): i for i, cb in enumerate(callbacks)}
    search = [cb for cb in callbacks if isinstance(cb, search_type)]
    prune, find = type(pruning).__name__, search_type.__name__
    if not search or pos[id(search[0])] > pos[id(pruning)]:
        raise ValueError(f"{prune} needs a {find} callback listed before it")
    if any(
        isinstance(cb, RolloutEvaluation) and pos[id(cb)] < pos[id(pruning)] for cb in callbacks
    ):
        raise ValueError(f"list RolloutEvaluation after {prune}: it must see the pruned policy")


class SubspacePruning(KeyedState):
    """At the end of a task, per subspace: prune the new anchor iff
    ``L_prev <= (1 + eps) * L_curr`` and store ``alpha_prev`` for the task, else keep it and
    store ``alpha_curr``. Decisions go to TensorBoard (text) and ``decisions.jsonl``.

    Must come after :class:`DirichletEvaluation` and before ``RolloutEvaluation`` in the
    callback list (checked in ``setup``).

    Args:
        eps_high: tolerance of the high subspace; ``None``: the task family's
            (:attr:`~hispo_pl.tasks.Family.pruning_eps`).
        eps_low: tolerance of the low subspace; ``None``: the task family's.
        eps: tolerances by subspace name, for modules whose subspaces are named otherwise
            (CSPO's single ``policy``: ``{"policy": 0.1}``); its entries override
            ``eps_high`` / ``eps_low``. A subspace named nowhere gets the largest tolerance
            given, else the smallest of the family's.
    """

    # the arguments that tell two instances apart: its checkpoint entry's key
    state_args = ("eps",)

    def __init__(
        self,
        eps_high: float | None = None,
        eps_low: float | None = None,
        eps: dict[str, float] | None = None,
    ):
        given = {"high": eps_high, "low": eps_low, **(eps or {})}
        self.eps = {name: e for name, e in given.items() if e is not None}
        bad = {name: e for name, e in self.eps.items() if tolerance_problem(e)}
        if bad:  # checked here, not after a task has trained
            raise ValueError(f"SubspacePruning tolerances must be >= 0, got {bad}")

    def tolerance(self, name: str, family: Family) -> float:
        """ε of subspace ``name`` on a task of ``family``: the one given, else the family's."""
        return resolved_tolerance(name, self.eps, family.pruning_eps)

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        require_subspaces(pl_module, PrunableSubspaces, type(self).__name__)
        check_task_end_order(trainer.callbacks, self, DirichletEvaluation)

    @override
    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        family = trainer.datamodule.task.env_family

        def decide(name: str, res: SearchResult) -> LossDecision:
            return self._decide(pl_module, name, res, self.tolerance(name, family))

        decide_subspaces(trainer, pl_module, decide)

    def _decide(self, module, name: str, res: SearchResult, eps: float) -> LossDecision:
        first = res.l_prev is None
        keep_new = None if first else not keep_previous(res.l_prev, res.l_curr, eps)
        action = apply_decision(module, name, keep_new, res.alpha_curr, res.alpha_prev)
        if not first and decided_by_budget(res.improvement, eps):
            rank_zero_warn(
                f"task {task_label(module.task_index)}, {name} subspace ({action}): L_curr "
                f"still fell by {res.improvement:.1%} over the last "
                f"{module.task_record.convergence_window:.0%} of "
                f"the steps, more than eps = {eps}; the step budget, not the task, decided "
                "this. Train longer (--trainer.max_steps) for a decision about the task."
            )
        return LossDecision.of(
            res,
            task=module.task_index,
            subspace=name,
            decision=action,
            eps=eps,
            anchors=module.n_anchors(name),
        )


def apply_decision(
    module,
    name: str,
    keep_new: bool | None,
    alpha_curr: list[float],
    alpha_prev: list[float] | None,
) -> str:
    """Carry out a task-end decision on subspace ``name`` and say which it was: keep the new
    anchor and store ``alpha_curr`` for the task, or prune it and store ``alpha_prev`` (its
    last weight, the new anchor's, dropped); ``keep_new`` None: the subspace's first anchor,
    nothing to compare."""
    task = module.task_index
    if keep_new is False:
        module.prune_last_anchor(name)
        module.set_task_alpha(task, name, torch.tensor(alpha_prev[:-1]))
        return "prune"
    module.set_task_alpha(task, name, torch.tensor(alpha_curr))
    return "first" if keep_new is None else "keep"


def decide_subspaces(
    trainer: L.Trainer, module, decide: Callable[[str, object], Decision]
) -> list[Decision]:
    """A pruning callback's task end: ``decide(name, result)`` for every subspace the search
    just scored (the module's task record), then every weight frozen and the decisions
    logged."""
    decisions = [decide(name, res) for name, res in module.task_record.searches.items()]
    module.freeze_all()
    log_decisions(trainer, module, decisions)
    return decisions


SEARCH_TAGS = {
    "l_prev": "L_prev",
    "l_curr": "L_curr",
    "l_trained": "L_trained",  # refine_current replaced the trained weights
    "l_curr_train": "L_curr_train",
    "l_prev_train": "L_prev_train",
    "improvement": "convergence",
}
"""A decision's values logged as ``search/<subspace>/<tag>`` where it has them."""


def log_decisions(trainer: L.Trainer, module, records: list[Decision]) -> None:
    """Append decisions to ``decisions.jsonl`` in the run dir and log them to TensorBoard.

    The anchor counts start with a point at step 0 (one anchor, before any task): with only
    the tasks' points, TensorBoard's default outlier scaling (it leaves out a chart's extreme
    5 %) draws a count that grew once, 1 then 2, as an empty chart."""
    RunDir(trainer.default_root_dir).append_decisions(records)
    logger = trainer.logger
    if logger is None:
        return
    task = task_label(module.task_index)
    metrics = {f"anchors/{d.subspace}/count": d.anchors for d in records}
    metrics.update(rule_metrics(records))
    for d in records:
        for key, tag in SEARCH_TAGS.items():
            if getattr(d, key, None) is not None:
                metrics[f"search/{d.subspace}/{tag}"] = getattr(d, key)
        if isinstance(d, ZeroShotDecision):
            for policy, rate in d.pac_rate.items():
                metrics[f"zero_shot/{d.subspace}/pac_rate_{policy}"] = rate
    if module.task_index == 0:  # the one anchor each subspace starts with, at step 0
        logger.log_metrics({f"anchors/{d.subspace}/count": 1 for d in records}, step=0)
    logger.log_metrics(metrics, step=task)
    if isinstance(logger, TensorBoardLogger):
        from ..figures import anchor_counts_figure, rule_figure  # matplotlib: only to draw

        text = "\n".join(f"{d.subspace}: {d.decision} (anchors {d.anchors})" for d in records)
        logger.experiment.add_text("decisions", text, global_step=task)
        so_far = RunDir(trainer.default_root_dir).decisions()  # every task's, this one last
        # drawn as they are: TensorBoard's charts smooth these few points and leave out their
        # extremes when scaling an axis, so a scalar chart can miss the very value that decided
        for tag, fig in (("pruning/rule", rule_figure(so_far)),
                         ("anchors/per_subspace", anchor_counts_figure(so_far))):  # fmt: skip
            if fig is not None:
                logger.experiment.add_figure(tag, fig, global_step=task)
