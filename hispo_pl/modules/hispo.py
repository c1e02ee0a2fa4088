"""HiSPO: the HBC backbone with two subspaces of policies (high and low), one anchor per task.

The module owns everything inference needs: the anchors of both subspaces, the trainable score
vector of the current task, and the anchor weights (alpha) chosen for every task so far, kept in
registered buffers. A checkpoint alone therefore acts on every task seen. Growing, searching and
pruning are decided by callbacks, each through the small protocol of what it needs
(:mod:`hispo_pl.callbacks.protocols`).
"""

from __future__ import annotations

from contextlib import ExitStack
from typing import ClassVar, Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..nn import eval_mode
from ..nn.hierarchy import Forward, HierarchicalPolicy
from ..nn.mlp import GaussianPolicy
from ..nn.subspace import AnchorInit, SubspaceResidualMLP, cosine_similarity_penalty
from .hbc import GoalConditionedBC

SUBSPACES = ("high", "low")
Precision = Literal["32", "bf16"]


class SubspaceGaussianPolicy(GaussianPolicy):
    """A Gaussian policy whose network is a subspace; ``alpha`` [K] or a batch of them [M, K]."""

    network = SubspaceResidualMLP

    def forward(self, x: Tensor, alpha: Tensor) -> tuple[Tensor, Tensor]:
        return self.distribution(self.net(x, alpha))


def training_alphas(scores: Tensor, groups: int, noise: float, generator=None) -> Tensor:
    """Anchor weights for one training step, one row per sample group:
    softmax(K · (tanh(s) + noise · ε)), ε ~ N(0, 1). Differentiable in the scores ``s``."""
    k = scores.shape[-1]
    eps = torch.randn(groups, k, generator=generator, device=scores.device)
    return torch.softmax(k * (torch.tanh(scores) + noise * eps), dim=-1)


class HiSPO(GoalConditionedBC):
    """Hierarchical subspace of policies on the HBC backbone.

    Args:
        obs_dim, action_dim, goal_dim: sizes (linked from the data by the CLI).
        backbone: the network each anchor is (:class:`~hispo_pl.config.BackboneConfig`,
            hierarchical only).
        optim: Adam's learning rate and schedule, restarted each task.
        anchor_init: a new anchor starts as the ``mean`` of the others, ``random``, or a
            copy of the ``first``; ``None``: the task family's choice
            (:attr:`~hispo_pl.tasks.Family.anchor_init`, which :class:`~callbacks.
            AnchorExtension` passes; ``mean`` outside a stream).
        cosine_weight: weight λ of the anchors' squared-cosine regulariser (0: off).
        alpha_noise: std of the noise on the scores while training (0.1 in the paper).
        alpha_groups: anchor weights drawn per step: the batch is split into this many
            groups, each mixed with its own weights, in one batched forward (per-sample weights
            would need a weight matrix per sample; ``alpha_groups`` = batch size gives exactly
            that). The default, one draw per step, keeps a step a plain forward (the fast
            training path of :mod:`hispo_pl.nn.fast`); figures in ``docs/performance.md``.
        new_anchor_score: the score a new anchor starts its task with, the older anchors
            starting at 0. At 0 (the authors' code) training starts from equal weights, so a
            new anchor, whose gradient is scaled by its weight, starts at 1/K of the rate a
            fresh network learns at; a positive score starts the task close to the new anchor.

    Which policies a subspace holds is the class attribute ``subspace_policies`` (here each
    policy its own subspace; :class:`~hispo_pl.modules.cspo.CSPO` puts both in one): the
    policies of one subspace grow, get pruned and are mixed together, with one weight vector.
    """

    subspace_policies: ClassVar[dict[str, tuple[str, ...]]] = {n: (n,) for n in SUBSPACES}
    subspace_names: ClassVar[tuple[str, ...]] = SUBSPACES  # the keys of subspace_policies

    def __init__(
        self,
        *args,
        anchor_init: AnchorInit | None = None,
        cosine_weight: float = 0.0,
        alpha_noise: float = 0.1,
        alpha_groups: int = 1,
        new_anchor_score: float = 0.0,
        **kwargs,
    ):
        super().__init__(*args, **kwargs)
        if self.backbone_config.kind != "hbc":
            raise ValueError(f"{type(self).__name__} needs the hierarchical backbone (kind: hbc)")
        self.save_hyperparameters()
        self.policies = self.make_policy(SubspaceGaussianPolicy)
        if tuple(self.subspace_policies) != self.subspace_names:
            raise TypeError(f"{type(self).__name__}: subspace_names must list subspace_policies")
        names = self.subspace_names
        self.scores = nn.ParameterDict({name: nn.Parameter(torch.zeros(1)) for name in names})
        for name in names:  # one row of anchor weights per finished task
            self.register_buffer(f"task_alpha_{name}", torch.zeros(0, 1))
        # task -> subspaces transferred zero-shot (decided at the task's start, so not stored)
        self._transferred: dict[int, set[str]] = {}
        # subspace -> the task its newest anchor was added for (in this process; a resumed
        # task starts from the previous task's weights, which were not grown for it yet)
        self._grown_for: dict[str, int] = {}

    def _nets(self, subspace: str) -> list[nn.Module]:
        """The subspace networks of the policies a subspace holds (they grow together)."""
        return [self.policies[p].net for p in self.subspace_policies[subspace]]

    def subspace_of(self, policy: str) -> str:
        """The subspace whose weights the policy ``policy`` (high or low) is mixed with."""
        return next(s for s, held in self.subspace_policies.items() if policy in held)

    # --- what the callbacks talk to -----------------------------------------------------

    def n_anchors(self, subspace: str) -> int:
        return self._nets(subspace)[0].n_anchors

    def task_alphas(self, subspace: str) -> Tensor:
        return getattr(self, f"task_alpha_{subspace}")

    def _set_task_alphas(self, subspace: str, value: Tensor) -> None:
        setattr(self, f"task_alpha_{subspace}", value)

    def add_anchor(self, subspace: str, default_init: AnchorInit = "mean") -> None:
        """Grow a subspace by one trainable anchor (older ones frozen), reset its scores and
        give every stored task a zero weight on the new anchor. The anchor starts as
        ``anchor_init`` says, or as ``default_init`` where that is unset."""
        init = self.hparams.anchor_init or default_init
        for net in self._nets(subspace):
            net.add_anchor(init)
        k = self.n_anchors(subspace)
        scores = torch.zeros(k, device=self.scores[subspace].device)
        scores[-1] = self.hparams.new_anchor_score
        self.scores[subspace] = nn.Parameter(scores)
        self._set_task_alphas(subspace, F.pad(self.task_alphas(subspace), (0, 1)))
        self._grown_for[subspace] = self.task_index

    def grown(self, subspace: str) -> bool:
        """Whether :meth:`add_anchor` already grew ``subspace`` for the current task."""
        return self._grown_for.get(subspace) == self.task_index

    def prune_last_anchor(self, subspace: str) -> None:
        """Drop the newest anchor of a subspace; stored weights lose their last coordinate."""
        for net in self._nets(subspace):
            net.remove_last_anchor()
        k = self.n_anchors(subspace)
        self.scores[subspace] = nn.Parameter(torch.zeros(k, device=self.scores[subspace].device))
        self._set_task_alphas(subspace, self.task_alphas(subspace)[:, :k].contiguous())

    def current_alpha(self, subspace: str) -> Tensor:
        """The trained weights of the current task: softmax of the scores (no noise)."""
        return torch.softmax(self.scores[subspace].detach(), dim=-1)

    def set_task_alpha(self, task: int, subspace: str, alpha: Tensor) -> None:
        """Store the weights task ``task`` acts with (rows are appended in task order)."""
        rows = self.task_alphas(subspace)
        alpha = alpha.detach().to(rows.device, rows.dtype).reshape(1, -1)
        if alpha.shape[1] != self.n_anchors(subspace):
            k = self.n_anchors(subspace)
            raise ValueError(f"alpha has {alpha.shape[1]} entries, {subspace} has {k} anchors")
        if rows.shape[1] != alpha.shape[1]:  # first task: the buffer had a placeholder width
            rows = rows.new_zeros(rows.shape[0], alpha.shape[1])
        if task < rows.shape[0]:
            rows = rows.clone()
            rows[task] = alpha[0]
        elif task == rows.shape[0]:
            rows = torch.cat([rows, alpha])
        else:
            raise ValueError(f"task {task} stored before tasks 0..{task - 1}")
        self._set_task_alphas(subspace, rows)

    @torch.no_grad()
    def score_alphas(
        self,
        subspace: str,
        alphas: Tensor,
        batch: dict[str, Tensor],
        loss: Literal["mse", "nll"] = "mse",
        chunk: int = 64,
        precision: Precision = "32",
    ) -> Tensor:
        """Loss of each candidate weight vector ``alphas`` [S, K] on ``batch``, shape [S]:
        one batched forward per chunk of candidates, deterministic predictions (eval mode,
        whatever the module's mode; the mode is restored afterwards). ``precision="bf16"``
        runs the forwards in bfloat16 autocast (several times faster where the CPU has
        bf16 units); the losses are reduced in float32. A subspace holding several policies
        scores the sum of their losses (each policy on its own inputs and targets)."""
        names = self.subspace_policies[subspace]
        io = {name: self.policies.inputs(name, batch) for name in names}
        out = []
        device = next(iter(io.values()))[0].device
        autocast = torch.autocast(device.type, torch.bfloat16, enabled=precision == "bf16")
        # dropout off: every candidate is scored on the same, deterministic predictions
        with ExitStack() as stack:
            policies = {name: stack.enter_context(eval_mode(self.policies[name])) for name in names}
            for part in alphas.split(chunk):
                total = None
                for name, policy in policies.items():
                    x, target = io[name]
                    with autocast:
                        mean, log_std = policy(x, part)  # [M, B, d]
                    mean, log_std = mean.float(), log_std.float()
                    if loss == "mse":
                        part_loss = (policy.prediction(mean) - target).pow(2).sum(-1).mean(-1)
                    else:
                        part_loss = policy.nll(mean, log_std, target, normalised=False).mean(-1)
                    total = part_loss if total is None else total + part_loss
                out.append(total)
        return torch.cat(out)

    # --- training and acting --------------------------------------------------------------

    def _training_alphas(self, subspace: str, batch_size: int) -> Tensor:
        """One step's anchor weights of a subspace, one row per group of the batch."""
        groups = min(self.hparams.alpha_groups, batch_size)
        while batch_size % groups:
            groups -= 1
        return training_alphas(self.scores[subspace], groups, self.hparams.alpha_noise)

    def _grouped_forward(self, policy: str, x: Tensor, alphas: Tensor) -> tuple[Tensor, Tensor]:
        groups = alphas.shape[0]
        if groups == 1:  # one weight vector: the plain (unbatched) forward, no bmm
            return self.policies[policy](x, alphas[0])
        mean, log_std = self.policies[policy](x.reshape(groups, -1, x.shape[-1]), alphas)
        return mean.reshape(x.shape[0], -1), log_std.reshape(x.shape[0], -1)

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        trained = [s for s in self.subspace_names if not self.transferred(s)]  # zero-shot: fixed
        alphas: dict[str, Tensor] = {}  # one draw per subspace, shared by its policies

        def forward(name: str, x: Tensor) -> tuple[Tensor, Tensor]:
            subspace = self.subspace_of(name)
            if subspace not in alphas:
                alphas[subspace] = self._training_alphas(subspace, len(batch["action"]))
            return self._grouped_forward(name, x, alphas[subspace])

        names = [n for s in trained for n in self.subspace_policies[s]]
        out = self.policies.losses(batch, forward, names)
        if self.hparams.cosine_weight > 0:
            reg = sum(cosine_similarity_penalty(p) for p in self.policies.heads().values())
            out["cosine"] = reg
            out["loss"] = out["loss"] + self.hparams.cosine_weight * reg
        return out

    def transfer(self, subspace: str, alpha: Tensor) -> None:
        """Zero-shot transfer: the current task acts with ``alpha`` over the existing anchors
        of ``subspace``, which is then neither extended nor trained on this task."""
        self.set_task_alpha(self.task_index, subspace, alpha)
        self._transferred.setdefault(self.task_index, set()).add(subspace)

    def transferred(self, subspace: str) -> bool:
        """Whether :meth:`transfer` fixed the current task's weights of ``subspace``."""
        return subspace in self._transferred.get(self.task_index, ())

    @torch.no_grad()
    def prediction_distances(
        self, subspace: str, alpha: Tensor, batch: dict[str, Tensor]
    ) -> dict[str, Tensor]:
        """Per-sample Euclidean distance between each policy's deterministic prediction with
        weights ``alpha`` and the data (subgoal offset for ``high``, action for ``low``), for
        the policies ``subspace`` holds: the d(a, â) of the PAC criterion."""
        out = {}
        for name in self.subspace_policies[subspace]:
            x, target = self.policies.inputs(name, batch)
            with eval_mode(self.policies[name]) as policy:
                mean, _ = policy(x, alpha)
            out[name] = (policy.act(mean) - target).norm(dim=-1)
        return out

    def alpha_for(self, subspace: str, task: int | None) -> Tensor:
        """Weights to act with: a finished task's stored row, else the current scores."""
        rows = self.task_alphas(subspace)
        if task is not None and task < rows.shape[0]:
            return rows[task]
        return self.current_alpha(subspace)

    def acting_policy(self, task: int) -> tuple[HierarchicalPolicy, Forward]:
        """The subspaces, each head mixed with the weights of task ``task``."""

        def forward(name: str, x: Tensor) -> tuple[Tensor, Tensor]:
            return self.policies[name](x, self.alpha_for(self.subspace_of(name), task))

        return self.policies, forward

    def acting_state(self, task: int) -> dict[str, Tensor]:
        """Every anchor of every subspace and task ``task``'s weights over them."""
        state = dict(self.policies.state_dict())
        for subspace in self.subspace_names:
            state[f"alpha.{subspace}"] = self.alpha_for(subspace, task)
        return state

    @property
    def n_tasks(self) -> int:
        return self.task_alphas(self.subspace_names[0]).shape[0]

    # --- checkpoints ----------------------------------------------------------------------

    def restore_structure(self, state_dict: dict[str, Tensor]) -> None:
        """Resize anchors, scores and stored weights to a state dict's, before it loads."""
        for name in self.subspace_names:
            rows = state_dict[f"task_alpha_{name}"]
            k = state_dict[f"scores.{name}"].shape[0]
            for net in self._nets(name):
                net.set_n_anchors(k)
            self.scores[name] = nn.Parameter(torch.zeros(k))
            self._set_task_alphas(name, torch.zeros_like(rows))
