"""Memory against tasks for the methods whose memory follows from their structure alone: one
network per task (SCN, FTN) or PNN's columns and laterals. Their MEM after each task of a
stream of any length is what the module stores once it has grown for that many tasks, so it is
computed by growing the product's own module as the loop does (``start_task`` then
``finish_task`` per task, :class:`~hispo_pl.modules.columns.GrowingPolicy`) without training.
``tests/benchmark/test_growth.py`` pins it to the stored size of committed runs.

    memory = structural_memory(module_for(["configs/streams/pointmaze-1.yaml",
                                           "configs/methods/pnn.yaml"]), 12)
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from ..metrics import memory_ratio, module_bytes


def module_for(configs: Sequence[str | Path], *overrides: str):
    """The method module ``hispo-pl fit --config ...`` would train, sized by the stream's data
    (parsed and instantiated, nothing trained or read beyond the configs)."""
    from ..console import lightning_notices_held
    from ..fit import run_lightning_cli

    args = [a for config in configs for a in ("--config", str(config))]
    args += ["--trainer.logger", "false", *overrides]
    with lightning_notices_held():  # a report's output, not a run's: no accelerator lines, tips
        return run_lightning_cli(args, run=False).model


def structural_memory(module, n_tasks: int) -> list[float]:
    """MEM after each of ``n_tasks`` tasks of a growing module (``start_task``, ``finish_task``
    per task, as :class:`~hispo_pl.callbacks.TaskNetworks` calls them), against one
    single-task model of its backbone. The module is grown in place.

    Raises:
        TypeError: a module whose memory depends on its decisions (no ``start_task``)."""
    if not (hasattr(module, "start_task") and hasattr(module, "finish_task")):
        raise TypeError(f"{type(module).__name__} grows by its decisions, not by its structure")
    reference = module_bytes(module.reference_model())
    memory = []
    for task in range(n_tasks):
        module.task_index = task
        module.start_task(task)
        module.finish_task(task)
        memory.append(memory_ratio(module_bytes(module), reference))
    return memory
