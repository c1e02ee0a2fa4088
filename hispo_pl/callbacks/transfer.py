"""The paper's PAC zero-shot criterion as a callback: before a task's subspaces are extended,
accept a point of the existing subspace for the new task when it predicts the task's data
closely enough. The rule lives in :mod:`hispo_pl.decisions`."""

from __future__ import annotations

import time
from typing import Literal

import lightning as L
import torch
from typing_extensions import override

from ..decisions import pac_rate, zero_shot
from ..nn import eval_mode
from ..nn.simplex import sample_dirichlet
from ..race import race_subspace, resolve_precision
from ..results import ZeroShotDecision
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
        eps_high: distance (maze units) the high policy's subgoal may be off.
        eps_low: distance the low policy's action may be off (actions lie in [-1, 1]²; the
            expert data carry Gaussian action noise of std 0.2). The defaults separate a
            repeated task from a new one on the PointMaze streams (measured on their runs).
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
        eps_high: float = 0.5,
        eps_low: float = 1.0,
        delta: float = 0.1,
        n_candidates: int = 1024,
        n_batches: int = 4,
        survivors: int | None = 32,
        probe_samples: int = 256,
        precision: Literal["auto", "32", "bf16"] = "auto",
        seed: int = 0,
    ):
        self.eps = {"high": eps_high, "low": eps_low}
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
    def _transfer(self, trainer: L.Trainer, module) -> list[ZeroShotDecision]:
        dm = trainer.datamodule
        device = module.device
        batches = dm.fixed_batches(self.n_batches, self.seed, device=device)
        probe = {k: v[: self.probe_samples] for k, v in batches[0].items()}
        precision = resolve_precision(self.precision, device)
        generator = torch.Generator().manual_seed(self.seed)
        decisions = []
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
                rates, eps, accepted = {}, {}, True
                for policy in distances[0]:
                    d = torch.cat([dist[policy] for dist in distances])
                    eps[policy] = self.eps.get(policy, max(self.eps.values()))
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
                        anchors=k,
                        alpha=best.tolist(),
                    )
                )
        return decisions


def _check_before_extension(callbacks: list[L.Callback], transfer: ZeroShotTransfer) -> None:
    pos = {id(cb): i for i, cb in enumerate(callbacks)}
    for cb in callbacks:
        if isinstance(cb, AnchorExtension) and pos[id(cb)] < pos[id(transfer)]:
            raise ValueError("list ZeroShotTransfer before AnchorExtension: it decides first")
