"""HiSPO's callbacks: extend the subspaces at task start, search the previous subspace at task
end, and keep or prune the new anchors (zero-shot transfer before a task: :mod:`.transfer`).
Each hook is thin; the rules live in :mod:`hispo_pl.decisions`."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Literal

import lightning as L
import torch
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_warn
from torch import Tensor
from typing_extensions import override

from ..decisions import (
    decided_by_budget,
    extended_subspace_candidates,
    keep_previous,
    previous_subspace_candidates,
)
from ..modules.hispo import SubspacePolicy
from ..nn import eval_mode
from ..rundir import RunDir, task_label
from ..search import RaceOutcome, race_subspace, resolve_precision
from ..tasks import Family


def require_subspace_policy(pl_module: L.LightningModule, who: str) -> SubspacePolicy:
    if not isinstance(pl_module, SubspacePolicy):
        raise TypeError(
            f"{who} needs a module with subspaces of policies (the SubspacePolicy protocol, e.g. "
            f"hispo_pl.modules.HiSPO), got {type(pl_module).__name__}"
        )
    return pl_module


class AnchorExtension(L.Callback):
    """At the start of every task after the first, add one trainable anchor to each subspace
    (older anchors frozen) before the optimiser is built; stored weights get a 0 appended."""

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        module = require_subspace_policy(pl_module, type(self).__name__)
        if stage != "fit" or module.task_index == 0:
            return
        for name in module.subspace_names:
            if not module.transferred(name) and not module.grown(name):
                module.add_anchor(name)  # (transferred: ZeroShotTransfer chose its weights)


@dataclass
class SearchResult:
    """What the search of one subspace found on the current task. Losses are scored on the
    task's held-out episodes (what the decision uses); ``*_train`` on its training episodes."""

    l_curr: float
    alpha_curr: list[float]
    l_prev: float | None = None
    alpha_prev: list[float] | None = None
    l_trained: float | None = None  # the trained weights' loss, when refine_current moved them
    l_curr_train: float | None = None
    l_prev_train: float | None = None
    l_window: float | None = None  # L_curr when the convergence window opened
    improvement: float | None = None  # relative fall of L_curr over the window (convergence)


def _refine(result: SearchResult, candidates: Tensor, race: RaceOutcome) -> None:
    """The best of the grown subspace replaces the trained weights if its loss is lower."""
    if race.best_loss < result.l_curr:
        result.l_trained = result.l_curr
        result.l_curr, result.alpha_curr = race.best_loss, candidates[race.best].tolist()


def window_start(max_steps: int, window: float) -> int | None:
    """The step after which a task's last ``window`` share of steps begins (None: no window,
    e.g. a run bounded by epochs or a zero window)."""
    if max_steps is None or max_steps <= 0 or window <= 0:
        return None
    return max(max_steps - max(round(window * max_steps), 1), 0)


class DirichletEvaluation(L.Callback):
    """At the end of a task, search the previous anchors of each subspace for the best weights.

    ``n_candidates`` Dirichlet(1) draws are raced (:func:`hispo_pl.search.race_candidates`):
    all are ranked on a probe of ``probe_samples`` samples, and the ``survivors`` best are
    scored on ``n_batches`` batches of the current task's held-out episodes (see
    ``TaskDataModule.holdout``), the same batches for every candidate (common random numbers),
    in eval mode with deterministic predictions, chunks of candidates in one batched forward.
    The trained weights (softmax of the scores) are scored on the same batches. The chosen
    points are also scored on training batches (``l_curr_train``, ``l_prev_train``), so that a
    record shows how much of a loss is generalisation. Results are kept in ``results`` for
    :class:`SubspacePruning`, and the losses saved as ``search/task_XX_<subspace>.npz`` in
    the run directory.

    Convergence: when the last ``convergence_window`` share of a task's steps begins,
    ``L_curr`` is measured once more; ``improvement = L_window / L_curr − 1`` says how much the
    current point was still improving at the end of training. Above the pruning tolerance the
    decision is made by the step budget rather than by the task (SubspacePruning warns).

    Args:
        n_candidates: Dirichlet draws per subspace.
        n_batches: batches of the current task the survivors are scored on.
        survivors: candidates kept after the probe; ``None`` scores every candidate on every
            batch (exhaustive, about 10x slower with the defaults).
        probe_samples: samples (from the first batch) every candidate is ranked on.
        loss: ``mse`` of the deterministic prediction (positive), or ``nll``.
        precision: ``32``, ``bf16`` (autocast; several times faster on CPUs with bf16 units),
            or ``auto``: bf16 where the device supports it natively.
        seed: seeds the batches and the draws.
        every_n_steps: also search every this many training steps (0: only at the end), to
            watch ``L_prev`` against ``L_curr`` while the new anchor learns: logged as
            ``search/<subspace>/l_prev`` and ``l_curr``; nothing is decided or saved then.
        refine_current: also race the grown subspace (the trained weights, the new anchor
            alone and ``n_candidates`` Dirichlet draws over every anchor) and take the best as
            ``alpha_curr`` / ``L_curr``. Not in the paper, which keeps the softmax of the
            trained scores; on short budgets the scores stay near uniform and better points
            lie nearer the new anchor (docs/method.md).
        convergence_window: share of the task's last steps over which the convergence
            diagnostic is measured (0: off).
    """

    def __init__(
        self,
        n_candidates: int = 1024,
        n_batches: int = 16,
        survivors: int | None = 32,
        probe_samples: int = 256,
        loss: Literal["mse", "nll"] = "mse",
        precision: Literal["auto", "32", "bf16"] = "auto",
        seed: int = 0,
        every_n_steps: int = 0,
        refine_current: bool = True,
        convergence_window: float = 0.2,
    ):
        if every_n_steps < 0:
            raise ValueError(
                f"every_n_steps must be >= 0 (0: only at task end), got {every_n_steps}"
            )
        if not 0.0 <= convergence_window < 1.0:
            raise ValueError(f"convergence_window must be in [0, 1), got {convergence_window}")
        self.n_candidates, self.n_batches, self.loss, self.seed = (
            n_candidates,
            n_batches,
            loss,
            seed,
        )
        self.survivors, self.probe_samples, self.precision = survivors, probe_samples, precision
        self.every_n_steps = every_n_steps
        self.refine_current = refine_current
        self.convergence_window = convergence_window
        self._l_window: dict[str, float] = {}  # L_curr per subspace when the window opened

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        require_subspace_policy(pl_module, type(self).__name__)
        self._l_window = {}

    @override
    def state_dict(self) -> dict:
        return {"l_window": dict(self._l_window)}

    @override
    def load_state_dict(self, state_dict: dict) -> None:
        self._l_window = {k: float(v) for k, v in state_dict.get("l_window", {}).items()}

    @override
    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx) -> None:
        step = trainer.global_step
        if step == window_start(trainer.max_steps, self.convergence_window):
            self._l_window = {
                name: res.l_curr
                for name, res in self._run_search(
                    trainer, pl_module, save=False, prev=False
                ).items()
            }
        if not self.every_n_steps or step % self.every_n_steps or step >= trainer.max_steps:
            return  # the last step's search is the task-end one
        metrics = {}
        for name, res in self._run_search(trainer, pl_module, save=False).items():
            metrics[f"{pl_module.log_prefix}search/{name}/l_curr"] = res.l_curr
            if res.l_prev is not None:
                metrics[f"{pl_module.log_prefix}search/{name}/l_prev"] = res.l_prev
        for logger in trainer.loggers:
            logger.log_metrics(metrics, step=step)

    @override
    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        results = self._run_search(trainer, pl_module, train_losses=True)
        for name, res in results.items():
            if name in self._l_window and res.l_curr > 0:
                res.l_window = self._l_window[name]
                res.improvement = res.l_window / res.l_curr - 1.0
        pl_module.task_record.searches = results
        pl_module.task_record.convergence_window = self.convergence_window

    @torch.no_grad()
    def _run_search(
        self,
        trainer: L.Trainer,
        module,
        save: bool = True,
        prev: bool = True,
        train_losses: bool = False,
    ) -> dict[str, SearchResult]:
        """``L_curr`` (and with ``prev``, ``L_prev``) of every trained subspace on held-out
        batches; with ``train_losses`` the chosen points are scored on training batches too."""
        device = module.device
        batches = trainer.datamodule.fixed_batches(self.n_batches, self.seed, device=device)
        train_batches = (
            trainer.datamodule.fixed_batches(
                self.n_batches, self.seed, device=device, split="train"
            )
            if train_losses
            else None
        )
        probe = {k: v[: self.probe_samples] for k, v in batches[0].items()}
        precision = resolve_precision(self.precision, device)
        generator = torch.Generator().manual_seed(self.seed)
        results = {}
        with eval_mode(module):
            for name in module.subspace_names:
                if module.transferred(name):  # zero-shot: nothing was trained to compare
                    continue

                def race(cands, probe=probe, name=name, batches=batches):
                    return race_subspace(
                        module, name, cands, batches, probe, self.survivors, self.loss, precision
                    )

                alpha_curr = module.current_alpha(name).to(device)
                l_curr = race(alpha_curr[None], probe=None).best_loss
                result = SearchResult(l_curr, alpha_curr.tolist())
                k = module.n_anchors(name)
                cands, outcome = None, None
                if k > 1 and prev:
                    cands = previous_subspace_candidates(self.n_candidates, k, generator).to(device)
                    outcome = race(cands)
                    result.l_prev, result.alpha_prev = (
                        outcome.best_loss,
                        cands[outcome.best].tolist(),
                    )
                if k > 1 and self.refine_current:
                    cands_curr = extended_subspace_candidates(
                        self.n_candidates, alpha_curr, generator
                    )
                    _refine(result, cands_curr, race(cands_curr))
                if save and outcome is not None:
                    self._save(trainer, module, name, cands, outcome, result)
                if train_batches is not None:
                    chosen = [result.alpha_curr]
                    if result.alpha_prev is not None:
                        chosen.append(result.alpha_prev)
                    on_train = race(
                        torch.tensor(chosen, device=device), probe=None, batches=train_batches
                    )
                    result.l_curr_train = float(on_train.losses[0])
                    if result.l_prev is not None:
                        result.l_prev_train = float(on_train.losses[1])
                results[name] = result
        return results

    def _save(self, trainer, module, name, cands, race: RaceOutcome, result: SearchResult) -> None:
        probe = {}
        if race.probe_losses is not None:
            probe = {
                "probe_alphas": cands.cpu().numpy(),
                "probe_losses": race.probe_losses.cpu().numpy(),
            }
        RunDir(trainer.default_root_dir).write_search(
            module.task_index,
            name,
            alphas=cands[race.survivors].cpu().numpy(),
            losses=race.losses.cpu().numpy(),
            l_curr=result.l_curr,
            l_trained=result.l_trained if result.l_trained is not None else result.l_curr,
            **probe,
        )


def check_task_end_order(callbacks: list[L.Callback], pruning: L.Callback, search_type: type):
    """Task-end hooks run in list order: the search (an instance of ``search_type``), then
    ``pruning``, then the rollout evaluation that must see the pruned policy."""
    from .rollout import RolloutEvaluation

    pos = {id(cb): i for i, cb in enumerate(callbacks)}
    search = [cb for cb in callbacks if isinstance(cb, search_type)]
    prune, find = type(pruning).__name__, search_type.__name__
    if not search or pos[id(search[0])] > pos[id(pruning)]:
        raise ValueError(f"{prune} needs a {find} callback listed before it")
    if any(
        isinstance(cb, RolloutEvaluation) and pos[id(cb)] < pos[id(pruning)] for cb in callbacks
    ):
        raise ValueError(f"list RolloutEvaluation after {prune}: it must see the pruned policy")


class SubspacePruning(L.Callback):
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

    def __init__(
        self,
        eps_high: float | None = None,
        eps_low: float | None = None,
        eps: dict[str, float] | None = None,
    ):
        given = {"high": eps_high, "low": eps_low, **(eps or {})}
        self.eps = {name: e for name, e in given.items() if e is not None}
        bad = {name: e for name, e in self.eps.items() if not e >= 0}
        if bad:  # checked here, not after a task has trained
            raise ValueError(f"SubspacePruning tolerances must be >= 0, got {bad}")

    def tolerance(self, name: str, family: Family) -> float:
        """ε of subspace ``name`` on a task of ``family``: the one given, else the family's."""
        if name in self.eps:
            return self.eps[name]
        if name in family.pruning_eps:
            return family.pruning_eps[name]
        return max(self.eps.values()) if self.eps else min(family.pruning_eps.values())

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        require_subspace_policy(pl_module, type(self).__name__)
        check_task_end_order(trainer.callbacks, self, DirichletEvaluation)

    @override
    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        searches = pl_module.task_record.searches  # DirichletEvaluation's, just before
        family = trainer.datamodule.task.env_family
        decisions = [
            self._decide(pl_module, name, res, self.tolerance(name, family))
            for name, res in searches.items()
        ]
        pl_module.freeze_all()
        log_decisions(trainer, pl_module, decisions)

    def _decide(self, module, name: str, res: SearchResult, eps: float) -> dict:
        task = module.task_index
        if res.l_prev is None:
            module.set_task_alpha(task, name, torch.tensor(res.alpha_curr))
            action = "first"
        elif keep_previous(res.l_prev, res.l_curr, eps):
            module.prune_last_anchor(name)
            module.set_task_alpha(task, name, torch.tensor(res.alpha_prev[:-1]))
            action = "prune"
        else:
            module.set_task_alpha(task, name, torch.tensor(res.alpha_curr))
            action = "keep"
        if res.l_prev is not None and decided_by_budget(res.improvement, eps):
            rank_zero_warn(
                f"task {task + 1}, {name} subspace ({action}): L_curr still fell by "
                f"{res.improvement:.1%} over the last "
                f"{module.task_record.convergence_window:.0%} of "
                f"the steps, more than eps = {eps}; the step budget, not the task, decided "
                "this. Train longer (--trainer.max_steps) for a decision about the task."
            )
        return {
            "task": task,
            "subspace": name,
            "decision": action,
            "eps": eps,
            "anchors": module.n_anchors(name),
            **asdict(res),
        }


def log_decisions(trainer: L.Trainer, module, decisions: list[dict]) -> None:
    """Append decisions to ``decisions.jsonl`` in the run dir and log them to TensorBoard."""
    RunDir(trainer.default_root_dir).append_decisions(decisions)
    logger = trainer.logger
    if logger is None:
        return
    task = task_label(module.task_index)
    metrics = {f"anchors/{d['subspace']}/count": d["anchors"] for d in decisions}
    for d in decisions:
        if d.get("l_prev") is not None:
            metrics[f"search/{d['subspace']}/L_prev"] = d["l_prev"]
        if d.get("l_curr") is not None:
            metrics[f"search/{d['subspace']}/L_curr"] = d["l_curr"]
        if d.get("l_trained") is not None:  # refine_current replaced the trained weights
            metrics[f"search/{d['subspace']}/L_trained"] = d["l_trained"]
        for key, tag in (
            ("l_curr_train", "L_curr_train"),
            ("l_prev_train", "L_prev_train"),
            ("improvement", "convergence"),
        ):
            if d.get(key) is not None:
                metrics[f"search/{d['subspace']}/{tag}"] = d[key]
        for policy, rate in d.get("pac_rate", {}).items():
            metrics[f"zero_shot/{d['subspace']}/pac_rate_{policy}"] = rate
    logger.log_metrics(metrics, step=task)
    if isinstance(logger, TensorBoardLogger):
        text = "\n".join(
            f"{d['subspace']}: {d['decision']} (anchors {d['anchors']})" for d in decisions
        )
        logger.experiment.add_text("decisions", text, global_step=task)
