"""HiSPO's search at a task's end (:class:`DirichletEvaluation`): the best weights of the
previous subspace and of the grown one, which :class:`~hispo_pl.callbacks.SubspacePruning`
decides between. The candidates are raced by :mod:`hispo_pl.race`."""

from __future__ import annotations

import math
from typing import Literal

import lightning as L
import torch
from torch import Tensor
from typing_extensions import override

from ..decisions import (
    extended_subspace_candidates,
    previous_subspace_candidates,
    stored_task_points,
)
from ..errors import TrainingDivergedError
from ..nn import eval_mode
from ..progress import ProgressPrinter
from ..race import RaceOutcome, race_subspace, resolve_precision
from ..results import SearchResult
from ..rundir import RunDir, task_label
from .protocols import SearchableSubspaces, WeightedSubspaces, require_subspaces
from .state import KeyedState


def _refine(result: SearchResult, candidates: Tensor, race: RaceOutcome) -> None:
    """The best of the grown subspace replaces the trained weights if its loss is lower."""
    if race.best_loss < result.l_curr:
        result.l_trained = result.l_curr
        result.l_curr, result.alpha_curr = race.best_loss, candidates[race.best].tolist()


def refuse_non_finite(results: dict[str, SearchResult], task_index: int) -> None:
    """Stop the task, rather than decide on it, when a search loss is NaN or infinite (every
    comparison with NaN is false, so a decision on one would look like a real one)."""
    for name, res in results.items():
        for label, value in (("L_curr", res.l_curr), ("L_prev", res.l_prev)):
            if value is not None and not math.isfinite(value):
                raise TrainingDivergedError(
                    f"the search at the end of task {task_label(task_index)} scored {label} = "
                    f"{value} on the {name} subspace's held-out episodes: no decision is taken "
                    "on it and nothing of this task was saved. Check the task's data and lower "
                    "the learning rate (--model.init_args.optim.lr)."
                )


def window_start(max_steps: int, window: float) -> int | None:
    """The step after which a task's last ``window`` share of steps begins (None: no window,
    e.g. a run bounded by epochs or a zero window)."""
    if max_steps is None or max_steps <= 0 or window <= 0:
        return None
    return max(max_steps - max(round(window * max_steps), 1), 0)


class DirichletEvaluation(KeyedState):
    """At the end of a task, search the previous anchors of each subspace for the best weights.

    ``n_candidates`` Dirichlet(1) draws are raced (:func:`hispo_pl.race.race_candidates`):
    all are ranked on a probe of ``probe_samples`` samples, and the ``survivors`` best are
    scored on ``n_batches`` batches of the current task's held-out episodes (see
    ``TaskDataModule.holdout``), the same batches for every candidate (common random numbers),
    in eval mode with deterministic predictions, chunks of candidates in one batched forward.
    The trained weights (softmax of the scores) are scored on the same batches. The chosen
    points are also scored on training batches (``l_curr_train``, ``l_prev_train``), so that a
    record shows how much of a loss is generalisation. Results go to the module's task record
    (``task_record.searches``) for :class:`~hispo_pl.callbacks.SubspacePruning`, and the
    losses to the run directory (:meth:`~hispo_pl.rundir.RunDir.write_search`).

    Convergence: when the last ``convergence_window`` share of a task's steps begins,
    ``L_curr`` is measured once more; ``improvement = L_window / L_curr − 1`` says how much the
    current point was still improving at the end of training. Above the pruning tolerance the
    decision is made by the step budget rather than by the task (SubspacePruning warns).

    Args:
        n_candidates: Dirichlet draws per subspace.
        n_batches: batches of the current task the survivors are scored on.
        survivors: candidates kept after the probe; ``None`` scores every candidate on every
            batch (exhaustive: every candidate costs what a survivor does).
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
        stored_points: also race, for ``L_prev``, the weights every earlier task acts with,
            each scored on every batch whatever its probe rank. A task that repeats an earlier
            one then finds that task's own point, however many anchors the subspace holds
            (Dirichlet(1) draws over many anchors almost never land near it). Not in the paper
            or the authors' code; the default leaves the search as theirs.
    """

    # the arguments that tell two instances apart: its checkpoint entry's key
    state_args = (
        "n_candidates",
        "n_batches",
        "survivors",
        "probe_samples",
        "loss",
        "precision",
        "seed",
        "every_n_steps",
        "refine_current",
        "convergence_window",
    )

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
        stored_points: bool = False,
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
        self.stored_points = stored_points
        self._l_window: dict[str, float] = {}  # L_curr per subspace when the window opened

    @override
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        require_subspaces(pl_module, SearchableSubspaces, type(self).__name__)
        if self.stored_points:
            require_subspaces(pl_module, WeightedSubspaces, f"{type(self).__name__}(stored_points)")
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
        results = self._run_search(trainer, pl_module, train_losses=True, progress=True)
        refuse_non_finite(results, pl_module.task_index)
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
        progress: bool = False,
    ) -> dict[str, SearchResult]:
        """``L_curr`` (and with ``prev``, ``L_prev``) of every trained subspace on held-out
        batches; with ``train_losses`` the chosen points are scored on training batches too;
        with ``progress`` the scored batches are counted (:mod:`hispo_pl.progress`)."""
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
        names = [n for n in module.subspace_names if not module.transferred(n)]
        scored = len(batches), len(train_batches or [])
        total = sum(self._batches_scored(module.n_anchors(n), prev, *scored) for n in names)
        label = f"task {task_label(module.task_index)}: searching {', '.join(names)}"
        counter = ProgressPrinter(label, total, "batches", enabled=progress)
        with module.task_record.timed("search"), eval_mode(module), counter:
            for name in names:  # a transferred one (zero-shot) has nothing trained to compare

                def race(cands, probe=probe, name=name, batches=batches, seeded=0):
                    return race_subspace(
                        module,
                        name,
                        cands,
                        batches,
                        probe,
                        self.survivors,
                        self.loss,
                        precision,
                        counter.update,
                        seeded,
                    )

                alpha_curr = module.current_alpha(name).to(device)
                l_curr = race(alpha_curr[None], probe=None).best_loss
                result = SearchResult(l_curr=l_curr, alpha_curr=alpha_curr.tolist())
                k = module.n_anchors(name)
                cands, outcome = None, None
                if k > 1 and prev:
                    cands = previous_subspace_candidates(self.n_candidates, k, generator)
                    stored = self._stored(module, name, k)
                    cands = torch.cat([stored, cands]).to(device)
                    outcome = race(cands, seeded=len(stored))
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

    def _stored(self, module, name: str, anchors: int) -> Tensor:
        """The earlier tasks' points raced first (none unless ``stored_points``, and none with
        one previous anchor, whose only point is already the candidate)."""
        if not self.stored_points or anchors < 3:
            return torch.zeros(0, anchors)
        rows = module.task_alphas(name).detach().cpu().float()
        return stored_task_points(rows, module.task_index)

    def _batches_scored(self, anchors: int, prev: bool, held_out: int, train: int) -> int:
        """How many batches (and probes) one subspace's search scores, what its progress
        counts: ``L_curr`` on the ``held_out`` batches, each race of candidates on a probe and
        on them, the chosen points on the ``train`` batches."""

        def race(candidates: int) -> int:  # a probe when it leaves some out, then the batches
            return int(self.survivors is not None and self.survivors < candidates) + held_out

        total = held_out + train
        if anchors > 1 and prev:  # one previous anchor: a single point
            total += race(1 if anchors == 2 else self.n_candidates)
        if anchors > 1 and self.refine_current:
            total += race(self.n_candidates + 2)
        return total

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
