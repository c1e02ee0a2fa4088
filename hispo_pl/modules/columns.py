"""Plain networks per task: the scratch (SC1, SCN), fine-tuning (FT1, FTN) and frozen (FRZ)
baselines, and the regularised fine-tuning ones (L2, EWC) built on them.

One module covers the five simple methods through two choices made at each task start:
where the task's network starts (``init``) and which networks are kept (``keep``):

======  ============  ======  ================================================
method  init          keep    acting on an earlier task
======  ============  ======  ================================================
SC1     ``fresh``     last    the newest network (trained on the last task)
SCN     ``fresh``     all     that task's own network
FT1     ``previous``  last    the newest network (fine-tuned through the stream)
FTN     ``previous``  all     that task's own network (a fine-tuned copy)
FRZ     ``previous``  last    the first network (``TaskNetworks(train="first")``)
======  ============  ======  ================================================

The module owns everything inference needs: the networks and the buffer mapping every
finished task to the network it acts with, so a checkpoint alone acts on every task seen.
Growth is carried out by the :class:`~hispo_pl.callbacks.TaskNetworks` callback through the
:class:`GrowingPolicy` protocol.
"""

from __future__ import annotations

import copy
from typing import Literal, Protocol, runtime_checkable

import torch
from torch import Tensor, nn

from ..nn.hierarchy import HierarchicalPolicy
from .hbc import GoalConditionedBC

Init = Literal["fresh", "previous"]
Keep = Literal["all", "last"]


def record_task(mapping: Tensor, task: int, index: int) -> Tensor:
    """``mapping`` (finished task → the network it acts with) with ``task`` set to ``index``;
    tasks finish in order, so a new task is appended."""
    if task < len(mapping):
        mapping = mapping.clone()
        mapping[task] = index
    elif task == len(mapping):
        mapping = torch.cat([mapping, mapping.new_tensor([index])])
    else:
        raise ValueError(f"task {task} finished before tasks 0..{task - 1}")
    return mapping


@runtime_checkable
class GrowingPolicy(Protocol):
    """What :class:`~hispo_pl.callbacks.TaskNetworks` needs from a module."""

    task_index: int

    def start_task(self, task: int) -> None: ...
    def finish_task(self, task: int) -> None: ...
    def freeze_all(self) -> None: ...


class NetworkPerTask(GoalConditionedBC):
    """One backbone network per task, or one for the whole stream (see the module docstring).

    The template for a method that grows networks (docs/extending.md): with the
    :class:`~hispo_pl.callbacks.TaskNetworks` callback, each task calls :meth:`start_task`
    before its optimiser is built and :meth:`finish_task` at its end, before the evaluation.
    A subclass changes how a task's network is made (:meth:`next_network`), what it trains on
    (:meth:`losses`, reading :attr:`training_network`) or what a task's end keeps
    (:meth:`finish_task`, calling ``super()``), and reads :attr:`nets`, :attr:`n_tasks`,
    :attr:`started_task` and :attr:`task_index`.

    Attributes:
        nets: the networks kept, oldest first (``nn.ModuleList``); the last one trains.
        task_network: for each finished task, the index into ``nets`` it acts with.

    Args:
        obs_dim, action_dim, goal_dim: sizes (linked from the data by the CLI).
        backbone: each task's network (:class:`~hispo_pl.config.BackboneConfig`), ``hbc``
            (hierarchical) or ``bc`` (flat), for the BC-vs-HBC table.
        optim: Adam, restarted at every task.
        init: a task's network starts ``fresh`` (scratch) or from the ``previous`` task's.
        keep: ``all`` networks (one per task, each task acts with its own) or the ``last`` one.
    """

    def __init__(self, *args, init: Init = "fresh", keep: Keep = "all", **kwargs):
        super().__init__(*args, **kwargs)
        if init not in ("fresh", "previous"):
            raise ValueError(f"init must be 'fresh' or 'previous', got {init!r}")
        if keep not in ("all", "last"):
            raise ValueError(f"keep must be 'all' or 'last', got {keep!r}")
        self.save_hyperparameters()
        # attributes, not hparams: subclasses that fix them do not take them as arguments
        self.network_init, self.network_keep = init, keep
        self.nets = nn.ModuleList([self.new_network()])
        # network index each finished task acts with (one entry per finished task)
        self.register_buffer("task_network", torch.zeros(0, dtype=torch.long))
        self._started: int | None = None

    def new_network(self) -> HierarchicalPolicy:
        """A freshly initialised single-task network of this method's backbone (as MEM's
        unit, :meth:`reference_model`)."""
        return self.make_policy()

    # --- the GrowingPolicy protocol -------------------------------------------------------

    def next_network(self, task: int) -> HierarchicalPolicy:
        """The network task ``task`` (1 or later) trains, made once when the task starts:
        a copy of the previous task's (``init="previous"``) or a fresh one. The growth hook: a
        subclass returns its own (on any device: it is moved to the module's), and
        :meth:`start_task` freezes the earlier networks and stores it."""
        if self.network_init == "previous":
            return copy.deepcopy(self.nets[-1])
        return self.new_network()

    def start_task(self, task: int) -> None:
        """Make the network task ``task`` trains (before the optimiser is built); idempotent,
        so a resumed run does not grow twice: :meth:`next_network` is asked only for a task
        that has no network yet."""
        if task == 0 or self._started == task or self.n_tasks > task:
            self._started = task
            return
        new = self.next_network(task)
        new.to(self.device)
        self.freeze_all()  # earlier networks (all of them, also after a resume) stay as learned
        if self.network_keep == "all":
            self.nets.append(new)
        else:
            self.nets[0] = new
        new.requires_grad_(True)
        self._started = task

    def finish_task(self, task: int) -> None:
        """Record the network task ``task`` acts with from now on."""
        self.task_network = record_task(self.task_network, task, len(self.nets) - 1)

    @staticmethod
    def keep_last_checkpoint(checkpoint: dict) -> dict:
        """A keep-all checkpoint after task ``i`` as the keep-last run of the same training
        writes it: its newest network alone as ``nets.0``, every finished task mapped to it,
        ``keep: last``; the rest (optimiser, loops, callbacks) is the same, as only the newest
        network trains."""
        state = checkpoint["state_dict"]
        newest = max(int(k.split(".")[1]) for k in state if k.startswith("nets."))
        prefix = f"nets.{newest}."
        out_state = {}
        for key, value in state.items():
            if key.startswith(prefix):
                out_state["nets.0." + key[len(prefix) :]] = value
            elif key == "task_network":
                out_state[key] = torch.zeros_like(value)
            elif not key.startswith("nets."):
                out_state[key] = value
        out = dict(checkpoint)
        out["state_dict"] = out_state
        out["hyper_parameters"] = {**checkpoint["hyper_parameters"], "keep": "last"}
        return out

    @property
    def n_tasks(self) -> int:
        """Tasks finished (each has an entry in :attr:`task_network`)."""
        return len(self.task_network)

    @property
    def started_task(self) -> int | None:
        """The task :meth:`start_task` last started (None before the first)."""
        return self._started

    @property
    def training_network(self) -> HierarchicalPolicy:
        """The network the current task trains: the newest one."""
        return self.nets[-1]

    # --- training and acting --------------------------------------------------------------

    def losses(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        return self.training_network.losses(batch)

    def network_for(self, task: int | None) -> HierarchicalPolicy:
        """A finished task's network; the newest one for the current or an unseen task."""
        if task is not None and task < self.n_tasks:
            return self.nets[int(self.task_network[task])]
        return self.nets[-1]

    def acting_policy(self, task: int) -> tuple[HierarchicalPolicy, None]:
        return self.network_for(task), None

    # --- checkpoints ----------------------------------------------------------------------

    def restore_structure(self, state_dict: dict[str, Tensor]) -> None:
        """As many networks and mapped tasks as the state dict holds, before it loads."""
        indices = {int(k.split(".")[1]) for k in state_dict if k.startswith("nets.")}
        while len(self.nets) < len(indices):
            self.nets.append(self.new_network())
        self.task_network = torch.zeros_like(state_dict["task_network"])
