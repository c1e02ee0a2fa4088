"""A sweep as a tree: runs of one method that differ only in a setting nothing reads before
some task train alike until that task, so a run at another value is copied from a finished run
up to there instead of trained.

Two settings branch:

- the pruning rule's ε (``eps_high``, ``eps_low``). The rule ``L_prev <= (1 + ε) · L_curr`` is
  applied after a task has trained and its search has scored the subspaces, and nothing before
  it reads ε. So a run at ε_b repeats a finished run at ε_a up to the first task where ε_b
  decides otherwise on the losses ε_a's run recorded (``decisions.jsonl``).
- the penalty's λ (``model.init_args.penalty_lambda``, L2 and EWC). The penalty is zero until a
  task has ended, and the task-end statistics (weights, Fisher) do not read λ: every λ trains
  task 1 alike.

The shared tasks are copied (checkpoints, rows of R, decisions, the fingerprint, with the
branch's own value written in), and the run resumes from there through the loop's own resume,
which trains task ``k`` from the checkpoint of task ``k - 1`` with the same seed as an
uninterrupted run (``tests/benchmark/test_branch.py`` pins a branched run to a real one of each
setting). A run that agrees on every task is copied whole and its fit only writes the results.

    settings = {"eps_high": 0.05, "eps_low": 0.05}
    k = shared_tasks(RunDir("runs/eps0.01").decisions(), settings, 4)
    branch_run("runs/eps0.01", "runs/eps0.05", k, settings, record)
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
# a pruning knob -> the subspace whose tolerance it sets
EPS_KEYS = {"eps_high": "high", "eps_low": "low"}
PENALTY_KEY = "model.init_args.penalty_lambda"
PENALTY_UNREAD_TASKS = 1  # λ is first read by task 2's loss: task 1 trains alike at every λ
BRANCHING_KEYS = (*EPS_KEYS, PENALTY_KEY)  # the settings a tree may sweep
_FINGERPRINT_EPS = re.compile(
    rf"trainer\.callbacks\[{PRUNING_CLASS}[^\]]*\]\.init_args\.eps_(high|low)"
)


# --- which tasks two values share: pure --------------------------------------------------------


def branch_settings(extra: Sequence[str]) -> dict[str, float]:
    """The branching settings a run's extra fit arguments set (``--eps_high 0.1 --eps_low 0.1``
    → ``{"eps_high": 0.1, "eps_low": 0.1}``; ``--model.init_args.penalty_lambda 10`` →
    ``{"model.init_args.penalty_lambda": 10.0}``)."""
    pairs = zip(extra[::2], extra[1::2], strict=False)
    return {
        flag.removeprefix("--"): float(value)
        for flag, value in pairs
        if flag.removeprefix("--") in BRANCHING_KEYS
    }


def tolerances(settings: Mapping[str, float]) -> dict[str, float]:
    """The pruning tolerances among ``settings``, by subspace (``{"eps_low": 0.1}`` →
    ``{"low": 0.1}``)."""
    return {EPS_KEYS[key]: value for key, value in settings.items() if key in EPS_KEYS}


def decision_under(record: Decision, eps: Mapping[str, float]) -> str:
    """What the rule decides on a recorded loss decision with the tolerance ``eps`` gives its
    subspace (the recorded decision where ``eps`` names none, or nothing was compared)."""
    if not isinstance(record, LossDecision) or record.l_prev is None:
        return record.decision
    if record.subspace not in eps:
        return record.decision
    keep_new = not keep_previous(record.l_prev, record.l_curr, eps[record.subspace])
    return "keep" if keep_new else "prune"


def shared_tasks(decisions: Sequence[Decision], settings: Mapping[str, float], n_tasks: int) -> int:
    """How many leading tasks a run at ``settings`` shares with the run that recorded
    ``decisions`` over ``n_tasks`` finished tasks: the index of the first task with a decision
    its tolerances would take otherwise, at most one where it sets the penalty's λ, and
    ``n_tasks`` when nothing parts them.

    Example:
        >>> d = [LossDecision(task=1, subspace="low", decision="keep", l_prev=1.2, l_curr=1.0)]
        >>> shared_tasks(d, {"eps_low": 0.25}, 4), shared_tasks(d, {"eps_low": 0.05}, 4)
        (1, 4)
        >>> shared_tasks([], {PENALTY_KEY: 10.0}, 4)
        1
    """
    eps = tolerances(settings)
    differing = [d.task for d in decisions if decision_under(d, eps) != d.decision]
    unread = [PENALTY_UNREAD_TASKS] if PENALTY_KEY in settings else []
    return min([n_tasks, *differing, *unread])


def best_source(
    candidates: Mapping[str, tuple[Sequence[Decision], int]], settings: Mapping[str, float]
) -> tuple[str, int] | None:
    """The candidate (name → its decisions and finished tasks) a run at ``settings`` shares the
    most tasks with, and that count; None when it shares none with any. A tie goes to the
    candidate listed first."""
    best = None
    for name, (decisions, n_tasks) in candidates.items():
        k = shared_tasks(decisions, settings, n_tasks)
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


def branched_checkpoint(checkpoint: dict, settings: Mapping[str, float]) -> dict:
    """A finished task's checkpoint as the run at ``settings`` writes it: the pruning
    callback's entry, where it stored one, under the key its tolerances give
    (``SubspacePruning{'eps': ...}``), and the module's hyperparameters with its λ; the rest,
    trained alike, unchanged."""
    out = dict(checkpoint)
    eps = tolerances(settings)
    callbacks = dict(checkpoint.get("callbacks") or {})
    found = [k for k in callbacks if k.startswith(PRUNING_CLASS)]
    if eps and len(found) > 1:
        raise RunDirError(f"expected one {PRUNING_CLASS} entry in the checkpoint, found {found}")
    if eps and found:
        callbacks[_pruning_key(eps)] = callbacks.pop(found[0])
        out["callbacks"] = callbacks
    hparams = checkpoint.get("hyper_parameters")
    name = PENALTY_KEY.rsplit(".", 1)[1]
    if PENALTY_KEY in settings and isinstance(hparams, dict) and name in hparams:
        out["hyper_parameters"] = {**hparams, name: settings[PENALTY_KEY]}
    return out


def branched_config_text(text: str, run_dir: Path, settings: Mapping[str, float]) -> str:
    """A run's ``config.yaml`` (or ``task_XX.config.yaml``) as the run at ``settings`` in
    ``run_dir`` writes it: the pruning callback's tolerances, the penalty's λ and the logger's
    directory."""
    from .derive import rewritten_config_text

    eps = tolerances(settings)

    def change(config: dict) -> None:
        for callback in (config.get("trainer") or {}).get("callbacks") or []:
            if isinstance(callback, dict) and callback.get("class_path") == PRUNING:
                init = callback.setdefault("init_args", {})
                for name, value in eps.items():
                    init[f"eps_{name}"] = value
        if PENALTY_KEY in settings:
            *path, name = PENALTY_KEY.split(".")
            node = config
            for part in path:
                node = node.setdefault(part, {})
            node[name] = settings[PENALTY_KEY]

    return rewritten_config_text(text, run_dir, change)


def branched_fingerprint(fingerprint: Mapping, settings: Mapping[str, float]) -> dict:
    """A run's fingerprint with the pruning tolerances and the penalty's λ of ``settings``."""
    eps = tolerances(settings)
    out = dict(fingerprint)
    for key in fingerprint:
        match = _FINGERPRINT_EPS.fullmatch(key)
        if match and match.group(1) in eps:
            out[key] = eps[match.group(1)]
    if PENALTY_KEY in settings and PENALTY_KEY in fingerprint:
        out[PENALTY_KEY] = settings[PENALTY_KEY]
    return out


def branch_run(
    source: str | Path,
    target: str | Path,
    tasks: int,
    settings: Mapping[str, float],
    record: LaunchRecord,
) -> None:
    """Start the run at ``settings`` in ``target`` with the first ``tasks`` tasks of the run in
    ``source``: their checkpoints, task configs and search files, ``progress.json`` (rows,
    datasets and fingerprint; no training time, as none was spent), the decisions with its
    tolerances written in, and ``run.json`` (``record`` with ``branched_tasks``, and
    ``branched_from``: the source's directory unless ``record`` names it otherwise).
    The run's own fit then resumes after them. ``target``'s run lock is held meanwhile.

    Raises:
        RunDirError: ``source`` has fewer finished tasks or checkpoints, ``target`` already
            holds a run or another process holds it, or those tasks would not train alike at
            ``settings`` (a decision would differ, or they reach past task 1 at another λ)."""
    from ..resume import RunDirLock

    Path(target).mkdir(parents=True, exist_ok=True)
    with RunDirLock(target):  # as a run holds its folder: two launches never branch into one
        _write_branch(source, target, tasks, settings, record)


def _write_branch(
    source: str | Path,
    target: str | Path,
    tasks: int,
    settings: Mapping[str, float],
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
    if shared_tasks(decisions, settings, tasks) < tasks:
        raise RunDirError(
            f"{src}: its first {tasks} tasks would not train alike at {dict(settings)}"
        )
    out.path.mkdir(parents=True, exist_ok=True)
    for i in range(tasks):
        checkpoint = branched_checkpoint(read_checkpoint(src.checkpoint(i)), settings)
        atomic_save(out.checkpoint(i), lambda tmp, c=checkpoint: torch.save(c, tmp))
        if src.task_config(i).exists():
            text = src.task_config(i).read_text()
            out.write_task_config(i, branched_config_text(text, out.path, settings))
        for subspace in dict.fromkeys(d.subspace for d in decisions if d.task == i):
            search = src.search_file(i, subspace)  # the search's candidates, for the notebook
            if search.is_file():
                real_folder(out.search_file(i, subspace).parent, out.path)
                copy_files([(search, out.search_file(i, subspace))])
    out.decisions_file.unlink(missing_ok=True)
    out.append_decisions([_with_eps(d, tolerances(settings)) for d in decisions])
    fingerprint, memory = progress.fingerprint, progress.mem_per_task
    if fingerprint is not None:
        fingerprint = branched_fingerprint(fingerprint, settings)
    branched = dataclasses.replace(
        progress,
        rows=progress.rows[:tasks],
        datasets=progress.datasets[:tasks],
        mem_per_task=memory[:tasks] if memory is not None else None,
        wall_time_s=[0.0] * tasks,
        phase_time_s=[{"training": 0.0}] * tasks,
        fingerprint=fingerprint,
    )
    launch = LaunchRecord.from_json({"branched_from": str(src)}).merged(record)
    out.write_run_record(launch.merged({"branched_tasks": tasks}))
    out.write_progress(branched)
