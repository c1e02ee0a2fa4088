"""CSP: the paper's first ablation (section 5.5.1, appendix B), the continual subspace of
policies of Gaussier et al. with its critic learned offline.

CSPO's single subspace of (high, low) anchor pairs, trained by imitation as CSPO is, but the
anchor weights and the extend / prune decision come from a critic, as in the online CSP: a
subspace critic trained with Implicit Q-Learning on each task's relabelled goals, alongside
the new anchor. :class:`~hispo_pl.callbacks.CriticEvaluation` searches the old and the grown
subspace for the weights the critic values most, and :class:`~hispo_pl.callbacks.CriticPruning`
keeps the new anchor iff ``W(α_new) > (1 + ε) · W(α_old)``. The paper's point, which the
callback measures per task: on expert data an IQL critic barely depends on the action, so it
cannot tell good anchor weights from bad ones.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import torch
from torch import Tensor, nn

from ..nn import eval_mode
from ..nn.hierarchy import high_input, high_input_dim
from ..nn.simplex import sample_dirichlet
from ..nn.subspace import AnchorInit
from ..nn.subspace_critic import CriticConfig, SubspaceCritic
from .cspo import CSPO, POLICY

AlphaSampling = Literal["dirichlet", "scores"]


class CSP(CSPO):
    """CSPO's subspace with CSP's critic: IQL values of the mixed policy choose the weights.

    The critic (:class:`~hispo_pl.nn.subspace_critic.SubspaceCritic`): ``V(s, g, α)`` and twin
    ``Q(s, g, a, α)`` on the high policy's inputs (observation, position, goal and its
    features), rebuilt at the start of every task over the weights of the grown subspace and
    trained with IQL on the task's transitions (``--data.transitions true``): the reward is 1,
    and the transition ends, when the next position lies within ``success_radius`` of the
    relabelled goal (the test rollouts are judged by), else 0; the target ``r + γ (1 − done)
    V(s', g, α)``; V the expectile of the target Q on the data's action.

    How α enters: as in CSP, the critic sees the anchor weights, here drawn per sample from
    Dirichlet(1) over the grown subspace. Online, α changes which actions fill the replay
    buffer; offline, IQL regresses on the dataset's action only, so its targets do not depend
    on α and the fixed point is the same for every α: α is an input the critic learns to
    ignore. A point of the subspace is therefore valued through its policy's action,
    ``W(α) = E_s[Q(s, g, π_α(s, g), α)]`` on held-out states, which is where the subspace
    differs: this is the quantity CSP maximises, and the one the paper says flattens when Q
    barely depends on the action.

    Training the anchors: CSP draws the weights of every step from Dirichlet(1) over all
    anchors (``alpha_sampling="dirichlet"``, the default); ``scores`` trains HiSPO's scores
    instead, as CSPO does, to isolate the effect of the critic alone.

    Memory: the critic is per-task state, kept in the state dict (checkpoints load with
    ``weights_only=True`` and resume mid-stream), replaced at the next task, and never needed
    to act; MEM counts what acting needs, so :meth:`decision_only_state` leaves it out (see
    :func:`hispo_pl.metrics.module_bytes`), as CSP counts only its policy anchors.

    Args:
        alpha_sampling: ``dirichlet`` (CSP) or ``scores`` (CSPO's trained scores).
        critic: overrides of :class:`~hispo_pl.nn.subspace_critic.CriticConfig` (hidden, expectile,
            discount, lr, polyak, success_radius).
        The others: as in :class:`~hispo_pl.modules.HiSPO`.

    Example:
        >>> m = CSP(obs_dim=4, action_dim=2, critic={"hidden": 16})
        >>> m.add_anchor("policy"); m.setup("fit")  # a new task: a critic over 2 anchors
        >>> m.critic.alpha_dim, m.decision_only_state()
        (2, ('critic.',))
    """

    critic_prefix: ClassVar[str] = "critic."

    def __init__(
        self,
        *args,
        anchor_init: AnchorInit = "mean",
        alpha_sampling: AlphaSampling = "dirichlet",
        critic: dict[str, int | float] | None = None,
        **kwargs,
    ):
        if alpha_sampling not in ("dirichlet", "scores"):
            raise ValueError(
                f"CSP: alpha_sampling must be 'dirichlet' or 'scores', got {alpha_sampling!r}"
            )
        super().__init__(*args, anchor_init=anchor_init, **kwargs)
        self.critic_config = CriticConfig.from_dict(critic)
        self.critic = self._new_critic(self.n_anchors(POLICY))

    # --- the critic's life: one per task ----------------------------------------------------

    @property
    def state_dim(self) -> int:
        """Width of the critic's state input: the high policy's inputs with the observation
        (whatever the policy's ``high_obs``: a batch's next state has no velocity)."""
        return high_input_dim(self.obs_dim, self.goal_dim)

    def _new_critic(self, alpha_dim: int) -> SubspaceCritic:
        return SubspaceCritic(self.state_dim, self.action_dim, alpha_dim, self.critic_config.hidden)

    def setup(self, stage: str) -> None:
        """A fresh critic for the task about to train, over the weights of its grown subspace
        (AnchorExtension has run: callbacks' ``setup`` precedes the module's)."""
        if stage == "fit":
            self.critic = self._new_critic(self.n_anchors(POLICY))

    def decision_only_state(self) -> tuple[str, ...]:
        """State-dict prefixes of what is stored but only used to decide (MEM leaves it out)."""
        return (self.critic_prefix,)

    def restore_structure(self, state_dict: dict[str, Tensor]) -> None:
        super().restore_structure(state_dict)
        k = SubspaceCritic.alpha_dim_in(state_dict, self.critic_prefix, self.state_dim)
        self.critic = self._new_critic(k)

    # --- training ---------------------------------------------------------------------------

    def _training_alphas(self, subspace: str, batch_size: int) -> Tensor:
        if self.hparams.alpha_sampling == "scores":
            return super()._training_alphas(subspace, batch_size)
        groups = min(self.hparams.alpha_groups, batch_size)
        while batch_size % groups:
            groups -= 1
        return sample_dirichlet(groups, self.n_anchors(subspace), device=self.device)

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """CSPO's imitation losses of the anchors plus IQL's losses of the critic (their
        parameters are disjoint, and the critic's inputs come from the data, so one backward
        trains each on its own loss)."""
        if "next_observation" not in batch:
            raise ValueError(
                "CSP's critic learns from transitions: the data module must serve them "
                "(--data.transitions true; configs/methods/csp.yaml sets it)"
            )
        out = super().losses(batch)
        out["loss_bc"] = out["loss"]
        # the critic reads the data's maze positions: it values the policies, it does not act
        obs, pos, goal = batch["observation"], batch["position"], batch["goal"]
        x = high_input(obs, pos, goal)
        next_x = high_input(batch["next_observation"], batch["next_position"], goal)
        alpha = sample_dirichlet(len(x), self.critic.alpha_dim, device=x.device)
        critic = self.critic.goal_losses(
            x, batch["action"], alpha, next_x, batch["next_position"], goal, self.critic_config
        )
        out.update({f"critic_{k}": v for k, v in critic.items()})
        out["loss"] = out["loss"] + critic["loss_v"] + critic["loss_q"]
        return out

    def on_train_batch_end(self, outputs, batch, batch_idx: int) -> None:
        self.critic.update_targets(self.critic_config.polyak)

    def configure_optimizers(self):
        """Adam with two groups: the anchors at ``lr`` (cosine-annealed over the task unless
        ``lr_schedule`` is constant) and the critic at its own constant ``lr``."""
        critic = [p for p in self.critic.parameters() if p.requires_grad]
        ids = {id(p) for p in critic}
        policy = [p for p in self.parameters() if p.requires_grad and id(p) not in ids]
        groups, schedules = [], []
        steps = self._trainer.max_steps if self._trainer is not None else -1
        cosine = self.optim_config.schedule == "cosine" and steps is not None and steps > 0
        if policy:
            groups.append({"params": policy, "lr": self.lr})
            schedules.append(
                (lambda t: 0.5 * (1 + math.cos(math.pi * min(t, steps) / steps)))
                if cosine
                else (lambda t: 1.0)
            )
        groups.append({"params": critic, "lr": self.critic_config.lr})
        schedules.append(lambda t: 1.0)
        opt = torch.optim.Adam(groups)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, schedules)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    # --- valuing points of the subspace -------------------------------------------------------

    def _mixed_actions(self, alphas: Tensor, batch: dict[str, Tensor]) -> Tensor:
        """Deterministic actions [M, B, A] of the policies mixed with ``alphas`` [M, K]."""
        obs, goal = batch["observation"], batch["goal"]
        pos = batch.get("agent_position", batch["position"])  # as the policies sense it
        return self.policies.act(
            obs, pos, goal, batch.get("velocity"), lambda name, x: self.policies[name](x, alphas)
        )

    def _critic_alpha(self, alphas: Tensor) -> Tensor:
        """Weights as the critic reads them: a point of a pruned subspace is the grown one's
        with zeros on the anchors it lost."""
        missing = self.critic.alpha_dim - alphas.shape[-1]
        if missing < 0:
            raise ValueError(
                f"the critic reads {self.critic.alpha_dim} weights, got {alphas.shape[-1]}"
            )
        return nn.functional.pad(alphas, (0, missing))

    @torch.no_grad()
    def critic_values(self, alphas: Tensor, batch: dict[str, Tensor], chunk: int = 64) -> Tensor:
        """``W(α) = mean_s Q(s, g, π_α(s, g), α)`` of each candidate ``alphas`` [M, K] on
        ``batch``, shape [M]: the deterministic mixed policy (eval mode) acts, the critic
        values its action."""
        x = high_input(batch["observation"], batch["position"], batch["goal"])
        out = []
        with eval_mode(self.policies):
            for part in alphas.split(chunk):
                actions = self._mixed_actions(part, batch)
                a = self._critic_alpha(part)[:, None, :].expand(-1, len(x), -1)
                out.append(self.critic.q(x.expand(len(part), *x.shape), actions, a).mean(-1))
        return torch.cat(out)

    @torch.no_grad()
    def critic_diagnostic(
        self,
        alpha: Tensor,
        batch: dict[str, Tensor],
        n_actions: int = 16,
        generator: torch.Generator | None = None,
    ) -> dict[str, float]:
        """How much the critic's Q depends on the action, at the weights ``alpha`` [K]:
        per state, Q of the data's action, the mixed policy's action and ``n_actions``
        actions uniform in the batch's action box (per-dimension min to max of the data);
        ``q_action_std`` is the std over these actions averaged over states,
        ``q_state_std`` the std over states of Q(s, g, a_data), and ``action_dependence``
        their ratio (near 0: the critic values states, not actions). Also the mean Q of
        each kind of action."""
        x = high_input(batch["observation"], batch["position"], batch["goal"])
        data = batch["action"]
        with eval_mode(self.policies):
            policy = self._mixed_actions(alpha[None], batch)[0]
        lo, hi = data.min(0).values, data.max(0).values
        u = torch.rand(n_actions, *data.shape, generator=generator).to(data.device)
        actions = torch.cat([data[None], policy[None], lo + (hi - lo) * u])  # [n + 2, B, A]
        a = self._critic_alpha(alpha)[None, None, :].expand(len(actions), len(x), -1)
        q = self.critic.q(x.expand(len(actions), *x.shape), actions, a)  # [n + 2, B]
        action_std, state_std = q.std(dim=0).mean(), q[0].std()
        return {
            "q_action_std": float(action_std),
            "q_state_std": float(state_std),
            "action_dependence": float(action_std / state_std.clamp_min(1e-12)),
            "q_data": float(q[0].mean()),
            "q_policy": float(q[1].mean()),
            "q_uniform": float(q[2:].mean()),
        }
