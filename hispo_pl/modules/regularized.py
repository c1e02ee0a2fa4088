"""Fine-tuning with a quadratic penalty towards earlier tasks' weights: L2 and EWC.

Both penalties have the form ``c · Σ_{j<t} Σ_i F_{j,i} (θ_i − θ*_{j,i})²`` with ``F_j = 1`` (L2,
``c = λ``) or the empirical Fisher of task ``j`` (EWC, ``c = λ / 2``). A sum of quadratics is
one quadratic, so instead of one copy of the weights (and one Fisher) per task the module keeps
its exact sufficient statistics: the summed importance ``A = Σ_j F_j``, the importance-weighted
centre ``μ = Σ_j F_j θ*_j / A`` and the constant ``C = Σ_j Σ_i F_{j,i} (θ*_{j,i} − μ_i)²``, so
that ``Σ_j Σ_i F_{j,i} (θ_i − θ*_{j,i})² = Σ_i A_i (θ_i − μ_i)² + C`` holds exactly, with storage
independent of the number of tasks (L2's ``A`` is one number per task count, EWC's a vector).
"""

from __future__ import annotations

from typing import Literal, Protocol, runtime_checkable

import torch
from torch import Tensor, nn
from torch.func import functional_call, grad, vmap

from .columns import NetworkPerTask

Penalty = Literal["l2", "ewc"]


@runtime_checkable
class ConsolidatingPolicy(Protocol):
    """What :class:`~hispo_pl.callbacks.WeightConsolidation` needs from a module."""

    needs_fisher: bool

    def consolidate(self, batches: list[dict[str, Tensor]]) -> None: ...


def flat_parameters(module: nn.Module) -> Tensor:
    """All parameters of ``module`` as one vector (differentiable)."""
    return torch.cat([p.reshape(-1) for p in module.parameters()])


class _LossOf(nn.Module):
    """``forward(batch) = net.losses(batch)["loss"]``, for :func:`torch.func.functional_call`."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net

    def forward(self, batch: dict[str, Tensor]) -> Tensor:
        return self.net.losses(batch)["loss"]


def empirical_fisher(net: nn.Module, batches: list[dict[str, Tensor]], chunk: int = 256) -> Tensor:
    """Diagonal empirical Fisher of ``net`` (flattened like :func:`flat_parameters`): the mean
    over every sample of ``batches`` of the squared per-sample gradient of the loss (the
    negative log-likelihood of the expert's labels), dropout off. Per-sample gradients come from
    ``vmap(grad(...))``; a batch-mean gradient squared would underestimate it."""
    wrapper = _LossOf(net)
    params = {k: v.detach() for k, v in wrapper.named_parameters()}

    def sample_loss(p: dict[str, Tensor], sample: dict[str, Tensor]) -> Tensor:
        return functional_call(wrapper, p, ({k: v.unsqueeze(0) for k, v in sample.items()},))

    per_sample = vmap(grad(sample_loss), in_dims=(None, 0))
    total, count = None, 0
    was_training = net.training
    net.eval()
    try:
        for batch in batches:
            n = len(batch["action"])
            for start in range(0, n, chunk):
                part = {k: v[start : start + chunk] for k, v in batch.items()}
                grads = per_sample(params, part)
                sq = torch.cat([g.pow(2).sum(0).reshape(-1) for g in grads.values()])
                total = sq if total is None else total + sq
                count += len(part["action"])
    finally:
        net.train(was_training)
    if total is None:
        raise ValueError("empirical_fisher needs at least one non-empty batch")
    return total / count


def merge_quadratics(
    importance: Tensor, centre: Tensor, constant: Tensor, new_importance: Tensor, new_centre: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Sufficient statistics of ``Σ A (θ − μ)² + C + Σ F (θ − θ*)²`` as ``(A', μ', C')``.

    ``A`` may be empty (no earlier task) and ``A``/``F`` may be a single number (uniform
    importance, L2), broadcast over the parameters. Where ``A' = 0`` the centre is ``θ*``.
    """
    if importance.numel() == 0:
        return new_importance.clone(), new_centre.clone(), constant.new_zeros(())
    total = importance + new_importance
    safe = torch.where(total > 0, total, torch.ones_like(total))
    merged = torch.where(
        total > 0, (importance * centre + new_importance * new_centre) / safe, new_centre
    )
    extra = (importance * (centre - merged).pow(2)).sum() + (
        new_importance * (new_centre - merged).pow(2)
    ).sum()
    return total, merged, constant + extra


class RegularizedFineTuning(NetworkPerTask):
    """FT1 plus a quadratic penalty towards every earlier task's weights: L2 or EWC.

    Args:
        penalty: ``l2`` (λ Σ_j ‖θ − θ*_j‖²) or ``ewc`` (λ/2 Σ_j Σ F_j (θ − θ*_j)², with F_j
            the empirical Fisher of task j, averaged over many samples at the task's end).
        penalty_lambda: λ (the paper's grid: 0.01, 0.1, 1, 10, 100).
        Others as :class:`NetworkPerTask` (``init="previous"``, ``keep="last"``).

    The statistics are buffers: stored, counted in MEM and restored by a checkpoint.
    """

    def __init__(self, *args, penalty: Penalty = "ewc", penalty_lambda: float = 1.0, **kwargs):
        if penalty not in ("l2", "ewc"):
            raise ValueError(f"penalty must be 'l2' or 'ewc', got {penalty!r}")
        super().__init__(*args, init="previous", keep="last", **kwargs)
        self.save_hyperparameters()
        self.remove_ignored_hparams(["init", "keep"])  # fixed here, not arguments
        self.register_buffer("penalty_importance", torch.zeros(0))  # A: [] before task 1 ends
        self.register_buffer("penalty_centre", torch.zeros(0))  # μ
        self.register_buffer("penalty_constant", torch.zeros(()))  # C

    @property
    def needs_fisher(self) -> bool:
        return self.hparams.penalty == "ewc"

    @property
    def penalty_coefficient(self) -> float:
        lam = self.hparams.penalty_lambda
        return lam if self.hparams.penalty == "l2" else lam / 2

    def consolidate(self, batches: list[dict[str, Tensor]]) -> None:
        """At a task's end: fold this task's weights (and Fisher, for EWC) into the penalty."""
        net = self.nets[-1]
        theta = flat_parameters(net).detach()
        importance = empirical_fisher(net, batches) if self.needs_fisher else theta.new_ones(1)
        self.penalty_importance, self.penalty_centre, self.penalty_constant = merge_quadratics(
            self.penalty_importance,
            self.penalty_centre,
            self.penalty_constant,
            importance,
            theta,
        )

    def penalty(self) -> Tensor:
        """``c · (Σ A (θ − μ)² + C)``; zero before the first task has ended."""
        if self.penalty_centre.numel() == 0:
            return self.penalty_constant.new_zeros(())
        theta = flat_parameters(self.nets[-1])
        quad = (self.penalty_importance * (theta - self.penalty_centre).pow(2)).sum()
        return self.penalty_coefficient * (quad + self.penalty_constant)

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        out = super().losses(batch)
        if self.penalty_centre.numel():
            out["penalty"] = self.penalty()
            out["loss"] = out["loss"] + out["penalty"]
        return out

    def restore_structure(self, state_dict: dict[str, Tensor]) -> None:
        super().restore_structure(state_dict)
        for name in ("penalty_importance", "penalty_centre"):
            setattr(self, name, torch.zeros_like(state_dict[name]))
