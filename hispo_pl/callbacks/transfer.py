"""The paper's PAC zero-shot criterion as a callback: before a task's subspaces are extended,
accept a point of the existing subspace for the new task when it predicts the task's data
closely enough. The rule lives in :mod:`hispo_pl.decisions`."""

from __future__ import annotations

import time
from typing import Literal

import lightning as L
import torch
from torch import Tensor
from typing_extensions import override

from ..decisions import pac_rate, resolved_tolerance, zero_shot
from ..nn import eval_mode
from ..nn.simplex import sample_dirichlet
from ..race import race_subspace, resolve_precision
from ..results import ZeroShotDecision
from ..task_families import Family
from .anchors import AnchorExtension, log_decisions
from .protocols import TransferableSubspaces, require_subspaces
from .state import KeyedState


class ZeroShotTransfer(KeyedState):
    """The paper's PAC criterion (section 5.5.3), before a task's subspaces are extended: per
    subspace, the best point of the existing subspace (Dirichlet candidates raced on the new
    task's data, as in :class:`DirichletEvaluation`) is accepted for the new task without a new
    anchor iff ``P[d(a, â) <= eps] >= 1 - delta``, with d the Euclidean distance between its
    deterministic prediction and the data: the subgoal offset for the high policy (maze units),
    the action for the low one. An accepted subspace is neither extended nor trained; when every
    subspace is accepted the task trains no step at all. Decisions (``zero-shot`` or ``train``,
    the rate, the estimated time saved) go to ``decisions.jsonl`` and TensorBoard.

    List it before :class:`AnchorExtension`.

    Args:
        eps_high: distance (maze units) the high policy's subgoal may be off; ``None``: the
            task family's (:attr:`~hispo_pl.tasks.Family.pac_eps`).
        eps_low: distance the low policy's action may be off; ``None``: the task family's.
            A family's tolerances separate, on its streams, the tasks where HiSPO's pruning
            dropped the new anchor from those where it kept one (``docs/studies/zero-shot.md``):
            subgoals and actions have each family's own units and dimensions.
        delta: accepted probability of a larger error.
        n_candidates, n_batches, survivors, probe_samples, precision, seed: the search, as in
            :class:`DirichletEvaluation`.
    """

    # the arguments that tell two instances apart: its checkpoint entry's key
    state_args = (
        "eps",
        "delta",
        "n_candidates",
        "n_batches",
        "survivors",
        "probe_samples",
        "precision",
        "seed",
    )

    def __init__(
        self,
        eps_high: float | None = None,
        eps_low: float | None = None,
        delta: float = 0.1,
        n_candidates: int = 1024,
        n_batches: int = 4,
        survivors: int | None = 32,
        probe_samples: int = 256,
        precision: Literal["auto", "32", "bf16"] = "auto",
        seed: int = 0,
    ):
        given = {"high": eps_high, "low": eps_low}
        self.eps = {name: e for name, e in given.items() if e is not None}
        self.delta = delta
        self.n_candidates, self.n_batches, self.survivors = n_candidates, n_batches, survivors
        self.probe_samples, self.precision, self.seed = probe_samples, precision, seed
        self._train_seconds: list[float] = []  # tasks trained in this process, for time saved
        self._started: float | None = None
        self._skip = False

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        module = require_subspaces(pl_module, TransferableSubspaces, type(self).__name__)
        self._skip = False
        _check_before_extension(trainer.callbacks, self)
        if stage != "fit" or module.task_index == 0:
            return
        decisions = self._transfer(trainer, module)
        self._skip = all(module.transferred(n) for n in module.subspace_names)
        if self._skip:  # the saving: this task's steps, at the mean time of a trained task
            saved = (
                sum(self._train_seconds) / len(self._train_seconds) if self._train_seconds else None
            )
            for d in decisions:
                d.steps_skipped, d.time_saved_s = trainer.max_steps, saved
        log_decisions(trainer, module, decisions)

    @override
    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self._skip:
            trainer.should_stop = True  # every subspace transferred: no gradient step
        self._started = time.perf_counter()

    @override
    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not self._skip and self._started is not None:
            self._train_seconds.append(time.perf_counter() - self._started)

    @torch.no_grad()
    def best_points(self, module, datamodule) -> dict[str, tuple[Tensor, dict[str, Tensor]]]:
        """Per subspace not yet taken for this task: the best point of its existing anchors on
        the task's held-out batches (Dirichlet candidates raced as in
        :class:`DirichletEvaluation`) and, per policy it holds, the distance of that point's
        prediction to each sample: what the criterion tests, before any anchor is added."""
        device = module.device
        batches = datamodule.fixed_batches(self.n_batches, self.seed, device=device)
        probe = {k: v[: self.probe_samples] for k, v in batches[0].items()}
        precision = resolve_precision(self.precision, device)
        generator = torch.Generator().manual_seed(self.seed)
        out = {}
        with eval_mode(module):
            for name in module.subspace_names:
                if module.transferred(name):
                    continue
                k = module.n_anchors(name)
                cands = sample_dirichlet(self.n_candidates, k, generator).to(device)
                race = race_subspace(
                    module, name, cands, batches, probe, self.survivors, precision=precision
                )
                best = cands[race.best]
                distances = [module.prediction_distances(name, best, b) for b in batches]
                out[name] = (best, {p: torch.cat([d[p] for d in distances]) for p in distances[0]})
        return out

    def tolerance(self, policy: str, family: Family) -> float:
        """ε of ``policy`` on a task of ``family``: the one given, else the family's."""
        return resolved_tolerance(policy, self.eps, family.pac_eps)

    def _transfer(self, trainer: L.Trainer, module) -> list[ZeroShotDecision]:
        family = trainer.datamodule.task.env_family
        decisions = []
        for name, (best, distances) in self.best_points(module, trainer.datamodule).items():
            rates, eps, accepted = {}, {}, True
            for policy, d in distances.items():
                eps[policy] = self.tolerance(policy, family)
                rates[policy] = pac_rate(d, eps[policy])
                accepted &= zero_shot(d, eps[policy], self.delta)
            if accepted:
                module.transfer(name, best)
            decisions.append(
                ZeroShotDecision(
                    task=module.task_index,
                    subspace=name,
                    decision="zero-shot" if accepted else "train",
                    pac_rate=rates,
                    eps=eps,
                    delta=self.delta,
                    anchors=module.n_anchors(name),
                    alpha=best.tolist(),
                )
            )
        return decisions


def _check_before_extension(callbacks: list[L.Callback], transfer: ZeroShotTransfer) -> None:
    pos = {id(cb): i for i, cb in enumerate(callbacks)}
    for cb in callbacks:
        if isinstance(cb, AnchorExtension) and pos[id(cb)] < pos[id(transfer)]:
            raise ValueError("list ZeroShotTransfer before AnchorExtension: it decides first")
