"""Goal-conditioned BC policies as LightningModules: hierarchical (HBC) and flat (BC), and
the plumbing every method shares."""

from __future__ import annotations

import inspect
from pathlib import Path

import lightning as L
import torch
from torch import Tensor, nn

from ..config import BackboneConfig, OptimConfig, plain
from ..errors import CheckpointError, ConfigError, TrainingDivergedError
from ..nn import fast
from ..nn.hierarchy import Forward, HierarchicalPolicy
from ..nn.mlp import GaussianPolicy
from ..nn.program import ProgramOptimizer, TrainingProgram, lr_table
from ..rundir import task_label
from ..task_record import TaskRecord
from .captured import CapturedSteps
from .checkpoints import check_finite_state, check_shapes_on_meta, first_line, read_checkpoint


class GoalConditionedBC(CapturedSteps, L.LightningModule):
    """Shared training plumbing: the backbone and optimiser configs, Adam with an optional
    cosine schedule, loss dict logging, checkpoints that rebuild the module alone.

    The base every method subclasses (``hispo-pl fit`` refuses any other LightningModule:
    the loop, the callbacks, MEM and ``hispo-pl evaluate`` use what it adds). Subclasses
    define :meth:`losses` (a dict with a ``loss`` entry) and :meth:`acting_policy` (which
    network acts on a task), call ``save_hyperparameters()`` at the end of their ``__init__``
    (a checkpoint rebuilds the module from them), and, when they grow, :meth:`restore_structure`.
    The loop sets :attr:`task_index` (0-based) and :attr:`log_prefix` before each task; the
    callbacks fill :attr:`task_record`. A method that grows per task implements
    :class:`~hispo_pl.modules.columns.GrowingPolicy` for the
    :class:`~hispo_pl.callbacks.TaskNetworks` callback, or subclasses
    :class:`~hispo_pl.modules.columns.NetworkPerTask`, which does (docs/extending.md).

    A subclass declares only its own arguments, keyword-only, and forwards the rest:
    ``def __init__(self, *args, own=..., **kwargs): super().__init__(*args, **kwargs)``;
    LightningCLI lists and parses the forwarded ones as the subclass's (jsonargparse reads
    the call), and :meth:`save_hyperparameters` stores them with its own.

    Args:
        obs_dim, action_dim, goal_dim: sizes (linked from the data by the CLI).
        backbone: the network (:class:`~hispo_pl.config.BackboneConfig`).
        optim: Adam's learning rate and schedule (:class:`~hispo_pl.config.OptimConfig`).
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        goal_dim: int = 2,
        backbone: BackboneConfig = BackboneConfig(),
        optim: OptimConfig = OptimConfig(),
    ):
        super().__init__()
        self.obs_dim, self.action_dim, self.goal_dim = obs_dim, action_dim, goal_dim
        self.backbone_config = BackboneConfig.of(backbone)
        self.optim_config = OptimConfig.of(optim)
        self.task_index = 0  # position in a stream, set by the ContinualLoop
        self.log_prefix = ""  # e.g. "task_03/" inside a stream, so curves of tasks do not collide
        self.task_record = TaskRecord()  # what this task's callbacks found (not saved)
        # a captured step trains in its own program: Lightning counts its updates (manual)
        self.automatic_optimization = not self.optim_config.captured
        self._program: TrainingProgram | None = None
        if self.optim_config.captured and (
            type(self).configure_optimizers is not GoalConditionedBC.configure_optimizers
        ):
            raise ConfigError(
                f"--model.init_args.optim.captured: {type(self).__name__} builds its own "
                "optimiser, which a captured step does not run; leave optim.captured off"
            )

    @property
    def lr(self) -> float:
        return self.optim_config.lr

    def save_hyperparameters(self, *args, frame=None, **kwargs) -> None:
        """Lightning's, with the configs stored as plain dicts (``weights_only=True`` loads).

        Called bare, it stores this base's five arguments first, as the base took them: a
        subclass forwards them through ``*args, **kwargs``, where Lightning sees only those
        given by name (not the positional ones, nor the defaults)."""
        super().save_hyperparameters(*args, frame=frame or inspect.currentframe().f_back, **kwargs)
        base = {
            "obs_dim": self.obs_dim,
            "action_dim": self.action_dim,
            "goal_dim": self.goal_dim,
            "backbone": plain(self.backbone_config),
            "optim": plain(self.optim_config),
        }
        for hparams in (self._hparams, self._hparams_initial):
            if args:  # only the names given: the configs among them as plain dicts
                hparams.update({k: base[k] for k in ("backbone", "optim") if k in hparams})
                continue
            items = list(hparams.items())
            hparams.clear()
            # LightningCLI's private entries that lead (``_class_path``) stay first
            while items and items[0][0][:1] == "_":
                hparams.update([items.pop(0)])
            hparams.update(base)
            hparams.update((k, v) for k, v in items if k not in base)

    def on_fit_start(self) -> None:
        """A fresh :class:`~hispo_pl.task_record.TaskRecord` for the task about to train."""
        self.task_record = TaskRecord()

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        """The training losses of a batch (``observation``, ``position``, ``goal``, ``action``,
        ``subgoal``... tensors): a dict of scalars whose ``loss`` entry is minimised; every
        entry is logged as ``<log_prefix>train/<name>``."""
        raise NotImplementedError

    def make_policy(self, head: type[GaussianPolicy] = GaussianPolicy) -> HierarchicalPolicy:
        """A freshly initialised backbone of this module's config and sizes, built of ``head``."""
        return HierarchicalPolicy(
            self.backbone_config, self.obs_dim, self.action_dim, self.goal_dim, head
        )

    def reference_model(self) -> nn.Module:
        """One single-task model of this method's backbone: MEM's unit."""
        return self.make_policy()

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

    def load_checkpoint(self, checkpoint: dict) -> None:
        """Take a checkpoint's state in place: structure first (anchors, columns, networks),
        then the weights. The one loader: the loop's resume and :meth:`from_checkpoint_file`."""
        self.on_load_checkpoint(checkpoint)
        self.load_state_dict(checkpoint["state_dict"])

    def load_checkpoint_file(self, path: str | Path) -> None:
        """:meth:`load_checkpoint` of a file, read with ``weights_only=True``."""
        self.load_checkpoint(read_checkpoint(path))

    @classmethod
    def from_checkpoint_file(cls, path: str) -> GoalConditionedBC:
        """Rebuild whichever method wrote ``path`` (its class is stored in the file), on CPU.

        The file holds plain tensors and values only (``weights_only=True``), and its class
        name is looked up among the methods already imported (:func:`imported_method`):
        nothing the file names is imported.

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
        method = imported_method(name)
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
            check_shapes_on_meta(method, hparams, checkpoint, path)
            module = method(**hparams)
            module.load_checkpoint(checkpoint)
        except (KeyError, TypeError, ValueError, RuntimeError, AttributeError) as err:
            raise CheckpointError(
                f"not a readable hispo-pl checkpoint: {path} ({type(err).__name__}: "
                f"{first_line(err)})"
            ) from None
        return module.eval()

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor | None:
        if not self.automatic_optimization:
            return self._program_step(batch)
        if batch["action"].dim() > 2:
            raise ConfigError(
                "a group of batches (--data.group above 1) trains as several updates of one "
                "captured step: set --model.init_args.optim.captured true, or --data.group 1"
            )
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

    def _divergence_message(self, loss: Tensor, step: int | None = None) -> str:
        trainer = self._trainer
        if step is None:
            step = trainer.global_step + 1 if trainer is not None else "?"
        lr = self.lr
        if trainer is not None and trainer.optimizers:
            lr = float(trainer.optimizers[0].param_groups[0]["lr"])
        return (
            f"training diverged: the loss is {float(loss)} at step {step} of task "
            f"{task_label(self.task_index)} (learning rate {lr:g}); training stopped and nothing "
            "of this task was saved. Lower the learning rate (--model.init_args.optim.lr, now "
            f"{self.lr:g}), or check the data and the other hyperparameters."
        )

    def configure_optimizers(self):
        params = [p for p in self.parameters() if p.requires_grad]
        if not params:  # a method that does not train on this task (FRZ after its first)
            self._program = None
            return None
        steps = self._trainer.max_steps if self._trainer is not None else -1
        if self.optim_config.captured:
            precision = str(self._trainer.precision) if self._trainer is not None else "32-true"
            if precision not in ("32-true", "32"):
                raise ConfigError(
                    f"--model.init_args.optim.captured trains in float32; the Trainer's precision "
                    f"is {precision}: leave --trainer.precision at 32, or optim.captured off"
                )
            rates = lr_table(self.lr, self.optim_config.schedule, steps)
            self._program = TrainingProgram(self.losses, params, rates, self.device)
            return ProgramOptimizer(self._program)
        # fused: one kernel for every tensor's update (the same update as the per-tensor loop)
        opt = torch.optim.Adam(params, lr=self.lr, fused=fast.enabled())
        if fast.enabled():
            fast.retain_freed_memory()
        if self.optim_config.schedule == "constant" or steps is None or steps <= 0:
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
        """Deterministic action; ``task`` selects the task's policy where a method keeps several
        (default: the current task); ``velocity`` is the goal-space velocity, which PointMaze's
        policies read (``low_velocity``) and others ignore, so passing it always works.

        Example: any method's checkpoint reads back as a policy with
        ``GoalConditionedBC.from_checkpoint_file("runs/demo/seed0/task_02.ckpt")`` (its class
        is stored in the file); an untrained one acts the same way::

            >>> import torch
            >>> from hispo_pl.modules import HBC
            >>> policy = HBC(obs_dim=4, action_dim=2)
            >>> obs, pos, goal = torch.zeros(1, 4), torch.zeros(1, 2), torch.ones(1, 2)
            >>> policy.act(obs, pos, goal, task=1, velocity=torch.zeros(1, 2)).shape
            torch.Size([1, 2])
        """
        policy, forward = self.acting_policy(self.task_index if task is None else task)
        return policy.act(observation, position, goal, velocity, forward)

    def acting_policy(self, task: int) -> tuple[HierarchicalPolicy, Forward | None]:
        """The backbone that acts for task ``task`` and how its heads are called (None: plain
        heads); the one thing a method adds to acting."""
        raise NotImplementedError

    def acting_state(self, task: int) -> dict[str, Tensor] | None:
        """Every tensor that acting on task ``task`` reads, by name; None where the method
        does not say. Two equal states act alike, so a rollout measured with one stands for
        the other (:class:`~hispo_pl.callbacks.RolloutEvaluation` reuses it). Here: the
        backbone's state, for a method whose heads are called plainly; a method whose
        ``forward`` reads more (weights over anchors, a column) says what."""
        policy, forward = self.acting_policy(task)
        return dict(policy.state_dict()) if forward is None else None

    def acting_digest(self, task: int) -> str | None:
        """:meth:`acting_state` as one hash (None where it is None)."""
        state = self.acting_state(task)
        return None if state is None else state_digest(state)


def state_digest(state: dict[str, Tensor]) -> str:
    """A hash of named tensors: their names, dtypes, shapes and every byte of their values, so
    equal digests mean bit-for-bit equal tensors.

        >>> import torch
        >>> state_digest({"w": torch.ones(2)}) == state_digest({"w": torch.ones(2)})
        True
        >>> state_digest({"w": torch.ones(2)}) == state_digest({"w": torch.ones(2, 1)})
        False
    """
    import hashlib

    h = hashlib.sha1()
    for name in sorted(state):
        tensor = state[name].detach().cpu().contiguous().reshape(-1)
        h.update(f"{name}|{tensor.dtype}|{tuple(state[name].shape)}|".encode())
        h.update(tensor.view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


class HBC(GoalConditionedBC):
    """Goal-conditioned BC on one task: one backbone network (hierarchical by default), of
    :class:`GoalConditionedBC`'s arguments."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.save_hyperparameters()
        self.net = self.make_policy()

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        return self.net.losses(batch)

    def acting_policy(self, task: int) -> tuple[HierarchicalPolicy, None]:
        return self.net, None


class BC(HBC):
    """Flat goal-conditioned BC (the paper's BC column): :class:`HBC` on the flat backbone."""

    def __init__(self, *args, backbone: BackboneConfig = BackboneConfig(kind="bc"), **kwargs):
        super().__init__(*args, backbone=backbone, **kwargs)


def imported_method(class_path: str) -> type[GoalConditionedBC] | None:
    """The method class ``class_path`` names (``package.module.Name``, as a config or
    LightningCLI's ``_class_path`` spells it), if its module is already imported and the name
    is a :class:`GoalConditionedBC` subclass; else None. Nothing is imported: a checkpoint can
    only pick among the methods hispo-pl (all of them: importing this module runs
    ``hispo_pl.modules``' ``__init__``, which imports each) or the user's own config loaded."""
    import sys

    module_name, _, name = class_path.rpartition(".")
    found = getattr(sys.modules.get(module_name), name, None) if module_name else None
    if isinstance(found, type) and issubclass(found, GoalConditionedBC):
        return found
    return None


def checkpoint_model_hparams(checkpoint: dict, path: str | Path) -> dict:
    """A checkpoint's model hyperparameters in the form LightningCLI parses
    (``class_path`` + ``dict_kwargs``; empty if the file stores none), once every class they
    name has been checked with :func:`imported_method`.

    Raises:
        CheckpointError: a class path that is not an imported hispo-pl method, at any depth."""
    hparams = dict(checkpoint.get("hyper_parameters") or {})
    hparams.pop("_instantiator", None)  # LightningCLI's own hook, never taken from a file
    named = [hparams["_class_path"]] if "_class_path" in hparams else []
    todo = [v for k, v in hparams.items() if k != "_class_path"]
    while todo:
        value = todo.pop()
        if isinstance(value, dict):
            named.extend(v for k, v in value.items() if k in ("class_path", "_class_path"))
            todo.extend(value.values())
        elif isinstance(value, (list, tuple)):
            todo.extend(value)
    for class_path in named:
        if not isinstance(class_path, str) or imported_method(class_path) is None:
            raise CheckpointError(
                f"not a readable hispo-pl checkpoint: {path} names the class {class_path!r}, "
                "which is not one of hispo-pl's methods (nothing it names is imported)"
            )
    if "_class_path" in hparams:
        hparams = {"class_path": hparams.pop("_class_path"), "dict_kwargs": hparams}
    return hparams
