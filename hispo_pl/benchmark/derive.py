"""A keep-last run (SC1, FT1) derived from its keep-all sibling's run (SCN, FTN) instead of
trained a second time.

A method whose registry entry has a keep-last variant
(:attr:`~hispo_pl.methods.MethodSpec.keep_last`: NetworkPerTask with ``keep: last``) trains the
same as that sibling (the same random draws, the same weights, the same optimiser state:
``tests/benchmark/test_derive.py`` pins it against real runs). So the keep-last run follows from the
keep-all one: after task ``i`` its checkpoint is the sibling's as the method rewrites it
(:attr:`~hispo_pl.methods.KeepLast.checkpoint`), and its row of R differs only
where a finished task ``j < i`` is evaluated (keep-last acts with network ``i``, keep-all with
network ``j``). Those entries are measured again through the evaluation a task's end runs
(:meth:`~hispo_pl.callbacks.RolloutEvaluation.evaluate_task`, with the run's own episodes and
seed); every other entry, the decisions and the datasets are the sibling's. The derived
``progress.json`` is then finished by the loop itself, as a rerun of a finished stream
(:class:`~hispo_pl.loop.ContinualLoop`: its fingerprint check, its results). A derived run's
wall time is that evaluation's, not the sibling's training.

    derive_run("runs/scn/seed0", "runs/sc1/seed0")  # writes the keep-last run's files
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TypeVar

from ..errors import RunDirError
from ..methods import KeepLast, config_callbacks, config_spec
from ..results import LaunchRecord, Progress, StreamResults
from ..rundir import RunDir

C = TypeVar("C")  # a grid cell: a frozen dataclass with name, stream, label, method, seed


# --- which methods, which cells: pure decisions ----------------------------------------------


def keep_all_twin(config: Mapping) -> dict | None:
    """The configuration of the keep-all run that trains what ``config`` (a method or run
    configuration, parsed YAML) trains, when its method keeps only its newest network
    (:attr:`~hispo_pl.methods.KeepLast.sibling`); None for any other."""
    spec = config_spec(config)
    keep_last = spec.keep_last if spec is not None else None
    return keep_last.sibling(config) if keep_last is not None else None


def keep_last_siblings(method_configs: Mapping[str, Mapping]) -> dict[str, str]:
    """``{keep-last method: its keep-all sibling}``: method configs (parsed YAML, by name)
    whose :func:`keep_all_twin` is another of them, so the sibling's run trains both.

    Example:
        >>> last = {"model": {"class_path": "hispo_pl.modules.NetworkPerTask",
        ...                   "init_args": {"keep": "last"}}}
        >>> keep_last_siblings({"sc1": last, "scn": keep_all_twin(last)})
        {'sc1': 'scn'}
    """
    out = {}
    for name, config in method_configs.items():
        twin = keep_all_twin(config)
        found = [m for m, c in method_configs.items() if m != name and dict(c) == twin]
        if twin is not None and found:
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


def _keep_last(text: str, run_dir: Path) -> KeepLast:
    """How the keep-last sibling of the keep-all run whose configuration is ``text`` follows
    from it (its method's registry entry).

    Raises:
        RunDirError: the run's method has no keep-last variant, or the run is that variant."""
    import yaml

    config = yaml.safe_load(text) or {}
    spec = config_spec(config)
    if spec is None or spec.keep_last is None:
        raise RunDirError(f"{run_dir}: its method has no keep-last variant to derive")
    if spec.keep_last.sibling(config) is not None:
        raise RunDirError(f"{run_dir}: derives only from a run that keeps all (keep: all)")
    return spec.keep_last


def keep_last_config_text(text: str, run_dir: Path) -> str:
    """A keep-all run's ``config.yaml`` (or ``task_XX.config.yaml``) as the keep-last run in
    ``run_dir`` writes it: the keep-last configuration of its method
    (:attr:`~hispo_pl.methods.KeepLast.from_sibling`) and the logger's directory
    (:func:`rewritten_config_text`).

    Raises:
        RunDirError: not a run that keeps all of a method with a keep-last variant, or YAML
            this cannot rewrite without changing more than those keys."""
    return rewritten_config_text(text, run_dir, _keep_last(text, run_dir).from_sibling)


def run_rollout_evaluation(config: dict):
    """The run's end-of-task evaluation callback, built from its saved arguments."""
    from ..callbacks import RolloutEvaluation

    for cls, callback in config_callbacks(config):
        if cls is not None and issubclass(cls, RolloutEvaluation):
            return cls(**(callback.get("init_args") or {}))
    raise RunDirError("the run has no RolloutEvaluation callback to measure R with")


def _nothing_to_train(_):
    raise RunDirError("a derived run has every task finished; nothing trains")


def derive_run(
    source: str | Path, target: str | Path, record: LaunchRecord | None = None
) -> StreamResults:
    """Write into ``target`` the keep-last run that the finished keep-all run ``source``
    stands for: :func:`write_derived_tasks` holding ``target``'s run lock, as a run holds it
    (two launches that derive the same run at once do not write into one folder together),
    then the results as the loop writes them on a rerun of a finished stream. Returns them.

    Raises:
        RunDirError: another process holds ``target``, or :func:`write_derived_tasks`'s."""
    import yaml

    from ..cli_stream import scratch_diagonal
    from ..errors import ConfigError
    from ..loop import ContinualLoop
    from ..metrics import module_bytes
    from ..modules import GoalConditionedBC
    from ..resume import RunDirLock

    out = RunDir(target)
    out.path.mkdir(parents=True, exist_ok=True)
    with RunDirLock(target):
        progress = write_derived_tasks(source, target, record)
    module = GoalConditionedBC.from_checkpoint_file(str(out.checkpoint(progress.done - 1)))
    config = yaml.safe_load(out.config_file.read_text()) or {}
    scratch = None
    if config.get("scratch_results"):
        try:
            scratch = scratch_diagonal(Path(config["scratch_results"]), len(progress.stream))
        except ConfigError as err:
            raise RunDirError(f"{out}: the source's FWT reference: {err}") from None
    reference = module_bytes(module.reference_model())
    no_task = _nothing_to_train
    loop = ContinualLoop(
        progress.stream, module, no_task, no_task, out, reference, scratch,
        fingerprint=progress.fingerprint,
    )  # fmt: skip
    loop.run()
    return out.stream_results()


def write_derived_tasks(
    source: str | Path, target: str | Path, record: LaunchRecord | None = None
) -> Progress:
    """Write into ``target`` every task of the keep-last run that the finished keep-all run
    ``source`` stands for: its checkpoints, ``config.yaml`` and ``task_XX.config.yaml``,
    ``progress.json`` (R re-measured below the diagonal, the fingerprint of the keep-last
    configuration), ``decisions.jsonl`` if the source has one, and ``run.json`` (``record``,
    else the source's without its method and command) naming ``derived_from``. Returns the
    progress; :func:`derive_run` has the loop write the results from it.

    Raises:
        RunDirError: ``source`` is not a finished keep-all run with every task's checkpoint
            of a method that has a keep-last sibling."""
    import torch
    import yaml

    from ..io import atomic_save, atomic_write_text
    from ..metrics import memory_ratio, module_bytes
    from ..modules import GoalConditionedBC
    from ..modules.hbc import read_checkpoint
    from ..run_checks import run_fingerprint
    from ..tasks import parse_task

    src, out = RunDir(source), RunDir(target)
    if not derivable_run(src.path):
        raise RunDirError(f"{src}: no finished run with a checkpoint for every task to derive from")
    results, progress = src.stream_results(), src.read_progress()
    keep_last = _keep_last(src.config_file.read_text(), src.path)
    config_text = keep_last_config_text(src.config_file.read_text(), out.path)
    config = yaml.safe_load(config_text)
    evaluation = run_rollout_evaluation(config)
    stream = [parse_task(t) for t in results.stream]
    R = [list(row) for row in results.R]
    wall, phases, memory, settings = [], [], [], None
    threads = torch.get_num_threads()
    if int(config.get("num_threads") or 0) > 0:
        torch.set_num_threads(int(config["num_threads"]))  # as the run evaluated
    try:
        for i in range(len(stream)):
            start = time.perf_counter()
            checkpoint = keep_last.checkpoint(read_checkpoint(src.checkpoint(i)))
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
                settings = yaml.safe_load(text)  # the settings as the loop took them
    finally:
        torch.set_num_threads(threads)
    if settings is None:
        settings = {k: v for k, v in config.items() if k != "config"}
    kept = progress if progress is not None else Progress(stream=list(results.stream))
    derived = Progress(
        stream=list(results.stream),
        rows=R,
        wall_time_s=wall,
        phase_time_s=phases,
        datasets=list(kept.datasets) or list(results.datasets or []),
        fingerprint=run_fingerprint(settings) if kept.fingerprint is not None else None,
        # measured as the source's run measures it
        mem_per_task=memory if kept.mem_per_task is not None else None,
        extra=dict(kept.extra),
    )
    out.write_progress(derived)
    decisions = src.decisions()
    if decisions:  # the task-end decisions of identical training
        out.decisions_file.unlink(missing_ok=True)
        out.append_decisions(decisions)
    atomic_write_text(out.config_file, config_text)
    if record is None:  # the source's, but for its method and the command that made it
        record = src.read_run_record().without("method", "argv", "command")
    out.write_run_record(LaunchRecord.from_json({"derived_from": str(src)}).merged(record))
    return derived
