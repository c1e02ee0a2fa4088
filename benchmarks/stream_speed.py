"""A whole stream's wall time on the reference path against the fast path: same stream, method
and seed, the two runs side by side (one thread each), through ``hispo-pl fit`` itself.

    python benchmarks/stream_speed.py [--stream pointmaze-1] [--method hispo] [--seed 0]
        [--steps-per-task N] [--out results/stream-speed] [--config-dir configs]
        [--compare A B] [--repeats R] [-- FIT_ARGS]
    python benchmarks/stream_speed.py --report-only docs/results/stream-speed

``--compare`` names the two variants: a path (``reference`` or ``fast``), optionally followed
by environment settings for its run, ``fast+NAME=VALUE+...`` (default: ``reference fast``).
``--repeats R`` runs the pair R times (each pair side by side, so that load from other jobs
hits both alike) and prints each pair's ratio of wall time and of CPU time, then their
median and spread: on a loaded machine one pair says little. ``FIT_ARGS`` after ``--`` go to
every run's ``fit`` (e.g. fewer evaluation episodes for a short stream).

Each run is the ``fit`` command ``hispo-pl benchmark`` would launch for (stream, method, seed),
run in a child process of this script, the reference one inside
``hispo_pl.nn.fast.reference_path`` (plain autograd modules, masks drawn byte by byte, the
default Adam, a log call every step, glibc's default allocator settings: the training step as
it was before the fast path). The runs log to ``OUT/runs/<method>-<path>/seed<S>`` and resume
like any stream; a finished one is not rerun, so a second call only prints the comparison.

Prints, per task, each run's wall time (training, search, pruning and rollout evaluation, as
``results.json`` records it) and their ratio; where each run's time went (``phase_time_s``:
training steps, the anchor search, rollout evaluation); then each run's PER, BWT, MEM and
anchors, and the largest difference between their success matrices. The two paths draw
different dropout masks, so the results agree within seed noise, not bit for bit.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

PATHS = ("reference", "fast")
CPU_FILE = "cpu_time.json"
"""Written by each run beside its ``results.json``: the CPU seconds its process used."""


def child(path: str, fit_args: list[str], cpu_file: str | None = None) -> int:
    """Run ``hispo-pl fit fit_args`` on ``path``; its CPU seconds go to ``cpu_file``."""
    from contextlib import nullcontext

    from hispo_pl.cli import main
    from hispo_pl.nn import fast

    with fast.reference_path() if path == "reference" else nullcontext():
        code = main(fit_args)
    if cpu_file is not None:
        Path(cpu_file).write_text(json.dumps({"cpu_s": time.process_time()}))
    return code


def parse_variant(spec: str) -> tuple[str, dict[str, str]]:
    """``PATH[+NAME=VALUE...]`` → (path, environment)."""
    path, *settings = spec.split("+")
    if path not in PATHS or not all("=" in s for s in settings):
        raise SystemExit(
            f"[stream_speed] a variant is PATH[+NAME=VALUE...] with PATH in {PATHS}, got {spec!r}"
        )
    return path, dict(s.split("=", 1) for s in settings)


def variant_name(spec: str) -> str:
    """A run name for a variant: ``fast+A=1`` → ``fast-A1``."""
    return spec.replace("+", "-").replace("=", "")


def planned(args, repeat: int | None = None) -> dict:
    """The two runs of one pair: variant → (run dir, fit arguments); ``repeat`` (from 0) gives
    each pair of ``--repeats`` its own run names."""
    from hispo_pl.benchmark.plan import RUNS_DIR, fit_argv, stream_config_path

    config_dir = Path(args.config_dir)
    stream_config = stream_config_path(args.stream, config_dir)
    method_config = (config_dir / "methods" / f"{args.method}.yaml").resolve()
    out = Path(args.out).resolve()
    extra = getattr(args, "fit_args", [])
    runs = {}
    for spec in getattr(args, "compare", PATHS):
        name = f"{args.method}-{variant_name(spec)}" + ("" if repeat is None else f"-r{repeat}")
        argv = fit_argv(
            stream_config, method_config, name, args.seed, out, 1, args.steps_per_task, extra
        )
        runs[spec] = (out / RUNS_DIR / name / f"seed{args.seed}", argv)  # where fit_argv logs
    return runs


def run_both(runs: dict) -> None:
    """Start the unfinished runs side by side and wait for them; exit if one fails."""
    from hispo_pl.benchmark.launch import execute_run, run_env
    from hispo_pl.rundir import RunDir

    todo = {p: r for p, r in runs.items() if not RunDir(r[0]).results_file.exists()}
    for spec in runs:
        state = "to run" if spec in todo else "finished, not rerun"
        print(f"[stream_speed] {spec}: {runs[spec][0]} ({state})", flush=True)

    def launch(spec: str) -> dict:
        run_dir, argv = todo[spec]
        path, env = parse_variant(spec)
        cpu_file = str(Path(run_dir) / CPU_FILE)
        command = [str(Path(__file__).resolve()), "--child", path, cpu_file, "--", *argv]
        return execute_run(
            command,
            str(RunDir(run_dir).fit_log),
            str(RunDir(run_dir).results_file),
            {**run_env(1), **env},
        )

    with ThreadPoolExecutor(max_workers=len(runs)) as pool:
        outcomes = dict(zip(todo, pool.map(launch, todo), strict=True))
    for path, outcome in outcomes.items():
        if outcome["results"] is None:
            sys.exit(
                f"[stream_speed] the {path} run failed (exit {outcome['returncode']}); its log "
                f"ends with:\n{outcome['log_tail']}"
            )
        print(f"[stream_speed] {path}: done in {outcome['seconds'] / 60:.1f} min", flush=True)


def report(runs: dict) -> None:
    import numpy as np

    from hispo_pl.metrics import METRIC
    from hispo_pl.rundir import RunDir

    results = {p: RunDir(r[0]).stream_results() for p, r in runs.items()}
    ref, fast = results.values()
    print(
        "\ntask  reference min  fast min  reference/fast"
        if tuple(runs) == PATHS
        else f"\ntask  {' min  '.join(runs)} min  ratio"
    )
    for i, (a, b) in enumerate(zip(ref.wall_time_s, fast.wall_time_s, strict=True), start=1):
        print(f"T{i:02d}   {a / 60:13.2f}  {b / 60:8.2f}  {a / b:14.2f}")
    total_ref, total_fast = sum(ref.wall_time_s), sum(fast.wall_time_s)
    print(f"all   {total_ref / 60:13.2f}  {total_fast / 60:8.2f}  {total_ref / total_fast:14.2f}\n")
    print("where the time went (minutes over all tasks, share of the stream's wall time)")
    for path, r in results.items():
        totals: dict[str, float] = {}
        for phases in r.phase_time_s or []:
            for name, seconds in (phases or {}).items():
                totals[name] = totals.get(name, 0.0) + seconds
        wall = sum(r.wall_time_s)
        parts = ", ".join(f"{k} {v / 60:.2f} ({v / wall:.0%})" for k, v in totals.items())
        print(f"{path:9s}  {parts or 'not recorded'}")
    print()
    for path, r in results.items():
        anchors = " ".join(f"{k}={v}" for k, v in (r.anchors or {}).items())
        metrics = "  ".join(f"{k} {METRIC[k].format(v):>5s}" for k, v in r.metrics.items())
        print(f"{path:9s}  {metrics}  anchors {anchors or '-'}")
    diff = np.nanmax(np.abs(ref.matrix - fast.matrix))
    print(f"largest success difference between the two R matrices: {100 * diff:.1f} points")


def pair_ratios(runs: dict) -> tuple[float, float | None]:
    """First variant over second: total wall time, and CPU time where both runs recorded it."""
    from hispo_pl.rundir import RunDir

    walls, cpus = [], []
    for run_dir, _ in runs.values():
        walls.append(sum(RunDir(run_dir).stream_results().wall_time_s))
        cpu = Path(run_dir) / CPU_FILE
        cpus.append(json.loads(cpu.read_text())["cpu_s"] if cpu.exists() else None)
    cpu_ratio = cpus[0] / cpus[1] if None not in cpus else None
    return walls[0] / walls[1], cpu_ratio


def report_repeats(pairs: list[dict]) -> None:
    """Each pair's ratios, then their median and spread (min–max)."""
    a, b = pairs[0]
    print(f"\n{a} / {b}, per pair (wall time, CPU time; > 1: {b} is faster)")
    walls, cpus = [], []
    for i, runs in enumerate(pairs):
        wall, cpu = pair_ratios(runs)
        walls.append(wall)
        if cpu is not None:
            cpus.append(cpu)
        print(f"pair {i}  wall {wall:.3f}  CPU " + ("-" if cpu is None else f"{cpu:.3f}"))
    for what, values in (("wall", walls), ("CPU", cpus)):
        if values:
            print(
                f"{what:4s} median {statistics.median(values):.3f}  spread "
                f"{min(values):.3f}-{max(values):.3f}  ({len(values)} pairs)"
            )


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:  # --child PATH [CPU_FILE] -- FIT_ARGS
        split = argv.index("--")
        return child(argv[1], argv[split + 1 :], *argv[2:split])
    fit_args = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stream", default="pointmaze-1")
    parser.add_argument("--method", default="hispo")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps-per-task", type=int, default=None, help="default: the config's")
    parser.add_argument("--out", default="results/stream-speed")
    parser.add_argument("--config-dir", default="configs")
    parser.add_argument("--compare", nargs=2, default=list(PATHS), metavar=("A", "B"))
    parser.add_argument("--repeats", type=int, default=1, help="pairs run one after another")
    parser.add_argument(
        "--report-only",
        metavar="DIR",
        help="print the comparison from exported runs (DIR/<method>-<path>/seed<S>, as "
        "hispo-pl benchmark --export writes them, e.g. docs/results/stream-speed) and run nothing",
    )
    args = parser.parse_args(argv)
    args.fit_args = fit_args
    for spec in args.compare:
        parse_variant(spec)
    if args.report_only:
        base = Path(args.report_only) / "{}" / f"seed{args.seed}"
        names = {spec: f"{args.method}-{variant_name(spec)}" for spec in args.compare}
        report({spec: (Path(str(base).format(name)), []) for spec, name in names.items()})
        return 0
    if args.repeats == 1:
        runs = planned(args)
        run_both(runs)
        report(runs)
        return 0
    pairs = [planned(args, r) for r in range(args.repeats)]
    for runs in pairs:
        run_both(runs)
    report_repeats(pairs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
