"""CSPO: the single-subspace ablation of HiSPO (the paper's section 5.5, CSP adapted to
offline continual RL with a loss-based selection).

The same HBC backbone, but ONE subspace holds both levels: an anchor is a whole (high, low)
pair of networks, a task adds one, and one weight vector per task mixes both policies. The
search scores the sum of the high and low losses, and one decision keeps or prunes the newest
pair. Everything else, including the callbacks and the checkpoints, is HiSPO's.
"""

from __future__ import annotations

from typing import ClassVar

from .hispo import HiSPO

POLICY = "policy"


class CSPO(HiSPO):
    """One subspace of hierarchical policies: anchors are (high, low) pairs.

    Takes HiSPO's arguments, with the same meaning; the widths stay ``high_hidden`` and
    ``low_hidden`` (MEM's reference HBC is built from them). The single subspace is named
    ``policy``: its anchor count is ``n_anchors("policy")``, its weights per task
    ``task_alphas("policy")`` (buffer ``task_alpha_policy``) and its scores ``scores.policy``;
    :class:`~hispo_pl.callbacks.SubspacePruning` takes its tolerance from ``eps={"policy": ε}``.

    Example:
        >>> m = CSPO(obs_dim=4, action_dim=2)
        >>> m.subspace_names, m.n_anchors("policy")
        (('policy',), 1)
        >>> m.add_anchor("policy")  # one more (high, low) pair
        >>> [m.policies[p].net.n_anchors for p in ("high", "low")]
        [2, 2]
    """

    subspace_policies: ClassVar[dict[str, tuple[str, ...]]] = {POLICY: ("high", "low")}
    subspace_names: ClassVar[tuple[str, ...]] = (POLICY,)
