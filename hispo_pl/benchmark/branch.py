"""A tolerance sweep as a tree: runs of one method that differ only in the pruning rule's ε
train alike until the first task whose decision differs.

The rule ``L_prev <= (1 + ε) · L_curr`` is applied after a task has trained and its search has
scored the subspaces, and nothing before it reads ε. So a run at ε_b repeats, task for task, a
finished run at ε_a up to the first task where ε_b decides otherwise on the losses ε_a's run
recorded (``decisions.jsonl``). Those tasks are copied instead of trained (checkpoints, rows of
R, decisions with ε_b written in, the fingerprint with ε_b's tolerances), and the run at ε_b
resumes from there through the loop's own resume, which trains task ``k`` from the checkpoint
of task ``k - 1`` with the same seed as an uninterrupted run
(``tests/benchmark/test_branch.py`` pins a branched run to a real one). A run that agrees on
every task is copied whole and its fit only writes the results.

    k = shared_tasks(RunDir("runs/eps0.01").decisions(), {"high": 0.05, "low": 0.05}, 4)
    branch_run("runs/eps0.01", "runs/eps0.05", k, {"high": 0.05, "low": 0.05}, record)
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from ..decisions import keep_previous
from ..errors import RunDirError
from ..results import Decision, LaunchRecord, LossDecision
from ..rundir import RunDir

PRUNING_CLASS = "SubspacePruning"
PRUNING = f"hispo_pl.callbacks.{PRUNING_CLASS}"
# a pruning knob's flag -> the subspace whose tolerance it sets
EPS_FLAGS = {"--eps_high": "high", "--eps_low": "low"}
_FINGERPRINT_EPS = re.compile(
    rf"trainer\.callbacks\[{PRUNING_CLASS}[^\]]*\]\.init_args\.eps_(high|low)"
)


# --- which tasks two tolerances share: pure ----------------------------------------------------


def tolerances(extra: Sequence[str]) -> dict[str, float]:
    """The pruning tolerances a run's extra fit arguments set, by subspace
    (``--eps_high 0.1 --eps_low 0.1`` → ``{"high": 0.1, "low": 0.1}``)."""
    pairs = zip(extra[::2], extra[1::2], strict=False)
    return {EPS_FLAGS[flag]: float(value) for flag, value in pairs if flag in EPS_FLAGS}


def decision_under(record: Decision, eps: Mapping[str, float]) -> str:
    """What the rule decides on a recorded loss decision with the tolerance ``eps`` gives its
    subspace (the recorded decision where ``eps`` names none, or nothing was compared)."""
    if not isinstance(record, LossDecision) or record.l_prev is None:
        return record.decision
    if record.subspace not in eps:
        return record.decision
    keep_new = not keep_previous(record.l_prev, record.l_curr, eps[record.subspace])
    return "keep" if keep_new else "prune"


def shared_tasks(decisions: Sequence[Decision], eps: Mapping[str, float], n_tasks: int) -> int:
    """How many leading tasks a run at ``eps`` shares with the run that recorded
    ``decisions`` over ``n_tasks`` finished tasks: the index of the first task with a decision
    ``eps`` would take otherwise, ``n_tasks`` when there is none.

    Example:
        >>> d = [LossDecision(task=1, subspace="low", decision="keep", l_prev=1.2, l_curr=1.0)]
        >>> shared_tasks(d, {"low": 0.25}, 4), shared_tasks(d, {"low": 0.05}, 4)
        (1, 4)
    """
    differing = [d.task for d in decisions if decision_under(d, eps) != d.decision]
    return min([n_tasks, *differing])


def best_source(
    candidates: Mapping[str, tuple[Sequence[Decision], int]], eps: Mapping[str, float]
) -> tuple[str, int] | None:
    """The candidate (name → its decisions and finished tasks) a run at ``eps`` shares the
    most tasks with, and that count; None when it shares none with any. A tie goes to the
    candidate listed first."""
    best = None
    for name, (decisions, n_tasks) in candidates.items():
        k = shared_tasks(decisions, eps, n_tasks)
        if k > 0 and (best is None or k > best[1]):
            best = (name, k)
    return best


# --- the branched run's files ----------------------------------------------------------------


def _with_eps(record: Decision, eps: Mapping[str, float]) -> Decision:
    if isinstance(record, LossDecision) and record.subspace in eps:
        return dataclasses.replace(record, eps=eps[record.subspace])
    return record


def _pruning_key(eps: Mapping[str, float]) -> str:
    from ..callbacks import SubspacePruning

    return SubspacePruning(eps=dict(eps)).state_key


def branched_checkpoint(checkpoint: dict, eps: Mapping[str, float]) -> dict:
    """A finished task's checkpoint as the run at ``eps`` writes it: the pruning callback's
    entry, where it stored one, under the key its tolerances give
    (``SubspacePruning{'eps': ...}``); the rest, trained alike, unchanged."""
    callbacks = dict(checkpoint.get("callbacks") or {})
    found = [k for k in callbacks if k.startswith(PRUNING_CLASS)]
    if not found:
        return checkpoint
    if len(found) > 1:
        raise RunDirError(f"expected one {PRUNING_CLASS} entry in the checkpoint, found {found}")
    state = callbacks.pop(found[0])
    callbacks[_pruning_key(eps)] = state
    return {**checkpoint, "callbacks": callbacks}


def branched_config_text(text: str, run_dir: Path, eps: Mapping[str, float]) -> str:
    """A run's ``config.yaml`` (or ``task_XX.config.yaml``) as the run at ``eps`` in
    ``run_dir`` writes it: the pruning callback's tolerances and the logger's directory."""
    from .derive import rewritten_config_text

    def change(config: dict) -> None:
        for callback in (config.get("trainer") or {}).get("callbacks") or []:
            if isinstance(callback, dict) and callback.get("class_path") == PRUNING:
                init = callback.setdefault("init_args", {})
                for name, value in eps.items():
                    init[f"eps_{name}"] = value

    return rewritten_config_text(text, run_dir, change)


def branched_fingerprint(fingerprint: Mapping, eps: Mapping[str, float]) -> dict:
    """A run's fingerprint with the pruning tolerances of ``eps``."""
    out = dict(fingerprint)
    for key in fingerprint:
        match = _FINGERPRINT_EPS.fullmatch(key)
        if match and match.group(1) in eps:
            out[key] = eps[match.group(1)]
    return out


def branch_run(
    source: str | Path,
    target: str | Path,
    tasks: int,
    eps: Mapping[str, float],
    record: LaunchRecord,
) -> None:
    """Start the run at ``eps`` in ``target`` with the first ``tasks`` tasks of the run in
    ``source``: their checkpoints, task configs and search files, ``progress.json`` (rows,
    datasets and fingerprint; no training time, as none was spent), the decisions with ``eps``
    written in, and ``run.json`` (``record`` with ``branched_tasks``, and ``branched_from``: the
    source's directory unless ``record`` names it otherwise).
    The run's own fit then resumes after them. ``target``'s run lock is held meanwhile.

    Raises:
        RunDirError: ``source`` has fewer finished tasks or checkpoints, ``target`` already
            holds a run or another process holds it, or a decision of those tasks would
            differ at ``eps``."""
    from ..resume import RunDirLock

    Path(target).mkdir(parents=True, exist_ok=True)
    with RunDirLock(target):  # as a run holds its folder: two launches never branch into one
        _write_branch(source, target, tasks, eps, record)


def _write_branch(
    source: str | Path,
    target: str | Path,
    tasks: int,
    eps: Mapping[str, float],
    record: LaunchRecord,
) -> None:
    import torch

    from ..io import atomic_save, copy_files, real_folder
    from ..modules.hbc import read_checkpoint

    src, out = RunDir(source), RunDir(target)
    progress = src.read_progress()
    rows = progress.rows if progress is not None else []
    if len(rows) < tasks or not all(src.checkpoint(i).exists() for i in range(tasks)):
        raise RunDirError(f"{src}: fewer than {tasks} finished tasks with checkpoints to branch")
    if out.progress_file.exists():
        raise RunDirError(f"{out}: already holds a run; branch into an empty directory")
    decisions = [d for d in src.decisions() if d.task < tasks]
    if shared_tasks(decisions, eps, tasks) < tasks:
        raise RunDirError(f"{src}: its first {tasks} tasks decide otherwise at {dict(eps)}")
    out.path.mkdir(parents=True, exist_ok=True)
    for i in range(tasks):
        checkpoint = branched_checkpoint(read_checkpoint(src.checkpoint(i)), eps)
        atomic_save(out.checkpoint(i), lambda tmp, c=checkpoint: torch.save(c, tmp))
        if src.task_config(i).exists():
            text = src.task_config(i).read_text()
            out.write_task_config(i, branched_config_text(text, out.path, eps))
        for subspace in dict.fromkeys(d.subspace for d in decisions if d.task == i):
            search = src.search_file(i, subspace)  # the search's candidates, for the notebook
            if search.is_file():
                real_folder(out.search_file(i, subspace).parent, out.path)
                copy_files([(search, out.search_file(i, subspace))])
    out.decisions_file.unlink(missing_ok=True)
    out.append_decisions([_with_eps(d, eps) for d in decisions])
    fingerprint, memory = progress.fingerprint, progress.mem_per_task
    branched = dataclasses.replace(
        progress,
        rows=progress.rows[:tasks],
        datasets=progress.datasets[:tasks],
        mem_per_task=memory[:tasks] if memory is not None else None,
        wall_time_s=[0.0] * tasks,
        phase_time_s=[{"training": 0.0}] * tasks,
        fingerprint=branched_fingerprint(fingerprint, eps) if fingerprint is not None else None,
    )
    launch = LaunchRecord.from_json({"branched_from": str(src)}).merged(record)
    out.write_run_record(launch.merged({"branched_tasks": tasks}))
    out.write_progress(branched)
