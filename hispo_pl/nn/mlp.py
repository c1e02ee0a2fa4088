"""Building blocks of the hierarchical BC backbone: residual MLP, Gaussian head (with optional
Bernoulli entries for gamepad buttons), goal features."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from . import fast
from .residual import residual_mlp_maths


def goal_features(delta: Tensor, eps: float = 1e-6) -> Tensor:
    """Direction features of a displacement: delta, its norm and its unit vector (2·d + 1)."""
    norm = delta.norm(dim=-1, keepdim=True)
    return torch.cat([delta, norm, delta / (norm + eps)], dim=-1)


def feature_dim(goal_dim: int) -> int:
    return 2 * goal_dim + 1


def _init_linear(layer: nn.Linear, scale: float = 0.1) -> None:
    """Variance scaling (uniform, fan_avg, small scale) with zero bias: a quiet start."""
    fan_avg = 0.5 * (layer.in_features + layer.out_features)
    bound = math.sqrt(3.0 * scale / fan_avg)
    nn.init.uniform_(layer.weight, -bound, bound)
    nn.init.zeros_(layer.bias)


class FastDropout(nn.Module):
    """Inverted dropout with the mask drawn from random bytes (:func:`~hispo_pl.nn.fast.
    dropout_masks`), cheaper than ``nn.Dropout``'s Bernoulli sampling on CPU. The drop
    probability is rounded to a multiple of 1/256 (0.1 → 26/256 ≈ 0.102)."""

    def __init__(self, p: float = 0.1):
        super().__init__()
        if not 0.0 <= p < 1.0:
            raise ValueError(f"dropout probability must be in [0, 1), got {p}")
        self.threshold = round(p * 256)
        self.scale = 256.0 / (256 - self.threshold)

    def forward(self, x: Tensor) -> Tensor:
        if not self.training or self.threshold == 0:
            return x
        return x * fast.dropout_masks(1, x.shape, self.threshold, self.scale, x)[0]

    def draw(self, count: int, shape: tuple[int, ...], like: Tensor) -> fast.DropoutDraw | None:
        """One draw for ``count`` masks of ``shape`` on ``like``'s device (the fast path's),
        or ``None`` without dropout."""
        if self.threshold == 0:
            return None
        noise = fast.dropout_bytes(count, shape, like.device)
        return fast.DropoutDraw(noise, self.threshold, self.scale)


class ResidualMLP(nn.Module):
    """:func:`residual_mlp_maths` with ``nn`` layers; the fast path while it trains."""

    def __init__(self, in_dim: int, hidden: int, out_dim: int, dropout: float = 0.1):
        super().__init__()
        self.inp = nn.Sequential(
            nn.Linear(in_dim, hidden), nn.LayerNorm(hidden), nn.GELU(), FastDropout(dropout)
        )
        self.block = nn.Sequential(
            nn.Linear(hidden, hidden),
            nn.LayerNorm(hidden),
            nn.GELU(),
            FastDropout(dropout),
            nn.Linear(hidden, hidden),
            nn.LayerNorm(hidden),
        )
        self.out = nn.Sequential(nn.GELU(), FastDropout(dropout))
        self.head = nn.Linear(hidden, out_dim)
        for m in self.modules():
            if isinstance(m, nn.Linear):
                _init_linear(m)

    def forward(self, x: Tensor) -> Tensor:
        if self.training and torch.is_grad_enabled() and fast.enabled():
            return fast.residual_mlp(x, self.parameter_tensors(), self.train_dropout(x), self.eps())
        return residual_mlp_maths(x, self.linears(), self.norms(), self.drops())

    def linears(self) -> tuple[nn.Linear, ...]:
        """The input layer, the block's two linears and the head."""
        return self.inp[0], self.block[0], self.block[4], self.head

    def norms(self) -> tuple[nn.LayerNorm, ...]:
        return self.inp[1], self.block[1], self.block[5]

    def drops(self) -> tuple[FastDropout, ...]:
        return self.inp[3], self.block[3], self.out[1]

    def parameter_tensors(self) -> list[Tensor]:
        """The 14 tensors :func:`~hispo_pl.nn.fast.residual_mlp` takes, in its order."""
        (l0, l1, l2, head), (n0, n1, n2) = self.linears(), self.norms()
        return [t for layer in (l0, n0, l1, n1, l2, n2, head) for t in (layer.weight, layer.bias)]

    def eps(self) -> tuple[float, float, float]:
        return tuple(norm.eps for norm in self.norms())

    def train_dropout(self, x: Tensor) -> fast.DropoutDraw | None:
        """The step's three dropout masks (input, block, output) in one draw."""
        shape = (*x.shape[:-1], self.inp[0].out_features)
        return self.inp[3].draw(3, shape, x)


def split_gaussian(raw: Tensor, out_dim: int, log_std_min: float, log_std_max: float):
    """Split a head's ``2 * out_dim`` outputs into a mean and a softly clamped log-std (a tanh
    squashed into [min, max] keeps gradients alive at the bounds, unlike a hard clamp)."""
    mean, free = raw.split(out_dim, dim=-1)
    log_std = log_std_min + 0.5 * (log_std_max - log_std_min) * (torch.tanh(free) + 1.0)
    return mean, log_std


class GaussianPolicy(nn.Module):
    """A diagonal Gaussian over ``out_dim`` values with a learned, softly clamped log-std, or a
    fixed one (``fixed_log_std``: the NLL is then a scaled squared error on the mean).
    Subclasses swap the network through ``network`` (e.g. a subspace of networks).

    ``binary`` > 0 makes the first ``binary`` values Bernoulli (gamepad buttons): their
    "mean" is a logit, their log-std is unused; :meth:`nll`, :meth:`act` and
    :meth:`prediction` treat them as such. Keeping one output layout for both kinds lets every
    network (subspaces, columns) serve either head unchanged.
    """

    network: type[nn.Module] = ResidualMLP

    def __init__(
        self,
        in_dim: int,
        hidden: int,
        out_dim: int,
        dropout: float = 0.1,
        log_std_min: float = -5.0,
        log_std_max: float = 1.0,
        fixed_log_std: float | None = None,
        binary: int = 0,
    ):
        super().__init__()
        if not 0 <= binary <= out_dim:
            raise ValueError(f"binary must be in [0, {out_dim}], got {binary}")
        self.out_dim = out_dim
        self.binary = binary
        self.log_std_min, self.log_std_max = log_std_min, log_std_max
        self.fixed_log_std = fixed_log_std
        heads = out_dim if fixed_log_std is not None else 2 * out_dim
        self.net = self.network(in_dim, hidden, heads, dropout)

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        return self.distribution(self.net(x))

    def distribution(self, raw: Tensor) -> tuple[Tensor, Tensor]:
        """Mean and log-std from the network's raw outputs."""
        if self.fixed_log_std is not None:
            return raw, torch.full_like(raw, self.fixed_log_std)
        return split_gaussian(raw, self.out_dim, self.log_std_min, self.log_std_max)

    def nll(self, mean: Tensor, log_std: Tensor, target: Tensor, normalised: bool = True) -> Tensor:
        """Per-sample negative log-likelihood of ``target`` (summed over values), shape
        ``mean.shape[:-1]``: Bernoulli on the binary values, Gaussian on the rest
        (``normalised=False`` leaves out the Gaussian's constant ½·log 2π per value)."""
        b = self.binary
        nll = gaussian_nll_per_sample(mean[..., b:], log_std[..., b:], target[..., b:], normalised)
        if b:
            bce = F.binary_cross_entropy_with_logits(
                mean[..., :b], target[..., :b].expand_as(mean[..., :b]), reduction="none"
            )
            nll = nll + bce.sum(-1)
        return nll

    def loss(self, mean: Tensor, log_std: Tensor, target: Tensor) -> Tensor:
        """Training loss: :meth:`nll` averaged over the batch."""
        return self.nll(mean, log_std, target).mean()

    def prediction(self, mean: Tensor) -> Tensor:
        """The expected value: probabilities for binary values, the mean for the others (what
        squared-error scoring compares with the data)."""
        if not self.binary:
            return mean
        return torch.cat([torch.sigmoid(mean[..., : self.binary]), mean[..., self.binary :]], -1)

    def act(self, mean: Tensor) -> Tensor:
        """The deterministic action: a button is pressed (1) iff its probability exceeds 1/2."""
        if not self.binary:
            return mean
        pressed = (mean[..., : self.binary] > 0).to(mean.dtype)
        return torch.cat([pressed, mean[..., self.binary :]], -1)


def gaussian_nll_per_sample(
    mean: Tensor, log_std: Tensor, target: Tensor, normalised: bool = True
) -> Tensor:
    """Negative log-likelihood of each sample, summed over dimensions (shape without the last);
    ``normalised=False`` drops the constant ½·log 2π per dimension."""
    z = (target - mean) * torch.exp(-log_std)
    nll = 0.5 * z.pow(2) + log_std
    if normalised:
        nll = nll + 0.5 * math.log(2 * math.pi)
    return nll.sum(-1)


def gaussian_nll(mean: Tensor, log_std: Tensor, target: Tensor) -> Tensor:
    """Mean over the batch of the negative log-likelihood, summed over dimensions."""
    return gaussian_nll_per_sample(mean, log_std, target).mean()
