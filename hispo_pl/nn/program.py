"""A training step as one program over static buffers: captured once and replayed on CUDA.

The step (a batch's losses, their backward, Adam's update and the learning-rate schedule) is
written once, as :meth:`TrainingProgram._body`: it reads the batch from buffers that keep
their storage from step to step, writes the losses into buffers likewise, and takes the
learning rate from a table on the device indexed by an update counter on the device. Nothing
in it reads a value back to the host, so on CUDA it is captured once per task as a
``torch.cuda.CUDAGraph`` (after a few eager warm-up updates) and each later step is one
replay; elsewhere the same body runs eagerly, which is how the CPU tests pin it to the
module's usual step (same loss, gradients and parameters after an update).

Adam runs fused (one kernel for every tensor), with a capturable state on CUDA (its step
counts live on the device) and its learning rate a device tensor the body writes in place.
Losses are read back only when they are logged; a non-finite loss is noted on the device
(:attr:`TrainingProgram.first_nonfinite`) and checked when the losses are read.

Switched on per method with ``--model.init_args.optim.captured true``
(:class:`~hispo_pl.config.OptimConfig`); ``docs/performance.md`` says what it changes.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterable

import torch
from torch import Tensor

LossFn = Callable[[dict[str, Tensor]], dict[str, Tensor]]


def lr_table(lr: float, schedule: str, steps: int | None) -> list[float]:
    """The learning rate of each update of a task, as the eager step's scheduler sets it:
    ``CosineAnnealingLR(T_max=steps)`` stepped after every update (``cosine``), or ``lr``
    throughout (``constant``, or no step budget). One entry per update (one for a constant
    rate); the program holds the last entry past the end."""
    if schedule == "constant" or steps is None or steps <= 0:
        return [lr]
    opt = torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=lr)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # its optimiser never steps: nothing trains here
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=steps)
        rates = []
        for _ in range(steps):
            rates.append(opt.param_groups[0]["lr"])
            sched.step()
    return rates


class TrainingProgram:
    """One training step of ``losses`` over ``params`` as a function of static buffers.

    Args:
        losses: the module's losses of a batch (a dict of scalars with a ``loss`` entry).
        params: the parameters Adam trains.
        rates: the learning rate of each update (:func:`lr_table`).
        device: where the parameters live; the program captures itself only on CUDA.
        capture: replay a captured graph (CUDA only); False runs the body eagerly.
        warmup: eager updates before the capture (CUDA's allocator and libraries settle).

    Example (on the CPU the body runs eagerly)::

        >>> net = torch.nn.Linear(3, 1)
        >>> program = TrainingProgram(
        ...     lambda b: {"loss": (net(b["x"]) - b["y"]).pow(2).mean()},
        ...     list(net.parameters()), lr_table(1e-2, "cosine", 10), torch.device("cpu"))
        >>> program.run({"x": torch.ones(4, 3), "y": torch.zeros(4, 1)})
        >>> int(program.updates), sorted(program.losses)
        (1, ['loss'])
    """

    def __init__(
        self,
        losses: LossFn,
        params: Iterable[Tensor],
        rates: list[float],
        device: torch.device,
        capture: bool | None = None,
        warmup: int = 3,
    ):
        self.device = torch.device(device)
        self.capture = self.device.type == "cuda" if capture is None else capture
        if self.capture and self.device.type != "cuda":
            raise ValueError(f"a training program is captured on CUDA only, not {self.device}")
        self._losses = losses
        self.params = list(params)
        self.lr = torch.tensor(rates[0], dtype=torch.float32, device=self.device)
        self.rates = torch.tensor(rates, dtype=torch.float32, device=self.device)
        # fused: one kernel for every tensor; capturable: its step counts stay on the device
        self.optimizer = torch.optim.Adam(
            self.params, lr=self.lr, fused=True, capturable=self.device.type == "cuda"
        )
        self.count = torch.zeros(1, dtype=torch.int64, device=self.device)
        self.first_nonfinite = torch.full((1,), -1, dtype=torch.int64, device=self.device)
        self.batch: dict[str, Tensor] | None = None
        self.losses: dict[str, Tensor] = {}
        self.warmup = warmup
        self.graph: torch.cuda.CUDAGraph | None = None
        self._done = 0  # updates run (host count)

    @property
    def updates(self) -> Tensor:
        """Updates done so far (a device tensor: reading it syncs)."""
        return self.count

    def run(self, batch: dict[str, Tensor]) -> None:
        """One update on ``batch`` (copied into the static buffers, on the device)."""
        self._load(batch)
        if not self.capture:
            self.optimizer.zero_grad(set_to_none=True)
            self._body()
        elif self._done < self.warmup:
            self._warm_up()
        else:
            if self.graph is None:
                self._capture()
            self.graph.replay()
        self._done += 1

    def _load(self, batch: dict[str, Tensor]) -> None:
        if self.batch is None:
            self.batch = {k: v.detach().to(self.device, copy=True) for k, v in batch.items()}
            return
        if batch.keys() != self.batch.keys():
            raise ValueError(f"batch keys changed: {sorted(batch)} != {sorted(self.batch)}")
        for key, value in batch.items():
            if value.shape != self.batch[key].shape:
                raise ValueError(
                    f"a training program's batch keeps its shapes: {key} is {tuple(value.shape)}, "
                    f"was {tuple(self.batch[key].shape)}"
                )
            self.batch[key].copy_(value, non_blocking=True)

    def _body(self) -> None:
        """The step: learning rate from the table, losses, backward, Adam, outputs."""
        last = self.rates.shape[0] - 1
        self.lr.copy_(torch.index_select(self.rates, 0, self.count.clamp(max=last)).view(()))
        losses = self._losses(self.batch)
        losses["loss"].backward()
        self.optimizer.step()
        for key, value in losses.items():
            if key not in self.losses:
                self.losses[key] = torch.zeros((), dtype=value.dtype, device=self.device)
            self.losses[key].copy_(value.detach())
        bad = ~torch.isfinite(losses["loss"].detach()).view(1)
        fresh = bad & (self.first_nonfinite < 0)
        self.first_nonfinite.copy_(torch.where(fresh, self.count, self.first_nonfinite))
        self.count.add_(1)

    def _warm_up(self) -> None:
        stream = torch.cuda.Stream(self.device)
        stream.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(stream):
            self.optimizer.zero_grad(set_to_none=True)
            self._body()
        torch.cuda.current_stream(self.device).wait_stream(stream)

    def _capture(self) -> None:
        # the gradients the graph's backward makes are its own buffers, reused by each replay
        self.optimizer.zero_grad(set_to_none=True)
        self.graph = torch.cuda.CUDAGraph()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # e.g. about AccumulateGrad streams
            with torch.cuda.graph(self.graph):
                self._body()

    def read_losses(self) -> dict[str, float]:
        """The last update's losses as floats (one host synchronisation)."""
        return {k: float(v) for k, v in self.losses.items()}

    def nonfinite_update(self) -> int | None:
        """The 0-based update whose loss first was not finite, if any (synchronises)."""
        first = int(self.first_nonfinite)
        return None if first < 0 else first

    def release(self) -> None:
        """Drop the captured graph and its memory pool (at a task's end): the gradients the
        graph wrote live in its pool, so they go too."""
        if self.graph is not None:
            self.optimizer.zero_grad(set_to_none=True)
        self.graph = None
        self.batch = None


class ProgramOptimizer(torch.optim.Optimizer):
    """What the Trainer sees of a :class:`TrainingProgram`: Adam's parameter groups and state
    (checkpoints save and load them), and a :meth:`step` that runs the program once, so that
    each update counts as one optimiser step (``trainer.global_step``, ``max_steps``)."""

    def __init__(self, program: TrainingProgram):
        self.program = program
        inner = program.optimizer
        super().__init__(inner.param_groups, inner.defaults)
        self.state = inner.state
        self._pending: dict[str, Tensor] | None = None

    def step(self, closure: Callable[[], object] | None = None) -> None:  # type: ignore[override]
        """Run Lightning's closure (its hooks; it computes nothing here), then the program on
        the batch loaded with :meth:`load`."""
        if closure is not None:
            closure()
        if self._pending is None:
            raise RuntimeError("ProgramOptimizer.step: load a batch first")
        self.program.run(self._pending)
        self._pending = None

    def load(self, batch: dict[str, Tensor]) -> None:
        """The batch the next :meth:`step` trains on."""
        self._pending = batch

    def zero_grad(self, set_to_none: bool = True) -> None:
        self.program.optimizer.zero_grad(set_to_none=set_to_none)

    def state_dict(self) -> dict:
        return self.program.optimizer.state_dict()

    def load_state_dict(self, state_dict: dict) -> None:
        self.program.optimizer.load_state_dict(state_dict)
        self.state = self.program.optimizer.state
