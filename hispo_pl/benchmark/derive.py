"""A keep-last run (SC1, FT1) derived from its keep-all sibling's run (SCN, FTN) instead of
trained a second time.

:class:`~hispo_pl.modules.NetworkPerTask` trains the same whether it keeps every task's
network or only the newest (the same random draws, the same weights, the same optimiser
state: ``tests/test_derive.py`` pins it against real runs). So the keep-last run follows from
the keep-all one: after task ``i`` its one network is the sibling's newest, and its row of R
differs only where a finished task ``j < i`` is evaluated (keep-last acts with network ``i``,
keep-all with network ``j``). Those entries are measured again through the evaluation a
task's end runs (:meth:`~hispo_pl.callbacks.RolloutEvaluation.evaluate_task`, with the run's
own episodes and seed); every other entry, the decisions and the datasets are the sibling's.
A derived run's wall time is that evaluation's, not the sibling's training.

    derive_run("runs/scn/seed0", "runs/sc1/seed0")  # writes the keep-last run's files
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TypeVar

from ..errors import RunDirError
from ..results import StreamResults
from ..rundir import RunDir

NETWORK_PER_TASK = "hispo_pl.modules.NetworkPerTask"
ROLLOUT_EVALUATION = "hispo_pl.callbacks.RolloutEvaluation"

C = TypeVar("C")  # a grid cell: a frozen dataclass with name, stream, label, method, seed


# --- which methods, which cells: pure decisions ----------------------------------------------


def _keep(config: Mapping) -> str | None:
    """``keep`` of a NetworkPerTask method config, None for any other method."""
    model = config.get("model") or {}
    if not isinstance(model, Mapping) or model.get("class_path") != NETWORK_PER_TASK:
        return None
    return (model.get("init_args") or {}).get("keep", "all")


def with_keep(config: Mapping, keep: str) -> dict:
    """A copy of a method (or run) config whose NetworkPerTask keeps ``keep``."""
    out = copy.deepcopy(dict(config))
    out["model"]["init_args"]["keep"] = keep
    return out


def keep_last_siblings(method_configs: Mapping[str, Mapping]) -> dict[str, str]:
    """``{keep-last method: its keep-all sibling}``: method configs (parsed YAML, by name)
    that are NetworkPerTask and equal but for ``keep``, so the sibling's run trains both.

    Example:
        >>> last = {"model": {"class_path": NETWORK_PER_TASK, "init_args": {"keep": "last"}}}
        >>> keep_last_siblings({"sc1": last, "scn": with_keep(last, "all")})
        {'sc1': 'scn'}
    """
    out = {}
    for name, config in method_configs.items():
        if _keep(config) != "last":
            continue
        twin = with_keep(config, "all")
        found = [m for m, c in method_configs.items() if m != name and _keep(c) == "all"]
        found = [m for m in found if dict(method_configs[m]) == twin]
        if found:
            out[name] = found[0]
    return out


def sibling_derivations(
    todo: Sequence[C],
    done: Sequence[C],
    sibling: Callable[[C], C | None],
    derivable: Callable[[C], bool],
) -> tuple[list[C], list[tuple[C, C]]]:
    """Which cells of ``todo`` to derive instead of train: those whose ``sibling`` is in
    ``todo`` too (derived once it has trained) or is done and ``derivable`` (its run directory
    with checkpoints is still there). Returns the cells to train and the (target, source)
    pairs; a cell whose sibling is done but gone from disk trains."""
    to_train, finished = {c.name for c in todo}, {c.name for c in done}
    keep, derive = [], []
    for cell in todo:
        source = sibling(cell)
        if source is not None and (
            source.name in to_train or (source.name in finished and derivable(source))
        ):
            derive.append((cell, source))
        else:
            keep.append(cell)
    return keep, derive


def derivable_run(run_dir: Path, committed: Path | None = None) -> bool:
    """Whether ``run_dir`` holds a finished run with a checkpoint for every task (and, given
    ``committed``, the very results committed there), so a sibling can be derived from it."""
    run, kept = RunDir(run_dir), RunDir(committed) if committed is not None else None
    if not run.has_results() or (kept is not None and not kept.has_results()):
        return False
    try:
        results = run.stream_results()
        if kept is not None and kept.stream_results() != results:
            return False
    except RunDirError:
        return False
    return all(run.checkpoint(i).exists() for i in range(len(results.stream)))


# --- the derived files -----------------------------------------------------------------------


def keep_last_checkpoint(checkpoint: dict) -> dict:
    """A keep-all checkpoint after task ``i`` as the keep-last run writes it: its newest
    network alone as ``nets.0``, every finished task mapped to it, ``keep: last``; the rest
    (optimiser, loops, callbacks) is the same, as only the newest network trains."""
    import torch

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


def rewritten_config_text(text: str, run_dir: Path, change: Callable[[dict], None]) -> str:
    """A run's ``config.yaml`` (or ``task_XX.config.yaml``) as another run in ``run_dir``
    writes it: ``change`` applied to the parsed configuration and the logger's directory
    pointing at ``run_dir`` (``save_dir/name/version``), in the same YAML style (leading
    comments kept).

    Raises:
        RunDirError: YAML this cannot rewrite without changing more than those keys."""
    import yaml

    lines = text.splitlines(keepends=True)
    header = "".join(lines[: next((i for i, ln in enumerate(lines) if ln[:1] != "#"), 0)])
    body = text[len(header) :]
    config = yaml.safe_load(body)
    if not isinstance(config, dict) or yaml.safe_dump(config, sort_keys=False) != body:
        raise RunDirError(f"{run_dir}: its source's configuration is not plain YAML to rewrite")
    change(config)
    logger = (config.get("trainer") or {}).get("logger")
    init = logger.get("init_args") if isinstance(logger, dict) else None
    if isinstance(init, dict):
        for key, value in (
            ("save_dir", str(run_dir.parent.parent)),
            ("name", run_dir.parent.name),
            ("version", run_dir.name),
        ):
            if key in init:
                init[key] = value
    return header + yaml.safe_dump(config, sort_keys=False)


def keep_last_config_text(text: str, run_dir: Path) -> str:
    """A keep-all run's ``config.yaml`` (or ``task_XX.config.yaml``) as the keep-last run in
    ``run_dir`` writes it: ``keep: last`` and the logger's directory
    (:func:`rewritten_config_text`).

    Raises:
        RunDirError: not a NetworkPerTask run that keeps all, or YAML this cannot rewrite
            without changing more than those keys."""
    import yaml

    if _keep(yaml.safe_load(text) or {}) != "all":
        raise RunDirError(f"{run_dir}: derives only from a {NETWORK_PER_TASK} run with keep: all")

    def change(config: dict) -> None:
        config["model"]["init_args"]["keep"] = "last"

    return rewritten_config_text(text, run_dir, change)


def _rollout_evaluation(config: dict):
    """The run's end-of-task evaluation callback, built from its saved arguments."""
    from ..callbacks import RolloutEvaluation

    for callback in (config.get("trainer") or {}).get("callbacks") or []:
        if isinstance(callback, dict) and callback.get("class_path") == ROLLOUT_EVALUATION:
            return RolloutEvaluation(**(callback.get("init_args") or {}))
    raise RunDirError(f"the run has no {ROLLOUT_EVALUATION} callback to measure R with")


def derive_run(source: str | Path, target: str | Path, record: dict | None = None) -> StreamResults:
    """:func:`write_derived_run` holding ``target``'s run lock, as a run holds it: two
    launches that derive the same run at once do not write into one folder together.

    Raises:
        RunDirError: another process holds ``target``, or :func:`write_derived_run`'s."""
    from ..resume import RunDirLock

    Path(target).mkdir(parents=True, exist_ok=True)
    with RunDirLock(target):
        return write_derived_run(source, target, record)


def write_derived_run(
    source: str | Path, target: str | Path, record: dict | None = None
) -> StreamResults:
    """Write into ``target`` the keep-last run that the finished keep-all run ``source``
    stands for: its checkpoints, ``config.yaml`` and ``task_XX.config.yaml``,
    ``progress.json``, ``results.json`` (R re-measured below the diagonal, PER, BWT, MEM and
    the table from it, the rest the source's), ``decisions.jsonl`` if the source has one, and
    ``run.json`` (``record``, else the source's without its method and command) naming
    ``derived_from``.
    Returns the results.

    Raises:
        RunDirError: ``source`` is not a finished keep-all NetworkPerTask run with every
            task's checkpoint."""
    import torch
    import yaml

    from ..io import atomic_save, atomic_write_text
    from ..metrics import continual_metrics, memory_ratio, module_bytes, results_row_table
    from ..modules import GoalConditionedBC
    from ..modules.hbc import read_checkpoint
    from ..tasks import parse_task

    src, out = RunDir(source), RunDir(target)
    if not derivable_run(src.path):
        raise RunDirError(f"{src}: no finished run with a checkpoint for every task to derive from")
    results, progress = src.stream_results(), src.read_progress()
    config_text = keep_last_config_text(src.config_file.read_text(), out.path)
    config = yaml.safe_load(config_text)
    evaluation = _rollout_evaluation(config)
    stream = [parse_task(t) for t in results.stream]
    out.path.mkdir(parents=True, exist_ok=True)
    R = [list(row) for row in results.R]
    wall, phases, memory, module = [], [], [], None
    threads = torch.get_num_threads()
    if int(config.get("num_threads") or 0) > 0:
        torch.set_num_threads(int(config["num_threads"]))  # as the run evaluated
    try:
        for i in range(len(stream)):
            start = time.perf_counter()
            checkpoint = keep_last_checkpoint(read_checkpoint(src.checkpoint(i)))
            atomic_save(out.checkpoint(i), lambda tmp, c=checkpoint: torch.save(c, tmp))
            module = GoalConditionedBC.from_checkpoint_file(str(out.checkpoint(i)))
            for j in range(i):  # a finished task, now acting with the newest network
                R[i][j] = evaluation.evaluate_task(stream[j], module, j).success
            seconds = module.task_record.seconds.get("evaluation", 0.0)
            phases.append({"training": 0.0, "evaluation": seconds})
            reference = module_bytes(module.reference_model())
            memory.append(memory_ratio(module_bytes(module), reference))
            wall.append(time.perf_counter() - start)
            if src.task_config(i).exists():
                text = keep_last_config_text(src.task_config(i).read_text(), out.path)
                out.write_task_config(i, text)
    finally:
        torch.set_num_threads(threads)
    matrix = [[math.nan if v is None else v for v in row] for row in R]
    metrics = {**results.metrics, **continual_metrics(matrix, None)}  # FWT: the same diagonal
    stored = module_bytes(module)
    if "MEM" in metrics:
        metrics["MEM"] = memory_ratio(stored, module_bytes(module.reference_model()))
    derived = dataclasses.replace(
        results,
        R=R,
        wall_time_s=wall,
        phase_time_s=phases,
        metrics=metrics,
        stored_bytes=stored,
        table=results_row_table(matrix),
        mem_per_task=memory if results.mem_per_task is not None else None,
    )
    if progress is not None:
        fingerprint = progress.fingerprint
        if fingerprint is not None:  # flat settings: only keep differs
            fingerprint = {**fingerprint, "model.init_args.keep": "last"}
        progress = dataclasses.replace(
            progress,
            rows=R,
            wall_time_s=wall,
            phase_time_s=phases,
            # measured as the source's run measures it
            mem_per_task=memory if progress.mem_per_task is not None else None,
            fingerprint=fingerprint,
        )
        out.write_progress(progress)
    decisions = src.decisions()
    if decisions:  # the task-end decisions of identical training
        out.decisions_file.unlink(missing_ok=True)
        out.append_decisions(decisions)
    atomic_write_text(out.config_file, config_text)
    if record is None:  # the source's, but for its method and the command that made it
        mine = ("method", "argv", "command")
        record = {k: v for k, v in src.read_run_record().items() if k not in mine}
    out.write_run_record({"derived_from": str(src), **record})
    out.write_results(derived)
    return derived
