"""CSP's callbacks: at the end of a task, search the old and the grown subspace for the weights
the critic values most (:class:`CriticEvaluation`), then keep or prune the new anchor by CSP's
rule (:class:`CriticPruning`). Anchors are added by HiSPO's
:class:`~hispo_pl.callbacks.AnchorExtension`; the rule lives in :mod:`hispo_pl.decisions`."""

from __future__ import annotations

from dataclasses import replace
from functools import partial

import lightning as L
import torch
from torch import Tensor
from typing_extensions import override

from ..decisions import (
    critic_extends,
    extended_subspace_candidates,
    previous_subspace_candidates,
    tolerance_problem,
)
from ..nn import eval_mode
from ..race import RaceOutcome, race_candidates, race_subspace
from ..results import CriticDecision, CriticSearchResult
from ..rundir import task_label
from .anchors import apply_decision, check_task_end_order, decide_subspaces
from .protocols import CriticScoredSubspaces, PrunableSubspaces, require, require_subspaces
from .state import KeyedState


def _require_critic(pl_module: L.LightningModule, who: str) -> CriticScoredSubspaces:
    needs = "a subspace of policies with a critic"
    return require(pl_module, CriticScoredSubspaces, who, needs, "CSP")


class CriticEvaluation(KeyedState):
    """At the end of a task, race Dirichlet candidates of each subspace by the critic's value
    of the mixed policy, ``W(α) = mean_s Q(s, g, π_α(s, g), α)``, on the task's held-out
    episodes (the same batches for every candidate), as
    :class:`~hispo_pl.callbacks.DirichletEvaluation` races them by loss.

    Candidates of the grown subspace: the trained weights, the new anchor alone and
    ``n_candidates`` Dirichlet(1) draws over every anchor; of the previous subspace:
    ``n_candidates`` draws over the older anchors (the new one at 0). Results go to the
    module's task record (``task_record.searches``) for :class:`CriticPruning`. The
    action-dependence diagnostic is measured at the best point of the grown subspace.

    Args:
        n_candidates: Dirichlet draws per subspace (old and grown each).
        n_batches: held-out batches the survivors are valued on.
        survivors: candidates kept after the probe (``None``: value every one on every batch).
        probe_samples: samples (from the first batch) every candidate is ranked on.
        diagnostic_actions: uniform actions per state in the diagnostic.
        seed: seeds the batches, the draws and the diagnostic's actions.

    Example:
        >>> from hispo_pl.callbacks import AnchorExtension, CriticEvaluation, CriticPruning
        >>> callbacks = [AnchorExtension(), CriticEvaluation(), CriticPruning(eps=0.1)]
    """

    # the arguments that tell two instances apart: its checkpoint entry's key
    state_args = (
        "n_candidates",
        "n_batches",
        "survivors",
        "probe_samples",
        "diagnostic_actions",
        "seed",
    )

    def __init__(
        self,
        n_candidates: int = 1024,
        n_batches: int = 16,
        survivors: int | None = 32,
        probe_samples: int = 256,
        diagnostic_actions: int = 16,
        seed: int = 0,
    ):
        if n_candidates < 1 or n_batches < 1 or diagnostic_actions < 1:
            raise ValueError(
                "n_candidates, n_batches and diagnostic_actions must be positive, got "
                f"{n_candidates}, {n_batches}, {diagnostic_actions}"
            )
        self.n_candidates, self.n_batches, self.survivors = n_candidates, n_batches, survivors
        self.probe_samples, self.diagnostic_actions, self.seed = (
            probe_samples,
            diagnostic_actions,
            seed,
        )

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        _require_critic(pl_module, type(self).__name__)

    @override
    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        pl_module.task_record.searches = self._run_search(trainer, pl_module)

    @torch.no_grad()
    def _run_search(self, trainer: L.Trainer, module) -> dict[str, CriticSearchResult]:
        device = module.device
        batches = trainer.datamodule.fixed_batches(self.n_batches, self.seed, device=device)
        probe = {k: v[: self.probe_samples] for k, v in batches[0].items()}
        generator = torch.Generator().manual_seed(self.seed)

        def race(cands: Tensor) -> RaceOutcome:
            def score(alphas: Tensor, batch: dict[str, Tensor]) -> Tensor:
                return -module.critic_values(alphas, batch)  # the race minimises

            return race_candidates(score, cands, batches, probe, self.survivors)

        results = {}
        with module.task_record.timed("search"), eval_mode(module):
            for name in module.subspace_names:
                if module.transferred(name):
                    continue
                trained = module.current_alpha(name).to(device)
                k = module.n_anchors(name)
                grown = (
                    extended_subspace_candidates(self.n_candidates, trained, generator)
                    if k > 1
                    else trained[None]
                ).to(device)
                best = race(grown)
                found = grown[best.best].tolist()
                res = CriticSearchResult(w_curr=-best.best_loss, alpha_curr=found)
                chosen = [res.alpha_curr]
                if k > 1:
                    previous = previous_subspace_candidates(self.n_candidates, k, generator)
                    previous = previous.to(device)
                    best_prev = race(previous)
                    res.w_prev = -best_prev.best_loss
                    res.alpha_prev = previous[best_prev.best].tolist()
                    chosen.append(res.alpha_prev)
                imitation = race_subspace(
                    module, name, torch.tensor(chosen, device=device), batches
                ).losses  # exhaustive: in the order given
                res.l_curr = float(imitation[0])
                res.l_prev = float(imitation[1]) if k > 1 else None
                diagnostic = self._diagnostic(module, grown[best.best], batches, generator)
                results[name] = replace(res, **diagnostic)
        return results

    def _diagnostic(self, module, alpha: Tensor, batches, generator) -> dict[str, float]:
        per_batch = [
            module.critic_diagnostic(alpha, b, self.diagnostic_actions, generator) for b in batches
        ]
        return {k: sum(d[k] for d in per_batch) / len(per_batch) for k in per_batch[0]}


class CriticPruning(KeyedState):
    """At the end of a task, per subspace, CSP's rule: keep the new anchor iff
    ``W(α_new) > (1 + eps) · W(α_old)`` (:func:`hispo_pl.decisions.critic_extends`, which
    also covers negative values) and store ``α_new`` for the task, else prune it and store
    ``α_old``. Decisions, the critic's values, the imitation losses of the two points and the
    action-dependence diagnostic go to ``decisions.jsonl`` and TensorBoard
    (``critic/<subspace>/...`` at the task's step).

    Must come after :class:`CriticEvaluation` and before ``RolloutEvaluation`` (checked in
    ``setup``).

    Args:
        eps: the tolerance ε of the rule.
    """

    # the arguments that tell two instances apart: its checkpoint entry's key
    state_args = ("eps",)

    def __init__(self, eps: float = 0.1):
        if tolerance_problem(eps):
            raise ValueError(f"CriticPruning's eps {tolerance_problem(eps)}, got {eps}")
        self.eps = eps

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        require_subspaces(pl_module, PrunableSubspaces, type(self).__name__)
        check_task_end_order(trainer.callbacks, self, CriticEvaluation)

    @override
    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        decisions = decide_subspaces(trainer, pl_module, partial(self._decide, pl_module))
        _log_critic(trainer, pl_module, decisions)

    def _decide(self, module, name: str, res: CriticSearchResult) -> CriticDecision:
        keep_new = None if res.w_prev is None else critic_extends(res.w_curr, res.w_prev, self.eps)
        action = apply_decision(module, name, keep_new, res.alpha_curr, res.alpha_prev)
        return CriticDecision.of(
            res,
            task=module.task_index,
            subspace=name,
            decision=action,
            eps=self.eps,
            anchors=module.n_anchors(name),
        )


CRITIC_TAGS = {
    "w_curr": "W_curr",
    "w_prev": "W_prev",
    "q_action_std": "q_action_std",
    "q_state_std": "q_state_std",
    "action_dependence": "action_dependence",
    "q_data": "q_data",
    "q_policy": "q_policy",
    "q_uniform": "q_uniform",
}


def _log_critic(trainer: L.Trainer, module, decisions: list[CriticDecision]) -> None:
    """The critic's values and diagnostic as ``critic/<subspace>/<tag>`` at the task's step."""
    if trainer.logger is None:
        return
    metrics = {
        f"critic/{d.subspace}/{tag}": getattr(d, key)
        for d in decisions
        for key, tag in CRITIC_TAGS.items()
        if getattr(d, key) is not None
    }
    trainer.logger.log_metrics(metrics, step=task_label(module.task_index))
