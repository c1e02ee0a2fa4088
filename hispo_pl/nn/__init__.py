"""Networks: the residual MLP backbone and its subspace version."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from torch import nn


@contextmanager
def eval_mode(module: nn.Module) -> Iterator[nn.Module]:
    """Run a block with dropout off (deterministic predictions), restoring the module's mode.
    Nothing to do, and nothing done, when every submodule is in eval mode already (a rollout
    calls its policy once per step, inside an evaluation that switched once)."""
    if not any(m.training for m in module.modules()):
        yield module
        return
    was_training = module.training
    module.eval()
    try:
        yield module
    finally:
        module.train(was_training)
