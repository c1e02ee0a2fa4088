"""Pure decision rules of HiSPO, kept apart from the hooks that apply them. Torch is imported
by the rules that draw candidates, so the benchmark's reports (which read the loss rules)
start without it."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch
    from torch import Tensor


def tolerance_problem(eps: object) -> str | None:
    """Why ``eps`` is no tolerance (of a pruning rule, a critic rule, a zero-shot test), or
    None: the one check of an ε, whether a rule gets it or a configuration gives it."""
    number = isinstance(eps, int | float) and not isinstance(eps, bool)
    return None if number and eps >= 0 else "must be >= 0"  # NaN fails eps >= 0


def _check_tolerance(eps: float) -> None:
    if tolerance_problem(eps) is not None:
        raise ValueError(f"eps must be non-negative, got {eps}")


def resolved_tolerance(name: str, given: Mapping[str, float], family: Mapping[str, float]) -> float:
    """The tolerance of ``name`` (a subspace or a policy): the one ``given``, else the task
    family's, else the largest given, else the family's smallest.

    Example:
        >>> resolved_tolerance("low", {}, {"high": 0.1, "low": 0.6})
        0.6
        >>> resolved_tolerance("policy", {"low": 0.2}, {"high": 0.1, "low": 0.6})
        0.2
    """
    if name in given:
        return given[name]
    if name in family:
        return family[name]
    return max(given.values()) if given else min(family.values())


def keep_previous(l_prev: float, l_curr: float, eps: float) -> bool:
    """Prune the new anchor iff the best point of the previous subspace is nearly as good:
    ``L_prev <= (1 + eps) * L_curr``, on positive losses."""
    if l_prev < 0 or l_curr < 0:
        raise ValueError(f"the rule compares positive losses, got L_prev={l_prev}, L_curr={l_curr}")
    _check_tolerance(eps)
    return l_prev <= (1.0 + eps) * l_curr


def critic_extends(w_new: float, w_old: float, eps: float) -> bool:
    """CSP's rule: keep the new anchor iff the critic values the best point of the grown
    subspace clearly above the best of the previous one, ``W_new > (1 + eps) · W_old``.

    Written for values of any sign as ``W_new > W_old + eps · |W_old|``: the paper's form
    when ``W_old >= 0`` (a sparse reward in [0, 1] gives non-negative values, but a learned
    critic may dip below 0), and still "better by a share eps of the old value's size" when
    ``W_old < 0``, where ``(1 + eps) · W_old`` would ask for less than ``W_old`` itself.
    """
    _check_tolerance(eps)
    return w_new > w_old + eps * abs(w_old)


def decided_by_budget(improvement: float | None, eps: float) -> bool:
    """Whether the newest anchor was still improving by more than the tolerance over the
    last window of its training (``improvement = L_window / L_curr − 1``): a longer budget
    could then flip the decision, so it reflects the step budget rather than the task."""
    return improvement is not None and improvement > eps


def previous_subspace_candidates(
    n: int, n_anchors: int, generator: torch.Generator | None = None
) -> Tensor:
    """Candidate weights over the previous anchors (all but the newest, which gets 0):
    Dirichlet(1) draws, shape [n, n_anchors]. With one previous anchor the only point is
    [1, 0, ...], returned once."""
    import torch

    from .nn.simplex import sample_dirichlet

    if n_anchors < 2:
        raise ValueError("the previous subspace needs a newest anchor to leave out")
    if n_anchors == 2:
        return torch.tensor([[1.0, 0.0]])
    draws = sample_dirichlet(n, n_anchors - 1, generator)
    return torch.cat([draws, torch.zeros(n, 1)], dim=1)


def stored_task_points(task_alphas: Tensor, n_tasks: int) -> Tensor:
    """The weights the first ``n_tasks`` tasks act with, as points of the previous subspace
    (rows of ``task_alphas`` [tasks, K], whose newest anchor is 0 for every earlier task), each
    once, in task order: shape [m, K]. A task that repeats an earlier one finds that task's own
    point among them; a Dirichlet(1) draw over many anchors rarely lands near one."""
    import torch

    rows = task_alphas[:n_tasks]
    rows = rows[rows[:, -1] == 0] if rows.shape[1] > 1 else rows[:0]
    kept: list[Tensor] = []
    for row in rows:
        if not any(torch.equal(row, k) for k in kept):
            kept.append(row)
    return torch.stack(kept) if kept else rows[:0]


def extended_subspace_candidates(
    n: int, trained: Tensor, generator: torch.Generator | None = None
) -> Tensor:
    """Candidate weights over every anchor of a grown subspace, to refine the trained weights:
    the trained weights first, then the newest anchor alone, then ``n`` Dirichlet(1) draws;
    shape [n + 2, K]. Training mixes the new anchor at weight ~1/K at first and the scores move
    slowly, so on short budgets points nearer the new anchor often fit the task better."""
    import torch

    from .nn.simplex import sample_dirichlet

    k = trained.shape[-1]
    vertex = torch.zeros(1, k, device=trained.device)
    vertex[0, -1] = 1.0
    draws = sample_dirichlet(n, k, generator).to(trained.device)
    return torch.cat([trained.reshape(1, k), vertex, draws])


def pac_rate(distances: Tensor, eps: float) -> float:
    """Empirical ``P[d(a, â) <= eps]``: the fraction of samples predicted within ``eps``."""
    if distances.numel() == 0:
        raise ValueError("the PAC criterion needs at least one sample")
    _check_tolerance(eps)
    return int((distances <= eps).sum()) / distances.numel()


def zero_shot(distances: Tensor, eps: float, delta: float) -> bool:
    """The paper's PAC criterion: the previous subspace's best policy needs no new anchor when
    ``P[d(a, â) <= eps] >= 1 - delta`` on the new task's data."""
    if not 0.0 <= delta <= 1.0:
        raise ValueError(f"delta must be in [0, 1], got {delta}")
    return pac_rate(distances, eps) >= 1.0 - delta
