"""A checkpoint file as hispo-pl reads and writes it: plain tensors and values only
(``weights_only=True``), weights checked finite before they are saved and hyperparameters
checked against the stored shapes before anything is allocated. Every method's loading goes
through here (:meth:`~hispo_pl.modules.hbc.GoalConditionedBC.from_checkpoint_file`)."""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from ..errors import CheckpointError, TrainingDivergedError
from ..rundir import task_label


def read_checkpoint(path: str | Path) -> dict:
    """A checkpoint file's contents, loaded with ``weights_only=True`` on CPU.

    Raises:
        CheckpointError: the file cannot be read as a checkpoint of plain tensors and values
            (corrupt, truncated, not a checkpoint, or holding objects that would run code);
            the message never suggests ``weights_only=False``.
    """
    import pickle
    import re
    import warnings

    try:
        with warnings.catch_warnings():
            # torch names the odd "protocol" of bytes that are no pickle before refusing them
            warnings.filterwarnings("ignore", message="Detected pickle protocol")
            checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except OSError as err:  # the file cannot be read at all
        raise CheckpointError(_not_a_checkpoint(path, first_line(err))) from None
    except pickle.UnpicklingError as err:
        # a class or function named by the file (GLOBAL), which weights_only refuses to load;
        # any other refusal of the unpickler is bytes that are no pickle at all
        found = re.search(r"GLOBAL ([A-Za-z_][\w.]*) (?:was not an allowed|whose module)", str(err))
        if found is None:
            raise CheckpointError(_not_a_checkpoint(path, NOT_A_PICKLE)) from None
        raise CheckpointError(
            f"not a readable hispo-pl checkpoint: {path} holds Python objects other than "
            f"tensors and plain values ({found.group(1)}), which hispo-pl never writes and will "
            "not load"
        ) from None
    except RuntimeError as err:  # torch's reading of its own format: a truncated archive
        raise CheckpointError(_not_a_checkpoint(path, first_line(err))) from None
    except Exception as err:  # noqa: BLE001 - whatever the unpickler trips on in bytes
        empty = isinstance(err, EOFError) and Path(path).stat().st_size == 0
        why = "the file is empty" if empty else NOT_A_PICKLE
        raise CheckpointError(_not_a_checkpoint(path, why)) from None
    if not isinstance(checkpoint, dict) or not isinstance(checkpoint.get("state_dict"), dict):
        raise CheckpointError(
            f"not a readable hispo-pl checkpoint: {path} (no state_dict: not a Lightning "
            "checkpoint)"
        )
    return checkpoint


NOT_A_PICKLE = "its bytes are not a pickle"


def _not_a_checkpoint(path, why: str) -> str:
    return f"not a readable hispo-pl checkpoint: {path} (corrupt, truncated or not one: {why})"


def check_shapes_on_meta(method, hparams: dict, checkpoint: dict, path) -> None:
    """Build ``method`` from a checkpoint's hyperparameters on the meta device (no memory)
    and compare its tensors' shapes with the stored ones, so that hyperparameters that do not
    match the weights (a crafted hidden size of a billion) are refused before anything is
    allocated. A method that cannot be built on the meta device is checked when loaded."""
    stored = checkpoint["state_dict"]
    try:
        with torch.device("meta"):
            probe = method(**hparams)
            probe.on_load_checkpoint(checkpoint)
        expected = {k: tuple(v.shape) for k, v in probe.state_dict().items()}
    except (RuntimeError, NotImplementedError):
        return
    for name in sorted(set(expected) | set(stored)):
        have = tuple(stored[name].shape) if torch.is_tensor(stored.get(name)) else None
        if expected.get(name) != have:
            raise CheckpointError(
                f"not a readable hispo-pl checkpoint: {path} (its hyperparameters make "
                f"{name} of shape {expected.get(name)}, its weights hold {have})"
            )


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
                f"{task_label(task_index)}; nothing was saved. Lower the learning rate "
                "(--model.init_args.optim.lr)."
            )


def first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__
