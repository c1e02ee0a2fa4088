"""Progressive networks (Rusu et al., 2016): one residual-MLP column per task, with lateral
adapters from every earlier column into every layer of the newer ones.

Column ``k`` has the layers of :class:`~hispo_pl.nn.mlp.ResidualMLP`. Each of its linear
layers after the input layer (the residual block's two linears and the head) adds
``Σ_{j<k} U_{k,j} h_j`` to its output, where ``h_j`` is column ``j``'s activation at the same
point (the input that column's own linear sees). The input layer has no lateral: every column
sees the same input. Earlier columns are run under ``torch.no_grad()``: they are frozen
feature extractors, and what task ``j`` acts with (column ``j`` and its laterals from columns
``< j``) never changes once a later column exists.

Choices:

- A lateral is linear with no bias: ``U_{k,j}`` is ``Linear(hidden, out, bias=False)``. The
  ``k`` adapters of one point are stored as one ``Linear(k · hidden, out, bias=False)`` over
  the concatenated activations (the same map and parameter count, one matmul instead of
  ``k``). The original PNN uses small MLP adapters; the reference notes ask for lateral
  adapters at every layer, which a linear map is at the least cost.
- Laterals start at zero: a new column starts exactly as a freshly initialised, independent
  network (SCN's start), so transfer is learned, never imposed as noise. Zeros do not stall
  learning: the gradient of ``U_{k,j}`` is ``δ h_jᵀ``, non-zero from the first step.
- Dropout runs in every column in training mode, so each trainable linear (own or lateral)
  sees dropped-out inputs, as in a plain network; acting (eval mode) is deterministic.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import torch
from torch import Tensor, nn

from .mlp import GaussianPolicy, ResidualMLP
from .residual import residual_mlp_maths

LATERAL_POINTS = ("block_first", "block_second", "head")
"""The linear layers of a column that get laterals, in forward order."""


class Laterals(nn.Module):
    """The lateral adapters into one column from the ``sources`` columns before it: one
    bias-free linear per receiving layer over the sources' concatenated activations."""

    def __init__(self, sources: int, hidden: int, out_dim: int):
        super().__init__()
        self.sources = sources
        self.block_first = nn.Linear(sources * hidden, hidden, bias=False)
        self.block_second = nn.Linear(sources * hidden, hidden, bias=False)
        self.head = nn.Linear(sources * hidden, out_dim, bias=False)
        for layer in (self.block_first, self.block_second, self.head):
            nn.init.zeros_(layer.weight)


class ProgressiveMLP(nn.Module):
    """Columns of :class:`ResidualMLP` with laterals; ``forward(x, column)`` runs columns
    ``0..column`` (the newest by default) and returns ``column``'s output.

    Example:
        >>> net = ProgressiveMLP(3, 8, 2, dropout=0.0)
        >>> net.add_column()
        >>> net(torch.zeros(5, 3)).shape, net.n_columns
        (torch.Size([5, 2]), 2)
    """

    def __init__(self, in_dim: int, hidden: int, out_dim: int, dropout: float = 0.1):
        super().__init__()
        self.in_dim, self.hidden, self.out_dim, self.dropout = in_dim, hidden, out_dim, dropout
        self.columns = nn.ModuleList([self._new_column()])
        self.laterals = nn.ModuleList()  # laterals[k - 1] feeds column k (k >= 1)

    def _new_column(self) -> ResidualMLP:
        return ResidualMLP(self.in_dim, self.hidden, self.out_dim, self.dropout)

    @property
    def n_columns(self) -> int:
        return len(self.columns)

    def add_column(self) -> None:
        """Append a freshly initialised column and its (zero) laterals from every earlier
        column, on the device of the existing ones."""
        device = self.columns[0].head.weight.device
        k = self.n_columns
        self.columns.append(self._new_column().to(device))
        self.laterals.append(Laterals(k, self.hidden, self.out_dim).to(device))

    def column_parameters(self, column: int) -> Iterator[nn.Parameter]:
        """Parameters that belong to ``column``: its own layers and its laterals."""
        yield from self.columns[column].parameters()
        if column > 0:
            yield from self.laterals[column - 1].parameters()

    def forward(self, x: Tensor, column: int | None = None) -> Tensor:
        last = self.n_columns - 1 if column is None else column
        if not 0 <= last < self.n_columns:
            raise IndexError(f"column {column} does not exist ({self.n_columns} columns)")
        # activations of the columns run so far at each lateral point, in column order
        features: tuple[list[Tensor], list[Tensor], list[Tensor]] = ([], [], [])
        with torch.no_grad():
            for j in range(last):
                self._column_forward(j, x, features)
        return self._column_forward(last, x, features)

    def _column_forward(
        self, j: int, x: Tensor, features: tuple[list[Tensor], list[Tensor], list[Tensor]]
    ) -> Tensor:
        """Column ``j``'s output, given the earlier columns' ``features``; appends its own."""
        col = self.columns[j]
        lat = self.laterals[j - 1] if j > 0 else None

        def with_lateral(layer: nn.Linear, point: int) -> Callable[[Tensor], Tensor]:
            """``layer`` plus the laterals from the earlier columns' activations at ``point``;
            records this column's own."""

            def linear(h: Tensor) -> Tensor:
                y = layer(h)
                if lat is not None:
                    adapter = getattr(lat, LATERAL_POINTS[point])
                    y = y + adapter(torch.cat(features[point], dim=-1))
                features[point].append(h)
                return y

            return linear

        first, *rest = col.linears()
        linears = [first, *(with_lateral(layer, p) for p, layer in enumerate(rest))]
        return residual_mlp_maths(x, linears, col.norms(), col.drops())


class ProgressivePolicy(GaussianPolicy):
    """A Gaussian policy over a :class:`ProgressiveMLP`; ``column`` picks the column acting."""

    network = ProgressiveMLP

    def forward(self, x: Tensor, column: int | None = None) -> tuple[Tensor, Tensor]:
        return self.distribution(self.net(x, column))


def column_parameter_count(in_dim: int, hidden: int, out_dim: int) -> int:
    """Parameters of one column (= one :class:`ResidualMLP`): three linears, three LayerNorms
    and the head, ``2h² + h(in + out + 9) + out``."""
    return 2 * hidden * hidden + hidden * (in_dim + out_dim + 9) + out_dim


def lateral_parameter_count(hidden: int, out_dim: int) -> int:
    """Parameters of the laterals from one earlier column into a newer one, ``2h² + h·out``."""
    return 2 * hidden * hidden + hidden * out_dim


def progressive_parameter_count(columns: int, in_dim: int, hidden: int, out_dim: int) -> int:
    """Parameters of a :class:`ProgressiveMLP` of ``columns`` columns: the columns plus
    ``columns · (columns − 1) / 2`` lateral sets (quadratic in the number of tasks)."""
    pairs = columns * (columns - 1) // 2
    return columns * column_parameter_count(in_dim, hidden, out_dim) + pairs * (
        lateral_parameter_count(hidden, out_dim)
    )
