"""Goal-conditioned BC policies as LightningModules: hierarchical (HBC) and flat (BC)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import lightning as L
import torch
from torch import Tensor, nn

from ..errors import CheckpointError, TrainingDivergedError
from ..nn import fast
from ..nn.mlp import GaussianPolicy, feature_dim, goal_features


class GoalConditionedBC(L.LightningModule):
    """Shared training plumbing: Adam, optional cosine schedule, loss dict logging.

    Subclasses define ``losses(batch) -> dict[str, Tensor]`` (with a ``loss`` entry) and
    ``act(observation, position, goal) -> action`` (deterministic).
    """

    def __init__(self, lr: float = 3e-4, lr_schedule: Literal["cosine", "constant"] = "cosine"):
        super().__init__()
        self.lr = lr
        self.lr_schedule = lr_schedule
        self.task_index = 0  # position in a stream, set by the ContinualLoop
        self.log_prefix = ""  # e.g. "task_03/" inside a stream, so curves of tasks do not collide

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        raise NotImplementedError

    def reference_model(self) -> nn.Module:
        """One single-task model of this method's architecture: MEM's unit. By default the
        backbone (``hbc`` unless a ``backbone`` hyperparameter says otherwise) built from the
        module's own width hyperparameters."""
        hp = self.hparams
        return make_backbone(
            hp.get("backbone", "hbc"),
            hp.obs_dim,
            hp.action_dim,
            hp.goal_dim,
            hp.get("high_hidden", 64),
            hp.get("low_hidden", 256),
            hp.get("dropout", 0.1),
            hp.get("high_log_std"),
            hp.get("low_obs", True),
            hp.get("binary_actions", 0),
            hp.get("low_log_std"),
            hp.get("low_velocity", False),
        )

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        check_finite_state(checkpoint["state_dict"], self.task_index)
        # enough to rebuild the module from the file alone (``hispo-pl evaluate``)
        checkpoint["hispo_pl_class"] = f"{type(self).__module__}.{type(self).__qualname__}"
        checkpoint["hispo_pl_task_index"] = self.task_index

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.task_index = int(checkpoint.get("hispo_pl_task_index", 0))
        self.restore_structure(checkpoint["state_dict"])

    def restore_structure(self, state_dict: dict[str, Tensor]) -> None:
        """Grow the module to a state dict's shape (networks, anchors, columns, per-task
        buffers) before it loads; a fixed-size module has nothing to do."""

    def freeze_all(self) -> None:
        """Nothing trains until a callback makes the next task's parameters trainable."""
        for p in self.parameters():
            p.requires_grad_(False)

    @classmethod
    def from_checkpoint_file(cls, path: str) -> GoalConditionedBC:
        """Rebuild whichever method wrote ``path`` (its class is stored in the file), on CPU.

        The file holds plain tensors and values only (``weights_only=True``), and its class
        name is looked up among hispo-pl's own methods (:func:`method_registry`): nothing the
        file names is imported.

        Raises:
            CheckpointError: the file is corrupt, truncated, unsafe, or not hispo-pl's.
        """
        checkpoint = read_checkpoint(path)
        name = checkpoint.get("hispo_pl_class")
        if not isinstance(name, str):
            raise CheckpointError(
                f"not a readable hispo-pl checkpoint: {path} (no hispo_pl_class entry: it was "
                "not written by a hispo-pl module)"
            )
        method = method_registry().get(name)
        if method is None:
            raise CheckpointError(
                f"not a readable hispo-pl checkpoint: {path} names the class {name!r}, which is "
                "not one of hispo-pl's methods"
            )
        if not issubclass(method, cls):
            raise CheckpointError(f"{path} holds a {method.__name__}, not a {cls.__name__}")
        try:
            # LightningCLI adds private entries such as ``_class_path`` to the hyperparameters
            hparams = {k: v for k, v in checkpoint["hyper_parameters"].items() if k[:1] != "_"}
            module = method(**hparams)
            module.on_load_checkpoint(checkpoint)
            module.load_state_dict(checkpoint["state_dict"])
        except (KeyError, TypeError, ValueError, RuntimeError, AttributeError) as err:
            raise CheckpointError(
                f"not a readable hispo-pl checkpoint: {path} ({type(err).__name__}: "
                f"{_first_line(err)})"
            ) from None
        return module.eval()

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        losses = self.losses(batch)
        if not torch.isfinite(losses["loss"]):
            raise TrainingDivergedError(self._divergence_message(losses["loss"]))
        if self._step_reaches_logger():
            self.log_dict(
                {f"{self.log_prefix}train/{k}": v.detach() for k, v in losses.items()},
                prog_bar=True,
                batch_size=len(batch["action"]),
            )
        return losses["loss"]

    def _step_reaches_logger(self) -> bool:
        """Whether the Trainer writes this step's logged values (every ``log_every_n_steps``
        steps, and when stopping): logging only then skips the per-step bookkeeping of
        ``self.log`` while the logger gets the same values. The progress bar's losses then
        change on those steps too. Always true without a Trainer or on the reference path."""
        trainer = self._trainer
        if trainer is None or not fast.enabled() or trainer.fast_dev_run:
            return True
        every = trainer.log_every_n_steps
        return every > 0 and ((self.global_step + 1) % every == 0 or trainer.should_stop)

    def _divergence_message(self, loss: Tensor) -> str:
        trainer = self._trainer
        step = trainer.global_step + 1 if trainer is not None else "?"
        lr = self.lr
        if trainer is not None and trainer.optimizers:
            lr = trainer.optimizers[0].param_groups[0]["lr"]
        return (
            f"training diverged: the loss is {float(loss)} at step {step} of task "
            f"{self.task_index + 1} (learning rate {lr:g}); training stopped and nothing of "
            "this task was saved. Lower the learning rate (--model.init_args.lr, now "
            f"{self.lr:g}), or check the data and the other hyperparameters."
        )

    def configure_optimizers(self):
        params = [p for p in self.parameters() if p.requires_grad]
        if not params:  # a method that does not train on this task (FRZ after its first)
            return None
        # fused: one kernel for every tensor's update (the same update as the per-tensor loop)
        opt = torch.optim.Adam(params, lr=self.lr, fused=fast.enabled())
        if fast.enabled():
            fast.retain_freed_memory()
        steps = self.trainer.max_steps if self.trainer is not None else -1
        if self.lr_schedule == "constant" or steps is None or steps <= 0:
            return opt
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=steps)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    @torch.no_grad()
    def act(
        self,
        observation: Tensor,
        position: Tensor,
        goal: Tensor,
        task: int | None = None,
        velocity: Tensor | None = None,
    ) -> Tensor:
        """Deterministic action; ``task`` selects the task's policy where a method keeps several;
        ``velocity`` is the goal-space velocity (read by low policies with ``low_velocity``)."""
        raise NotImplementedError


class HierarchicalNet(nn.Module):
    """The HBC networks: a high policy over subgoal offsets and a low policy over actions.

    The high policy sees [features(goal − pos), obs, pos, goal] and predicts a Gaussian over the
    subgoal offset (subgoal − pos); the low policy sees [features(subgoal − pos), obs] (never
    the absolute goal), or with ``low_obs=False`` only features(subgoal − pos) (never the
    proprioceptive observation, so observation variants and absolute positions cannot reach
    it), and predicts a Gaussian over the action (Bernoulli over its first ``binary_actions``
    entries: gamepad buttons). Acting re-plans every step.
    Kept apart from the LightningModule so that methods can hold several (one per task).
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        goal_dim: int = 2,
        high_hidden: int = 64,
        low_hidden: int = 256,
        dropout: float = 0.1,
        high_log_std: float | None = None,
        low_obs: bool = True,
        binary_actions: int = 0,
        low_log_std: float | None = None,
        low_velocity: bool = False,
    ):
        super().__init__()
        f = feature_dim(goal_dim)
        self.low_obs, self.low_velocity = low_obs, low_velocity
        self.high = GaussianPolicy(
            f + obs_dim + 2 * goal_dim, high_hidden, goal_dim, dropout, fixed_log_std=high_log_std
        )
        self.low = GaussianPolicy(
            low_input_dim(obs_dim, goal_dim, low_obs, low_velocity),
            low_hidden,
            action_dim,
            dropout,
            fixed_log_std=low_log_std,
            binary=binary_actions,
        )

    @staticmethod
    def high_input(observation: Tensor, position: Tensor, goal: Tensor) -> Tensor:
        return torch.cat([goal_features(goal - position), observation, position, goal], dim=-1)

    @staticmethod
    def low_input(
        observation: Tensor,
        subgoal_offset: Tensor,
        with_obs: bool = True,
        velocity: Tensor | None = None,
    ) -> Tensor:
        """[features(subgoal − pos), observation if ``with_obs``, ``velocity`` if given]."""
        parts = [goal_features(subgoal_offset)]
        if with_obs:
            parts.append(observation)
        if velocity is not None:
            parts.append(velocity)
        return torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        return hierarchical_losses(self.high, self.low, batch, self.low_obs, self.low_velocity)

    def act(
        self, observation: Tensor, position: Tensor, goal: Tensor, velocity: Tensor | None = None
    ) -> Tensor:
        offset, _ = self.high(self.high_input(observation, position, goal))
        velocity = low_velocity_input(self.low_velocity, velocity)
        mean, _ = self.low(self.low_input(observation, offset, self.low_obs, velocity))
        return self.low.act(mean)


def low_input_dim(obs_dim: int, goal_dim: int, low_obs: bool, low_velocity: bool = False) -> int:
    """Width of the low policy's input (see :meth:`HierarchicalNet.low_input`)."""
    return feature_dim(goal_dim) + (obs_dim if low_obs else 0) + (goal_dim if low_velocity else 0)


def low_velocity_input(wanted: bool, velocity: Tensor | None) -> Tensor | None:
    """The velocity a low policy with ``low_velocity`` reads (None for one without)."""
    if not wanted:
        return None
    if velocity is None:
        raise ValueError(
            "this policy's low level reads the goal-space velocity: pass velocity= to act() "
            "(RolloutEvaluator and module_policy do)"
        )
    return velocity


def hierarchical_losses(
    high: nn.Module,
    low: nn.Module,
    batch: dict[str, Tensor],
    low_obs: bool = True,
    low_velocity: bool = False,
) -> dict:
    """HBC's losses for any pair of Gaussian policies called as ``policy(x) -> (mean, log_std)``:
    the high one on the subgoal offset, the low one on the action given the true subgoal
    (``low_obs``: whether the low policy's input holds the observation, ``low_velocity``: the
    batch's goal-space velocity); each policy's own
    :meth:`~hispo_pl.nn.mlp.GaussianPolicy.loss` (so button entries are Bernoulli)."""
    obs, pos = batch["observation"], batch["position"]
    offset = batch["subgoal"] - pos
    velocity = batch["velocity"] if low_velocity else None
    mean_h, log_std_h = high(HierarchicalNet.high_input(obs, pos, batch["goal"]))
    mean_l, log_std_l = low(HierarchicalNet.low_input(obs, offset, low_obs, velocity))
    loss_high = high.loss(mean_h, log_std_h, offset)
    loss_low = low.loss(mean_l, log_std_l, batch["action"])
    return {"loss": loss_high + loss_low, "loss_high": loss_high, "loss_low": loss_low}


def flat_losses(policy: nn.Module, batch: dict[str, Tensor]) -> dict[str, Tensor]:
    """Flat BC's loss for any Gaussian policy called as ``policy(x) -> (mean, log_std)`` on
    the high policy's inputs: the NLL of the data's action."""
    x = HierarchicalNet.high_input(batch["observation"], batch["position"], batch["goal"])
    mean, log_std = policy(x)
    return {"loss": policy.loss(mean, log_std, batch["action"])}


class FlatNet(nn.Module):
    """Flat goal-conditioned BC: the high policy's inputs, one Gaussian policy over actions."""

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        goal_dim: int = 2,
        hidden: int = 256,
        dropout=0.1,
        binary_actions: int = 0,
    ):
        super().__init__()
        self.policy = GaussianPolicy(
            feature_dim(goal_dim) + obs_dim + 2 * goal_dim,
            hidden,
            action_dim,
            dropout,
            binary=binary_actions,
        )

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        return flat_losses(self.policy, batch)

    def act(
        self, observation: Tensor, position: Tensor, goal: Tensor, velocity: Tensor | None = None
    ) -> Tensor:
        mean, _ = self.policy(HierarchicalNet.high_input(observation, position, goal))
        return self.policy.act(mean)


Backbone = Literal["hbc", "bc"]


def make_backbone(
    backbone: Backbone,
    obs_dim: int,
    action_dim: int,
    goal_dim: int = 2,
    high_hidden: int = 64,
    low_hidden: int = 256,
    dropout: float = 0.1,
    high_log_std: float | None = None,
    low_obs: bool = True,
    binary_actions: int = 0,
    low_log_std: float | None = None,
    low_velocity: bool = False,
) -> HierarchicalNet | FlatNet:
    """One single-task network: hierarchical (``hbc``) or flat (``bc``, the low width)."""
    if backbone == "hbc":
        return HierarchicalNet(
            obs_dim,
            action_dim,
            goal_dim,
            high_hidden,
            low_hidden,
            dropout,
            high_log_std,
            low_obs,
            binary_actions,
            low_log_std,
            low_velocity,
        )
    if backbone == "bc":
        return FlatNet(obs_dim, action_dim, goal_dim, low_hidden, dropout, binary_actions)
    raise ValueError(f"unknown backbone {backbone!r}; expected 'hbc' or 'bc'")


class HBC(GoalConditionedBC):
    """Hierarchical goal-conditioned BC on one task (:class:`HierarchicalNet`).

    ``high_log_std``: a fixed log-std makes the high policy's loss a squared error on the
    subgoal; ``None`` learns it. ``low_log_std``: the same for the low policy's action (a
    squared error on the continuous entries). ``low_obs``: whether the low policy sees the
    observation. ``low_velocity``: whether it sees the goal-space velocity (from consecutive
    positions, so observation variants do not reach it; with ``low_obs=False`` the low policy
    then works in goal space only).
    ``binary_actions``: how many leading action entries are buttons (Bernoulli; linked from
    the data: 6 for the video-game mazes, 0 for the mazes' continuous controls).
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        goal_dim: int = 2,
        high_hidden: int = 64,
        low_hidden: int = 256,
        dropout: float = 0.1,
        lr: float = 3e-4,
        lr_schedule: Literal["cosine", "constant"] = "cosine",
        high_log_std: float | None = None,
        low_obs: bool = True,
        binary_actions: int = 0,
        low_log_std: float | None = None,
        low_velocity: bool = False,
    ):
        super().__init__(lr=lr, lr_schedule=lr_schedule)
        self.save_hyperparameters()
        self.net = self.reference_model()  # the single-task HBC its hyperparameters describe

    high_input = staticmethod(HierarchicalNet.high_input)
    low_input = staticmethod(HierarchicalNet.low_input)

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        return self.net.losses(batch)

    @torch.no_grad()
    def act(
        self,
        observation: Tensor,
        position: Tensor,
        goal: Tensor,
        task: int | None = None,
        velocity: Tensor | None = None,
    ) -> Tensor:
        return self.net.act(observation, position, goal, velocity)


class BC(GoalConditionedBC):
    """Flat goal-conditioned BC (the paper's BC column) on the same network and inputs."""

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        goal_dim: int = 2,
        hidden: int = 256,
        dropout: float = 0.1,
        lr: float = 3e-4,
        lr_schedule: Literal["cosine", "constant"] = "cosine",
        binary_actions: int = 0,
    ):
        super().__init__(lr=lr, lr_schedule=lr_schedule)
        self.save_hyperparameters()
        self.net = self.reference_model()

    def reference_model(self) -> nn.Module:
        hp = self.hparams
        return FlatNet(
            hp.obs_dim, hp.action_dim, hp.goal_dim, hp.hidden, hp.dropout, hp.binary_actions
        )

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        return self.net.losses(batch)

    @torch.no_grad()
    def act(
        self,
        observation: Tensor,
        position: Tensor,
        goal: Tensor,
        task: int | None = None,
        velocity: Tensor | None = None,
    ) -> Tensor:
        return self.net.act(observation, position, goal, velocity)


def check_finite_state(state_dict: dict[str, Tensor], task_index: int = 0) -> None:
    """Refuse to save weights that are NaN or infinite (a diverged step after the last finite
    loss): a checkpoint must never hold a policy that only looks trained.

    Raises:
        TrainingDivergedError: names the first non-finite tensor.
    """
    for name, tensor in state_dict.items():
        if torch.is_tensor(tensor) and tensor.is_floating_point() and not tensor.isfinite().all():
            raise TrainingDivergedError(
                f"training diverged: {name} holds NaN or infinite values at the end of task "
                f"{task_index + 1}; nothing was saved. Lower the learning rate "
                "(--model.init_args.lr)."
            )


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def read_checkpoint(path: str | Path) -> dict:
    """A checkpoint file's contents, loaded with ``weights_only=True`` on CPU.

    Raises:
        CheckpointError: the file cannot be read as a checkpoint of plain tensors and values
            (corrupt, truncated, not a checkpoint, or holding objects that would run code);
            the message never suggests ``weights_only=False``.
    """
    import pickle
    import re

    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        found = re.search(r"Unsupported global: GLOBAL ([\w.]+)", str(err))
        what = f" ({found.group(1)})" if found else ""
        raise CheckpointError(
            f"not a readable hispo-pl checkpoint: {path} holds Python objects other than "
            f"tensors and plain values{what}, which hispo-pl never writes and will not load"
        ) from None
    except (OSError, RuntimeError, EOFError, ValueError, KeyError, AttributeError) as err:
        raise CheckpointError(
            f"not a readable hispo-pl checkpoint: {path} (corrupt or truncated: {_first_line(err)})"
        ) from None
    if not isinstance(checkpoint, dict) or not isinstance(checkpoint.get("state_dict"), dict):
        raise CheckpointError(
            f"not a readable hispo-pl checkpoint: {path} (no state_dict: not a Lightning "
            "checkpoint)"
        )
    return checkpoint


def method_registry() -> dict[str, type[GoalConditionedBC]]:
    """hispo-pl's own methods by the name a checkpoint stores (``module.QualName``): every
    subclass of :class:`GoalConditionedBC` defined in the ``hispo_pl`` package. Only already
    imported code is searched; a checkpoint can never make hispo-pl import a module."""
    from .. import modules  # noqa: F401  (defines every shipped method)

    found: dict[str, type[GoalConditionedBC]] = {}
    todo = [GoalConditionedBC]
    while todo:
        klass = todo.pop()
        if klass.__module__.split(".")[0] == "hispo_pl":
            found[f"{klass.__module__}.{klass.__qualname__}"] = klass
        todo.extend(klass.__subclasses__())
    return found
