"""Planning a benchmark: which methods and seeds, the ``fit`` command of each run, and which
runs are still to do. Pure functions, apart from the run records ``pending_runs`` writes."""

from __future__ import annotations

import shlex
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..results import LaunchRecord, StreamResults, TaskFitResult
from ..run_files import read_json_object
from ..rundir import RunDir
from .configs import configured_max_steps, configured_value

PLAN_FILE = "benchmark.json"
RUNS_DIR = "runs"
FIT_MODULE = ("-m", "hispo_pl.cli")  # run with the worker's own interpreter


def known_methods(config_dir: Path) -> list[str]:
    """Method names: the stems of ``config_dir/methods/*.yaml``, sorted."""
    return sorted(p.stem for p in (Path(config_dir) / "methods").glob("*.yaml"))


def select_methods(spec: str, known: Sequence[str]) -> list[str]:
    """``all`` → every known method; ``a,b`` → those, in that order (duplicates dropped).

    Raises:
        ValueError: an unknown name (the message lists the known ones) or an empty list.
    """
    if spec.strip() == "all":
        chosen = list(known)
    else:
        chosen = list(dict.fromkeys(m.strip() for m in spec.split(",") if m.strip()))
    unknown = [m for m in chosen if m not in known]
    if unknown:
        raise ValueError(
            f"unknown method(s) {', '.join(unknown)}; known (configs/methods/*.yaml): "
            f"{', '.join(known) or 'none'}"
        )
    if not chosen:
        raise ValueError(f"no methods selected; known: {', '.join(known) or 'none'}")
    return chosen


def parse_seeds(spec: str) -> list[int]:
    """``3`` → seeds 0, 1, 2; ``0,4`` (any comma) → exactly those seeds.

    Raises:
        ValueError: not integers, negative, repeated, or zero seeds.
    """
    parts = [p.strip() for p in spec.split(",") if p.strip()]
    try:
        values = [int(p) for p in parts]
    except ValueError:
        raise ValueError(f"--seeds takes a count (3) or a comma list (0,4), got {spec!r}") from None
    if "," not in spec:
        if len(values) != 1 or values[0] < 1:
            raise ValueError(
                f"--seeds as a count must be >= 1, got {spec!r} (seed 0 alone: --seeds 1, "
                "or a list such as 0,)"
            )
        return list(range(values[0]))
    if not values or min(values) < 0 or len(set(values)) != len(values):
        raise ValueError(f"--seeds as a list needs distinct non-negative seeds, got {spec!r}")
    return values


def stream_config_path(stream: str, config_dir: Path) -> Path:
    """``pointmaze-1`` → ``config_dir/streams/pointmaze-1.yaml``; a random stream
    (``random-antmaze-8@3``) → its family's first reference stream's config
    (``antmaze-1.yaml``: budget, backbone, data settings), its tasks set by
    :func:`stream_fit_args`; a path to a YAML file is taken as is.

    Raises:
        FileNotFoundError: neither exists (the message lists the known streams).
        TaskSpecError: a malformed random stream name (the message shows the grammar).
    """
    from ..tasks import parse_random_stream

    as_path = Path(stream)
    if as_path.suffix in (".yaml", ".yml") and as_path.is_file():
        return as_path.resolve()
    random = parse_random_stream(stream)
    base = f"{random[0]}-1" if random is not None else stream
    path = Path(config_dir) / "streams" / f"{base}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in (Path(config_dir) / "streams").glob("*.yaml"))
        raise FileNotFoundError(
            f"no stream config {path}; known streams: {', '.join(known) or 'none'} "
            "(or pass a YAML path; --config-dir sets where configs live)"
        )
    return path.resolve()


def stream_fit_args(stream: str) -> tuple[str, ...]:
    """The fit arguments a stream name adds to its config's: a random stream's name, which the
    reference config it borrows (:func:`stream_config_path`) does not hold; none otherwise
    (a named stream, a YAML path)."""
    from ..tasks import parse_random_stream

    if Path(stream).suffix in (".yaml", ".yml"):
        return ()
    return ("--data.stream", stream) if parse_random_stream(stream) is not None else ()


def stream_name(stream: str, stream_config: Path) -> str:
    """The name a benchmark records for its stream: a random stream's own name, else its
    config's stem (``pointmaze-1``, or a YAML file's name)."""
    return stream if stream_fit_args(stream) else Path(stream_config).stem


def fit_argv(
    stream_config: Path,
    method_config: Path,
    method: str,
    seed: int,
    out: Path,
    num_threads: int = 1,
    steps_per_task: int | None = None,
    extra: Sequence[str] = (),
) -> list[str]:
    """The ``hispo-pl fit`` arguments of one run (after ``python -m hispo_pl.cli``).

    The run logs to ``out/runs/<method>/seed<seed>``; Lightning's progress bar is off (the
    output goes to a log file); ``extra`` comes last, so it overrides everything before it.
    """
    argv = [
        "fit",
        "--config",
        str(stream_config),
        "--config",
        str(method_config),
        "--seed_everything",
        str(seed),
        "--num_threads",
        str(num_threads),
    ]
    if steps_per_task is not None:
        argv += ["--trainer.max_steps", str(steps_per_task)]
    argv += [
        "--trainer.logger.init_args.save_dir",
        str(Path(out) / RUNS_DIR),
        "--trainer.logger.init_args.name",
        method,
        "--trainer.logger.init_args.version",
        f"seed{seed}",
        "--trainer.enable_progress_bar",
        "false",
    ]
    return argv + list(extra)


@dataclass(frozen=True)
class PlannedRun:
    """One (method, seed) of a benchmark and the command that produces it."""

    method: str
    seed: int
    run_dir: Path
    argv: tuple[str, ...]  # the arguments after the interpreter: -m hispo_pl.cli fit ...
    steps_per_task: int | None = None
    configs: tuple[Path, ...] = ()  # the stream and method configs in argv, in order
    single_task: bool = False  # a single-task fit (a study's run), finished by its result.json

    @property
    def name(self) -> str:
        return f"{self.method}/seed{self.seed}"

    @property
    def results_path(self) -> Path:
        """The file that marks the run finished and holds what it found."""
        run = RunDir(self.run_dir)
        return run.result_file if self.single_task else run.results_file

    def write_results(self, results: dict) -> None:
        """Write the results a remote worker sent back."""
        run = RunDir(self.run_dir)
        if self.single_task:
            run.write_result(TaskFitResult.from_json(results))
        else:
            run.write_results(StreamResults.from_json(results))

    @property
    def log_path(self) -> Path:
        return RunDir(self.run_dir).fit_log

    def command(self, python: str = "python") -> list[str]:
        return [python, *self.argv]


def plan_run(
    stream_config: Path,
    method_config: Path,
    label: str,
    seed: int,
    out: Path,
    num_threads: int = 1,
    steps_per_task: int | None = None,
    extra: Sequence[str] = (),
) -> PlannedRun:
    """One run of ``method_config`` on ``stream_config``, logging to
    ``out/runs/<label>/seed<seed>`` (``label``: the method's name, or a grid's name for one
    setting of it), with absolute paths in its command (a worker may start elsewhere)."""
    out = Path(out).resolve()
    args = fit_argv(
        stream_config, method_config, label, seed, out, num_threads, steps_per_task, extra
    )
    configs = (Path(stream_config), Path(method_config))
    steps = configured_max_steps(configs, args)
    run_dir = out / RUNS_DIR / label / f"seed{seed}"
    return PlannedRun(label, seed, run_dir, (*FIT_MODULE, *args), steps, configs)


def plan_runs(
    stream_config: Path,
    config_dir: Path,
    methods: Sequence[str],
    seeds: Sequence[int],
    out: Path,
    num_threads: int = 1,
    steps_per_task: int | None = None,
    extra: Sequence[str] = (),
) -> list[PlannedRun]:
    """One run per (method, seed), methods outer (:func:`plan_run`)."""
    return [
        plan_run(
            stream_config,
            (Path(config_dir) / "methods" / f"{method}.yaml").resolve(),
            method,
            seed,
            out,
            num_threads,
            steps_per_task,
            extra,
        )
        for method in methods
        for seed in seeds
    ]


def planned_tasks(run: PlannedRun) -> list[str]:
    """The task specs ``run`` trains, as its ``results.json`` spells them."""
    from ..tasks import parse_stream

    return [
        str(task) for task in parse_stream(configured_value(run.configs, run.argv, "data.stream"))
    ]


def planned_stream(folder: Path) -> str | None:
    """The stream a benchmark's folder (its ``--out``, or an ``--export`` of it) holds, as its
    ``benchmark.json`` names it; None without the file or the name.

    Raises:
        RunDirError: the file is not a JSON object."""
    path = Path(folder) / PLAN_FILE
    if not path.exists():
        return None
    stream = read_json_object(path, "the benchmark's stream; remove it to write it anew").get(
        "stream"
    )
    return str(stream) if stream else None


def foreign_export(runs: Sequence[PlannedRun], stream: str, dest: Path) -> list[str]:
    """What exporting ``runs`` of ``stream`` to ``dest`` would overwrite of another stream:
    its runs of the same method and seed (:func:`foreign_runs`) and its ``benchmark.json``."""
    from dataclasses import replace

    there = [replace(r, run_dir=Path(dest) / r.method / f"seed{r.seed}") for r in runs]
    found = foreign_runs(there, stream)
    old = planned_stream(dest)
    return found + ([f"{PLAN_FILE} ({old})"] if old not in (None, stream) else [])


def foreign_runs(runs: Sequence[PlannedRun], stream: str) -> list[str]:
    """The planned run directories that already hold a run of another stream (by the
    benchmark's ``run.json`` or by the tasks in ``results.json``), described for a message:
    run dirs are named by method and seed only, so a second stream in the same ``--out``
    would reuse or overwrite the first's runs."""
    found = []
    for run in runs:
        run_dir = RunDir(run.run_dir)
        old = run_dir.read_run_record().stream
        if old is not None and old != stream:
            found.append(f"{run.name} ({old})")
        elif run_dir.has_results():
            tasks = run_dir.stream_results().stream
            if tasks != planned_tasks(run):
                found.append(f"{run.name} ({' -> '.join(tasks)})")
    return found


# what else a launch records about the code it runs, each a function giving run.json keys (a
# repository's tool adds its checkout's commit): called in the launching process
CODE_RECORDERS: list[Callable[[], dict]] = []


def processor_name() -> str | None:
    """The CPU's model name (``/proc/cpuinfo``; ``platform.processor()`` elsewhere): torch's
    CPU kernels differ between processors, and with them the last bits of a training run."""
    import platform

    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            for line in info:
                key, _, value = line.partition(":")
                if key.strip() == "model name":
                    return value.strip()
    except OSError:
        pass
    return platform.processor() or None


def provenance() -> LaunchRecord:
    """Where a run is made, for the run's ``run.json``: hispo-pl's version and the machine,
    then what each of :data:`CODE_RECORDERS` adds."""
    import platform

    from ..packages import RESULT_PACKAGES, installed_version
    from .parser import cpu_count

    made = {
        "version": installed_version("hispo-pl"),
        "machine": {
            "platform": platform.platform(),
            "processor": processor_name(),
            "cpus": cpu_count(),
            "python": platform.python_version(),
            **{package: installed_version(package) for package in RESULT_PACKAGES},
        },
    }
    for recorder in CODE_RECORDERS:
        made |= recorder()
    return LaunchRecord.from_json(made)


def provenance_problem(record: LaunchRecord) -> str | None:
    """Why a run's recorded provenance (``run.json``, or :func:`provenance`) does not name
    the code that made it, or None when it does: a recorder of the commit found none, or a tree
    with uncommitted changes. A launch that records no commit at all has nothing to say."""
    if not record.holds("commit"):
        return None
    for commit in launch_commits(record):
        if not commit:
            return "no commit recorded (made outside a git checkout, or before runs recorded one)"
        if str(commit).endswith("+dirty"):
            return f"made from {commit[:12]} with uncommitted changes: no commit holds its code"
    return None


def earlier_than(commits: list[str | None], commit: str | None) -> list[str | None]:
    """The commits of a run's earlier launches, ``commits`` (oldest first), as its launch on
    ``commit`` records them: a last one equal to ``commit`` is the same checkout resumed, not
    an earlier one.

    Example:
        >>> earlier_than(["a", "b"], "b"), earlier_than(["a", "b"], "c")
        (['a'], ['a', 'b'])
    """
    return commits[:-1] if commits and commits[-1] == commit else commits


def launch_commits(old: LaunchRecord) -> list[str | None]:
    """The commits a run was launched on so far, oldest first, from its ``run.json`` (one
    entry per change of commit): what a resumed run's new record keeps as
    ``earlier_commits``, so a run that spans checkouts names every one, and what
    :func:`provenance_problem` checks.

    Example:
        >>> launch_commits(LaunchRecord.from_json({"commit": "b", "earlier_commits": ["a"]}))
        ['a', 'b']
        >>> launch_commits(LaunchRecord.from_json({"commit": "a", "earlier_commits": ["a"]}))
        ['a']
    """
    commits: list[str | None] = []
    for commit in [*(old.earlier_commits or []), old.commit]:
        if not commits or commits[-1] != commit:
            commits.append(commit)
    return commits


def warn_provenance(record: LaunchRecord, what: str) -> bool:
    """Print a loud warning when ``record``'s provenance names no commit that holds the code
    (:func:`provenance_problem`); whether it warned. Results meant for committing should be
    made from a clean tree."""
    problem = provenance_problem(record)
    if problem is not None:
        print(
            f"[benchmark] WARNING: {what}: {problem}. Commit first, then launch, so the run "
            "can be reproduced from its run.json",
            file=sys.stderr,
            flush=True,
        )
    return problem is not None


def pending_runs(
    runs: Sequence[PlannedRun], stream: str | None, made_on: LaunchRecord | None = None
) -> list[PlannedRun]:
    """The runs without results (:attr:`PlannedRun.results_path`: new or interrupted), each
    with a fresh ``run.json`` (method, seed, stream, budget, command, and ``made_on``: the
    :func:`provenance` of this launch); prints a line for each skipped or resumed run, noting
    when its command changed since the first launch."""
    todo = []
    if made_on is not None and runs:
        warn_provenance(made_on, f"launching {len(runs)} run(s)")
    for run in runs:
        run_dir = RunDir(run.run_dir)
        old = run_dir.read_run_record() if run_dir.run_record_file.exists() else None
        # a sweep tree's branch has no launch of its own yet: nothing to compare with
        changed = old is not None and old.argv is not None and old.argv != list(run.argv)
        if run.results_path.exists():
            note = " (it was launched with another command)" if changed else ""
            print(f"[benchmark] {run.name}: skipped, {run.results_path.name} exists{note}")
            continue
        if run_dir.progress_file.exists():
            note = "; note: the command differs from its first launch" if changed else ""
            print(f"[benchmark] {run.name}: resuming an interrupted run{note}")
        run.run_dir.mkdir(parents=True, exist_ok=True)
        record = LaunchRecord.launched(
            method=run.method,
            seed=run.seed,
            stream=stream,
            steps_per_task=run.steps_per_task,
            argv=list(run.argv),
            command=shlex.join(run.command(sys.executable)),
        )
        if made_on is not None:
            record = record.merged(made_on)
        if old is not None:  # a sweep tree's run keeps the record of its branching
            branched = {"branched_from": old.branched_from, "branched_tasks": old.branched_tasks}
            record = record.merged({k: v for k, v in branched.items() if old.holds(k)})
            if run_dir.progress_file.exists() and old.holds("commit") and record.holds("commit"):
                earlier = earlier_than(launch_commits(old), record.commit)
                record = record.merged({"earlier_commits": earlier} if earlier else {})
        run_dir.write_run_record(record)
        todo.append(run)
    return todo
