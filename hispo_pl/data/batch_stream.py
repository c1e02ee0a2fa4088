"""What a training DataLoader iterates: a sampler's batches, ``steps`` per epoch, one at a time
or in groups (:class:`~hispo_pl.data.datamodule.TaskDataModule`'s ``--data.group``)."""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch.utils.data import IterableDataset

from .sampler import HERSampler


class _Batches(IterableDataset):
    """An endless-looking stream of ready-made batches (``steps`` per epoch), or of groups of
    ``group`` batches (``[group, B, ...]`` tensors) when ``group`` > 1."""

    def __init__(self, sampler: HERSampler, steps: int, group: int = 1):
        self.sampler, self.steps, self.group = sampler, steps, group

    def __len__(self) -> int:
        return self.steps

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        for _ in range(self.steps):
            yield (
                self.sampler.sample() if self.group == 1 else self.sampler.sample_group(self.group)
            )
