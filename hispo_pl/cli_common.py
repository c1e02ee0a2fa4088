"""What every verb shares (``fit``, ``evaluate``, ``render``, ``benchmark``...): the thread
count flag and how it is applied, and how an evaluation's line says that episodes ended with
the agent flipped over. Nothing heavy is imported here: ``fit`` and the other verbs both read it
before any of them runs."""

from __future__ import annotations

import argparse

NUM_THREADS_FLAGS = ("--num_threads", "--num-threads")
"""Every verb takes the thread count as ``--num_threads`` (the configs' key), with
``--num-threads`` as another spelling of it."""


def set_num_threads(n: int) -> None:
    """Torch intra-op threads; 0 keeps torch's default. On 2 shared cores 1 often wins."""
    if n > 0:
        import torch

        torch.set_num_threads(n)


def add_num_threads_argument(parser: argparse.ArgumentParser) -> None:
    """``--num_threads`` (or ``--num-threads``), 1 as in fit's configs: on shared cores one
    thread per process often wins (docs/performance.md)."""
    parser.add_argument(
        *NUM_THREADS_FLAGS,
        type=int,
        default=1,
        help="torch.set_num_threads (default 1, as fit's configs; 0: torch's choice)",
    )


def flip_note(rate: float) -> str:
    """The share of episodes that ended with the agent flipped over, when there were any.

    Example:
        >>> flip_note(0.25), flip_note(0.0)
        (', 25% flipped over', '')
    """
    return f", {100 * rate:.0f}% flipped over" if rate > 0 else ""
