"""Continual-learning stream metrics (PER, BWT, FWT, MEM): one table, :data:`METRICS`, that
the loop, the console, the loggers and the report tables all read.

Kept pure (numpy only; torch is imported lazily by :func:`module_bytes`) so the numbers in
tables can be recomputed from saved results without a model, an environment or a GPU.

Convention: ``R[i, k]`` is the success on task ``k`` measured after training task ``i``
(0-based). Entries with ``k > i`` (tasks not trained yet) may be NaN and are ignored by every
metric. Values stay in the units of ``R`` (fractions 0-1); multiply by 100 for tables.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    import torch

UNKNOWN = "·"
"""Placeholder printed for entries that were not measured (NaN) in :func:`results_row_table`."""


def _results_matrix(R: ArrayLike) -> np.ndarray:
    """``R`` as a float N×N array, checked square and finite on/below the diagonal.

    Only the lower triangle (incl. diagonal) enters the metrics, so only it must be known.
    """
    arr = np.asarray(R, dtype=float)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"R must be a square N×N matrix, got shape {arr.shape}")
    n = arr.shape[0]
    if n == 0:
        raise ValueError("R must contain at least one task (got a 0×0 matrix)")
    lower = np.tril_indices(n)
    bad = ~np.isfinite(arr[lower])
    if bad.any():
        i, k = lower[0][bad][0], lower[1][bad][0]
        raise ValueError(
            f"R must be finite on and below the diagonal; R[{i}, {k}] = {arr[i, k]} "
            f"({int(bad.sum())} non-finite entr{'y' if bad.sum() == 1 else 'ies'})"
        )
    return arr


def _scratch_vector(R_scratch: ArrayLike, n: int) -> np.ndarray:
    """Per-task from-scratch success as a length-``n`` vector (diagonal if given as a matrix).

    The paper writes ``R_scratch[k, k]``, so both the vector and the matrix form are accepted.
    """
    arr = np.asarray(R_scratch, dtype=float)
    if arr.ndim == 2:
        if arr.shape != (n, n):
            raise ValueError(f"R_scratch as a matrix must be {n}×{n} like R, got shape {arr.shape}")
        arr = np.diagonal(arr)
    elif arr.ndim != 1:
        raise ValueError(
            f"R_scratch must be a length-{n} vector or an {n}×{n} matrix, got shape {arr.shape}"
        )
    if arr.shape[0] != n:
        raise ValueError(f"R_scratch must have length N={n} (one per task), got {arr.shape[0]}")
    if not np.isfinite(arr).all():
        raise ValueError(f"R_scratch must be finite, got {arr.tolist()}")
    return arr


@dataclass(frozen=True)
class Measures:
    """What the stream metrics are functions of: ``R`` (checked, NaN above the diagonal), the
    per-task success of from-scratch models (FWT's reference) and, where the model is at
    hand (the loop), its stored bytes and those of one single-task model."""

    R: np.ndarray
    scratch: np.ndarray | None = None
    stored_bytes: int | None = None
    reference_bytes: int | None = None

    @property
    def final(self) -> np.ndarray:
        return self.R[-1]

    @property
    def diagonal(self) -> np.ndarray:
        return np.diagonal(self.R)


@dataclass(frozen=True)
class Metric:
    """A stream metric: its name (the key in ``results.json``, the column of the tables, the
    ``stream/<name>`` tag), its function of :class:`Measures` (None where it cannot be had),
    the scale and decimals it is printed at, and a line of what it means.

    ``of_model``: measured on the trained model (MEM): computed by the loop, which has the
    model, and read back from ``results.json`` everywhere else."""

    name: str
    compute: Callable[[Measures], float | None]
    scale: float
    digits: int
    doc: str
    of_model: bool = False

    def format(self, value: float) -> str:
        """``81.0``: the value as the console and the tables print it."""
        return f"{self.scale * value:.{self.digits}f}"

    @property
    def percent(self) -> bool:
        """A success fraction (or a difference of two), printed ×100."""
        return self.scale == 100


def _mem(m: Measures) -> float | None:
    if m.stored_bytes is None or not m.reference_bytes:
        return None
    return memory_ratio(m.stored_bytes, m.reference_bytes)


METRICS: tuple[Metric, ...] = (
    Metric("PER", lambda m: float(m.final.mean()), 100, 1, "final success over all tasks"),
    Metric(
        "BWT",
        lambda m: float((m.final - m.diagonal).mean()),
        100,
        1,
        "change since each task was learned (negative: forgetting)",
    ),
    Metric(
        "FWT",
        lambda m: None if m.scratch is None else float((m.diagonal - m.scratch).mean()),
        100,
        1,
        "gain over single-task models trained from scratch",
    ),
    Metric("MEM", _mem, 1, 2, "stored size over one single-task model", of_model=True),
)
"""Every stream metric, in the order files, tables, the console and the loggers show them."""

METRIC = {m.name: m for m in METRICS}


def mean_std(values: ArrayLike) -> tuple[float, float]:
    """Mean and population standard deviation, as the paper's tables report runs over seeds."""
    arr = np.asarray(values, dtype=float)
    return float(arr.mean()), float(arr.std())


def continual_metrics(
    R: ArrayLike,
    R_scratch: ArrayLike | None = None,
    stored_bytes: int | None = None,
    reference_bytes: int | None = None,
) -> dict[str, float]:
    """Every metric of :data:`METRICS` the inputs give, by name, in table order: PER, BWT,
    FWT (when ``R_scratch`` is given), MEM (when both sizes are).

    - ``PER = 1/N Σ_k R[N-1, k]``: final performance over all tasks.
    - ``BWT = 1/N Σ_k (R[N-1, k] - R[k, k])``: change since each task was learned
      (negative = forgetting; the last task contributes 0).
    - ``FWT = 1/N Σ_k (R[k, k] - R_scratch[k])``: gain over a single-task model trained from
      scratch; omitted from the dict (not NaN) without ``R_scratch`` so callers cannot
      mistake a missing baseline for a number.
    - ``MEM``: :func:`memory_ratio`.
    """
    arr = _results_matrix(R)
    scratch = None if R_scratch is None else _scratch_vector(R_scratch, arr.shape[0])
    measures = Measures(arr, scratch, stored_bytes, reference_bytes)
    found = {m.name: m.compute(measures) for m in METRICS}
    return {name: value for name, value in found.items() if value is not None}


def memory_ratio(stored_bytes: int, reference_bytes: int) -> float:
    """MEM = stored bytes / bytes of one single-task model, so 1.0 means "as big as one model"."""
    if reference_bytes <= 0:
        raise ValueError(f"reference_bytes must be positive, got {reference_bytes}")
    if stored_bytes < 0:
        raise ValueError(f"stored_bytes must be non-negative, got {stored_bytes}")
    return stored_bytes / reference_bytes


@runtime_checkable
class KeepsDecisionState(Protocol):
    """A module that stores state used only to make its decisions, never to act (CSP's
    critic): it travels in checkpoints but is not part of the model MEM measures."""

    def decision_only_state(self) -> tuple[str, ...]:
        """Prefixes of the parameter and buffer names to leave out (e.g. ``("critic.",)``)."""
        ...


def module_bytes(module: torch.nn.Module, include_buffers: bool = True) -> int:
    """Bytes held by a module's parameters (and buffers): Σ numel × element_size.

    Buffers (e.g. normalisation statistics, subspace anchors kept as buffers) are part of what
    must be stored per model, hence counted by default. What a module declares decision-only
    (:class:`KeepsDecisionState`, e.g. CSP's critic) is left out: MEM measures the policy
    that acts on every task, as the paper's CSP counts its policy anchors only.
    """
    skip = module.decision_only_state() if isinstance(module, KeepsDecisionState) else ()
    named = list(module.named_parameters())
    if include_buffers:
        named += list(module.named_buffers())
    return int(sum(t.numel() * t.element_size() for name, t in named if not name.startswith(skip)))


def results_row_table(R: ArrayLike) -> str:
    """Plain-text table of ``R`` × 100 (one decimal), one row per "after T.." training step.

    Unmeasured (NaN) entries print as ``·``. Meant for logs while a stream runs, so it does not
    validate: partially filled matrices are fine as long as ``R`` is 2-D.
    """
    arr = np.asarray(R, dtype=float)
    if arr.ndim != 2:
        raise ValueError(f"R must be a 2-D matrix, got shape {arr.shape}")
    n_rows, n_cols = arr.shape
    digits = max(2, len(str(max(n_rows, n_cols))))
    cols = [f"T{k + 1:0{digits}d}" for k in range(n_cols)]
    labels = [f"after T{i + 1:0{digits}d}" for i in range(n_rows)]
    cells = [[UNKNOWN if not np.isfinite(v) else f"{100 * v:.1f}" for v in row] for row in arr]
    label_w = max((len(s) for s in labels), default=0)
    width = max([len(c) for c in cols] + [len(c) for row in cells for c in row])
    lines = [" " * label_w + "".join(f"  {c:>{width}}" for c in cols)]
    for label, row in zip(labels, cells, strict=True):
        lines.append(f"{label:<{label_w}}" + "".join(f"  {c:>{width}}" for c in row))
    return "\n".join(lines)
