"""``hispo-pl benchmark``: every method × seed on one stream, then the paper's tables.

    hispo-pl benchmark --stream pointmaze-1 --methods all --seeds 3 --out results/pointmaze-1

Each run is one ``hispo-pl fit`` subprocess (the stream config, then the method config) that
logs to ``OUT/runs/<method>/seed<S>/``; ``fit`` itself resumes a stream at task granularity,
so the runner only skips runs whose ``results.json`` exists and reruns the others with the
same command. Runs go to local worker processes or, with ``--launcher ray``, to Ray remote
tasks. Afterwards ``OUT/table.md``, ``table.csv``, ``runtime.csv`` and ``perf_vs_memory.png``
are rebuilt from every ``results.json`` under ``OUT/runs`` (``--report-only`` does just that).

Planning (methods, seeds, command lines) and aggregation (FWT against the SC run of the same
seed, mean ± std over seeds, table text) are pure functions; only the launchers touch
processes. numpy only at import, so Ray workers start quickly; matplotlib and ray lazily.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import shlex
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .io import atomic_write_text
from .metrics import continual_metrics
from .rundir import RunDir

PLAN_FILE = "benchmark.json"
RUNS_DIR = "runs"
FIT_MODULE = ("-m", "hispo_pl.cli")  # run with the worker's own interpreter
SCALED = ("PER", "BWT", "FWT")  # success fractions, reported ×100 like the paper
TAIL_LINES = 25


# --- planning ---------------------------------------------------------------------------------


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
            raise ValueError(f"--seeds as a count must be >= 1, got {spec!r}")
        return list(range(values[0]))
    if not values or min(values) < 0 or len(set(values)) != len(values):
        raise ValueError(f"--seeds as a list needs distinct non-negative seeds, got {spec!r}")
    return values


def stream_config_path(stream: str, config_dir: Path) -> Path:
    """``pointmaze-1`` → ``config_dir/streams/pointmaze-1.yaml``; a path to a YAML file is
    taken as is.

    Raises:
        FileNotFoundError: neither exists (the message lists the known streams).
    """
    as_path = Path(stream)
    if as_path.suffix in (".yaml", ".yml") and as_path.is_file():
        return as_path.resolve()
    path = Path(config_dir) / "streams" / f"{stream}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in (Path(config_dir) / "streams").glob("*.yaml"))
        raise FileNotFoundError(
            f"no stream config {path}; known streams: {', '.join(known) or 'none'} "
            "(or pass a YAML path; --config-dir sets where configs live)"
        )
    return path.resolve()


def _override_value(overrides: Sequence[str], key: str) -> str | None:
    """The last value given to ``--key`` in a jsonargparse argument list (``--k v`` or
    ``--k=v``), or None."""
    value = None
    for i, arg in enumerate(overrides):
        if arg == key and i + 1 < len(overrides):
            value = overrides[i + 1]
        elif arg.startswith(key + "="):
            value = arg.split("=", 1)[1]
    return value


_UNSET = object()


def configured_value(configs: Sequence[Path], overrides: Sequence[str], key: str):
    """The value ``fit`` will see for a dotted ``key`` (``trainer.max_steps``): the last
    ``--key`` in ``overrides`` (parsed as YAML, as jsonargparse does), else the last config
    file (in order) that sets it, else None."""
    import yaml  # a dependency of jsonargparse and lightning

    given = _override_value(overrides, f"--{key}")
    if given is not None:
        return yaml.safe_load(given)
    value = None
    for path in configs:
        node = yaml.safe_load(Path(path).read_text()) or {}
        for part in key.split("."):
            node = node.get(part, _UNSET) if isinstance(node, dict) else _UNSET
        if node is not _UNSET:
            value = node
    return value


def configured_max_steps(configs: Sequence[Path], overrides: Sequence[str] = ()) -> int | None:
    """Gradient steps per task that ``fit`` will use (``trainer.max_steps``)."""
    steps = configured_value(configs, overrides, "trainer.max_steps")
    return None if steps is None else int(steps)


def datasets_needed(configs: Sequence[Path], overrides: Sequence[str] = ()) -> dict[str, int]:
    """Our local maze datasets a run reads (``pointmaze-umaze`` → episodes it needs); empty
    when ``data.dataset`` names another Minari dataset or no stream is configured."""
    from .data.tasks import parse_stream

    stream = configured_value(configs, overrides, "data.stream")
    if not stream or configured_value(configs, overrides, "data.dataset"):
        return {}
    needed: dict[str, int] = {}
    for task in parse_stream(stream):
        needed[task.dataset_name] = max(needed.get(task.dataset_name, 0), task.episodes)
    return needed


def prepare_datasets(needed: dict[str, int]) -> None:
    """Generate the missing local datasets here, once, before the runs start: runs that each
    generated a missing dataset on first use would race on the same files."""
    from .data.datasets import dataset_exists, default_episodes, generate_dataset, local_dataset_id

    for name, episodes in sorted(needed.items()):
        if not dataset_exists(local_dataset_id(name)):
            print(f"[benchmark] generating the {name} expert dataset before the runs start")
            generate_dataset(name, episodes=max(episodes, default_episodes(name)))


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

    @property
    def name(self) -> str:
        return f"{self.method}/seed{self.seed}"

    @property
    def results_path(self) -> Path:
        return RunDir(self.run_dir).results_file

    @property
    def log_path(self) -> Path:
        return RunDir(self.run_dir).fit_log

    def command(self, python: str = "python") -> list[str]:
        return [python, *self.argv]


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
    """One run per (method, seed), methods outer, with absolute paths in every command (a
    worker may start elsewhere)."""
    out = Path(out).resolve()
    runs = []
    for method in methods:
        method_config = (Path(config_dir) / "methods" / f"{method}.yaml").resolve()
        for seed in seeds:
            args = fit_argv(
                stream_config, method_config, method, seed, out, num_threads, steps_per_task, extra
            )
            configs = (Path(stream_config), method_config)
            steps = configured_max_steps(configs, args)
            run_dir = out / RUNS_DIR / method / f"seed{seed}"
            runs.append(PlannedRun(method, seed, run_dir, (*FIT_MODULE, *args), steps, configs))
    return runs


# --- aggregation ------------------------------------------------------------------------------


@dataclass
class RunRecord:
    """A finished run as found on disk: its ``results.json``, its decision records and, if the
    benchmark launched it, its ``run.json``."""

    method: str
    seed: int
    results: dict
    meta: dict = field(default_factory=dict)
    decisions: list[dict] = field(default_factory=list)


def finished_run_dirs(out: Path) -> list[Path]:
    """Run folders with a ``results.json``: ``OUT/runs/<method>/seed<S>`` (where the benchmark
    runs them) or ``OUT/<method>/seed<S>`` (an exported copy, e.g. under ``docs/results``)."""
    out = Path(out)
    found = list(out.glob(f"{RUNS_DIR}/*/seed*/{RunDir.RESULTS}"))
    found += [p for p in out.glob(f"*/seed*/{RunDir.RESULTS}") if p.parts[-3] != RUNS_DIR]
    return sorted(p.parent for p in found)


def load_records(out: Path) -> list[RunRecord]:
    """Every finished run under ``out`` (:func:`finished_run_dirs`), sorted by method then seed."""
    records = []
    for seed_dir in finished_run_dirs(out):
        try:
            seed = int(seed_dir.name.removeprefix("seed"))
        except ValueError:
            continue
        run = RunDir(seed_dir)
        meta, decisions, results = run.read_run_record(), run.read_decisions(), run.read_results()
        records.append(RunRecord(seed_dir.parent.name, seed, results, meta, decisions))
    return sorted(records, key=lambda r: (r.method, r.seed))


def export_runs(out: Path, dest: Path) -> list[Path]:
    """Copy the small files of every finished run under ``out`` (results, decisions, config,
    run record; never checkpoints or event files) to ``dest/<method>/seed<S>/``, the layout
    that is committed under ``docs/results/<stream>/`` and read back by ``--report-only``."""
    written = []
    if (Path(out) / PLAN_FILE).exists():  # the stream's name, for the report's title
        Path(dest).mkdir(parents=True, exist_ok=True)
        (Path(dest) / PLAN_FILE).write_bytes((Path(out) / PLAN_FILE).read_bytes())
        written.append(Path(dest) / PLAN_FILE)
    for seed_dir in finished_run_dirs(out):
        target = Path(dest) / seed_dir.parent.name / seed_dir.name
        target.mkdir(parents=True, exist_ok=True)
        for name in RunDir.EXPORTED:
            if (seed_dir / name).exists():
                (target / name).write_bytes((seed_dir / name).read_bytes())
                written.append(target / name)
    return written


def scratch_method_for(method: str, available: Iterable[str]) -> str | None:
    """The from-scratch run whose R diagonal is ``method``'s FWT reference: ``scn``, else
    ``sc1``; for flat-BC methods (``bc-*``) ``bc-scn``, else ``bc-sc1``; None if none ran."""
    prefix = "bc-" if method.startswith("bc-") else ""
    available = set(available)
    for candidate in (f"{prefix}scn", f"{prefix}sc1"):
        if candidate in available:
            return candidate
    return None


def results_matrix(results: dict) -> np.ndarray:
    """``results["R"]`` as a float array, NaN where JSON has null (above the diagonal)."""
    return np.array(
        [[np.nan if v is None else v for v in row] for row in results["R"]], dtype=float
    )


def run_metrics(results: dict, scratch_results: dict | None = None) -> dict:
    """PER, BWT (from R), FWT (against the diagonal of ``scratch_results``'s R, when given
    and of the same size), MEM and anchors (when the run has them). Fractions, not ×100."""
    R = results_matrix(results)
    scratch = None
    if scratch_results is not None:
        R_scratch = results_matrix(scratch_results)
        if R_scratch.shape == R.shape:
            scratch = np.diagonal(R_scratch)
    out: dict = continual_metrics(R, scratch)
    if results.get("MEM") is not None:
        out["MEM"] = float(results["MEM"])
    if results.get("anchors"):
        out["anchors"] = {k: float(v) for k, v in results["anchors"].items()}
    return out


def mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and population standard deviation (as :func:`hispo_pl.metrics.summarize_runs`)."""
    arr = np.asarray(values, dtype=float)
    return float(arr.mean()), float(arr.std())


def format_mean_std(mean: float, std: float, scale: float = 100.0, digits: int = 1) -> str:
    """``81.0 ± 1.2``: mean ± std × ``scale`` (×100 for success fractions, as the paper)."""
    return f"{scale * mean:.{digits}f} ± {scale * std:.{digits}f}"


@dataclass
class MethodRow:
    """One method's line of the table: metrics as (mean, std) over seeds, in fractions (PER,
    BWT, FWT) or ratios (MEM, anchors); None where no seed has it."""

    method: str
    seeds: list[int]
    PER: tuple[float, float]
    BWT: tuple[float, float]
    FWT: tuple[float, float] | None = None
    MEM: tuple[float, float] | None = None
    anchors: dict[str, tuple[float, float]] = field(default_factory=dict)
    fwt_reference: str | None = None


def aggregate(records: Sequence[RunRecord]) -> tuple[list[MethodRow], list[str]]:
    """One row per method (sorted) and footnotes.

    FWT of a method uses, for each seed, the R diagonal of the from-scratch run of the same
    seed (:func:`scratch_method_for`); it is left empty, with a footnote, unless every seed of
    the method has one.
    """
    by_seed: dict[int, dict[str, RunRecord]] = {}
    for r in records:
        by_seed.setdefault(r.seed, {})[r.method] = r
    methods = sorted({r.method for r in records})
    rows, notes = [], []
    for method in methods:
        mine = [r for r in records if r.method == method]
        metrics, references, missing = [], set(), []
        for r in mine:
            ref = scratch_method_for(method, by_seed[r.seed])
            scratch = by_seed[r.seed][ref].results if ref else None
            m = run_metrics(r.results, scratch)
            if "FWT" in m:
                references.add(ref)
            else:
                missing.append(r.seed)
            metrics.append(m)
        row = MethodRow(
            method,
            [r.seed for r in mine],
            mean_std([m["PER"] for m in metrics]),
            mean_std([m["BWT"] for m in metrics]),
        )
        if missing:
            prefix = "bc-" if method.startswith("bc-") else ""
            seeds = ", ".join(str(s) for s in missing)
            notes.append(
                f"{method}: no FWT, no {prefix}scn or {prefix}sc1 run (with the same stream) "
                f"for seed {seeds}"
            )
        else:
            row.FWT = mean_std([m["FWT"] for m in metrics])
            row.fwt_reference = ", ".join(sorted(references))
        if all("MEM" in m for m in metrics):
            row.MEM = mean_std([m["MEM"] for m in metrics])
        names = sorted({k for m in metrics for k in m.get("anchors", {})})
        for name in names:
            if all(name in m.get("anchors", {}) for m in metrics):
                row.anchors[name] = mean_std([m["anchors"][name] for m in metrics])
        rows.append(row)
    return rows, notes


def _cell(value: tuple[float, float] | None, scale: float, digits: int) -> str:
    return "" if value is None else format_mean_std(*value, scale=scale, digits=digits)


def table_markdown(rows: Sequence[MethodRow], notes: Sequence[str], stream: str = "") -> str:
    """The paper's table: PER, BWT, FWT ×100 and MEM as mean ± std over seeds, anchors."""
    title = f"# Benchmark{': ' + stream if stream else ''}\n\n"
    lines = [
        "| method | seeds | PER | BWT | FWT | MEM | anchors |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for row in rows:
        anchors = ", ".join(f"{k} {_cell(v, 1, 1)}" for k, v in row.anchors.items())
        fwt = _cell(row.FWT, 100, 1) + ("" if row.FWT is not None or not notes else " ¹")
        lines.append(
            f"| {row.method} | {len(row.seeds)} | {_cell(row.PER, 100, 1)} | "
            f"{_cell(row.BWT, 100, 1)} | {fwt.strip()} | {_cell(row.MEM, 1, 2)} | {anchors} |"
        )
    legend = (
        "\nPER, BWT, FWT: success ×100, mean ± std (population) over seeds; MEM: stored size "
        "over one single-task model; anchors: per subspace. FWT is measured against the R "
        "diagonal of the from-scratch run of the same seed (scn, else sc1; bc-scn, else bc-sc1 "
        "for bc- methods).\n"
    )
    footnotes = "".join(f"\n¹ {note}" for note in notes)
    return title + "\n".join(lines) + "\n" + legend + footnotes + ("\n" if notes else "")


def table_csv(rows: Sequence[MethodRow]) -> str:
    """Machine-readable table: ``<metric>_mean`` and ``<metric>_std`` columns (PER, BWT, FWT
    ×100; MEM and anchors as ratios / counts), empty where unknown."""
    anchor_names = sorted({k for row in rows for k in row.anchors})
    header = ["method", "seeds"]
    for name in [*SCALED, "MEM", *(f"anchors_{a}" for a in anchor_names)]:
        header += [f"{name}_mean", f"{name}_std"]
    header.append("fwt_reference")
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        cells: list = [row.method, len(row.seeds)]
        values = [row.PER, row.BWT, row.FWT, row.MEM, *(row.anchors.get(a) for a in anchor_names)]
        scales = [100, 100, 100, 1] + [1] * len(anchor_names)
        for value, scale in zip(values, scales, strict=True):
            cells += ["", ""] if value is None else [round(scale * v, 4) for v in value]
        cells.append(row.fwt_reference or "")
        writer.writerow(cells)
    return buf.getvalue()


def _loss(value: float | None) -> str:
    return "" if value is None else f"{value:.4f}"


def decisions_markdown(records: Sequence[RunRecord], stream: str = "") -> str:
    """Every keep / prune decision of every run: the losses the rule compared (held-out), the
    same points on training episodes, and how much ``L_curr`` still fell over the last steps
    of the task (the convergence diagnostic; above ε the budget decided)."""
    lines = [
        f"# Decisions{': ' + stream if stream else ''}\n",
        "| method | seed | task | subspace | L_prev | L_curr | L_prev / L_curr | ε | "
        "train L_prev / L_curr | convergence | decision | anchors |",
        "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for r in records:
        for d in r.decisions:
            if d.get("decision") not in ("first", "keep", "prune") or d.get("rule") == "critic":
                continue  # zero-shot records carry no losses; CSP decides by its critic
            ratio = d["l_prev"] / d["l_curr"] if d.get("l_prev") is not None else None
            train = (
                d["l_prev_train"] / d["l_curr_train"]
                if d.get("l_prev_train") is not None and d.get("l_curr_train")
                else None
            )
            conv = d.get("improvement")
            lines.append(
                f"| {r.method} | {r.seed} | {d['task'] + 1} | {d['subspace']} | "
                f"{_loss(d.get('l_prev'))} | {_loss(d['l_curr'])} | "
                f"{'' if ratio is None else f'{ratio:.3f}'} | {d.get('eps', '')} | "
                f"{'' if train is None else f'{train:.3f}'} | "
                f"{'' if conv is None else f'{conv:+.1%}'} | {d['decision']} | {d['anchors']} |"
            )
    if len(lines) == 3:
        return ""
    legend = (
        "\nLosses: squared error of the deterministic prediction on the task's held-out "
        "episodes (train: on its training episodes). The rule prunes iff L_prev / L_curr ≤ "
        "1 + ε. Convergence: relative fall of L_curr over the last 20 % of the task's steps. "
        "CSP's critic decisions (W, not losses) are in its decisions.jsonl (docs/csp.md).\n"
    )
    return "\n".join(lines) + "\n" + legend


def runtime_csv(records: Sequence[RunRecord]) -> str:
    """One line per run: method, seed, wall minutes (sum of the tasks' ``wall_time_s``),
    steps per task (from ``run.json``; empty for runs the benchmark did not launch)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["method", "seed", "minutes", "steps_per_task"])
    for r in records:
        minutes = sum(r.results.get("wall_time_s", [])) / 60
        steps = r.meta.get("steps_per_task")
        writer.writerow([r.method, r.seed, round(minutes, 3), "" if steps is None else steps])
    return buf.getvalue()


def plot_perf_vs_memory(rows: Sequence[MethodRow], path: Path, stream: str = "") -> bool:
    """The paper's Figure 2: MEM on x, PER on y, one marker per method with error bars over
    seeds. Returns False (after a printed note) when matplotlib is not installed."""
    try:
        from matplotlib.figure import Figure  # no pyplot: no global backend state
    except ImportError:
        print(
            "[benchmark] matplotlib is not installed: no perf_vs_memory.png (pip install "
            "matplotlib, or the dev extra); the tables are written"
        )
        return False
    fig = Figure(figsize=(6.0, 4.5))
    ax = fig.add_subplot()
    markers = "osD^vP*Xh<>p"
    for i, row in enumerate(r for r in rows if r.MEM is not None):
        (x, xs), (y, ys) = row.MEM, row.PER
        ax.errorbar(
            x,
            100 * y,
            xerr=xs,
            yerr=100 * ys,
            fmt=markers[i % len(markers)],
            capsize=3,
            label=row.method,
        )
        ax.annotate(row.method, (x, 100 * y), textcoords="offset points", xytext=(5, 5), fontsize=8)
    ax.set_xlabel("MEM (stored size / one single-task model)")
    ax.set_ylabel("PER (success %, mean ± std over seeds)")
    ax.set_title(f"Performance vs memory{': ' + stream if stream else ''}")
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8, loc="best")
    fig.savefig(path, dpi=150, bbox_inches="tight")
    return True


def unfinished_runs(out: Path) -> list[tuple[str, int, str]]:
    """(method, seed, status) of every run the benchmark launched (it has a ``run.json``)
    without a ``results.json``: failed (with its exit status and log), or not finished."""
    found = []
    for meta_path in sorted((Path(out) / RUNS_DIR).glob(f"*/seed*/{RunDir.RUN_RECORD}")):
        seed_dir = meta_path.parent
        run = RunDir(seed_dir)
        if run.has_results():
            continue
        try:
            meta = run.read_run_record()
            seed = int(seed_dir.name.removeprefix("seed"))
        except ValueError:
            continue
        status = meta.get("status") or "not finished (interrupted, or still running)"
        found.append((seed_dir.parent.name, seed, status))
    return found


def unfinished_markdown(runs: Sequence[tuple[str, int, str]]) -> str:
    """The table.md section listing runs without results, so a failed method is never
    silently missing from the table."""
    if not runs:
        return ""
    lines = ["", "## Runs without results", "", "| method | seed | status |", "|---|---:|---|"]
    lines += [f"| {method} | {seed} | {status} |" for method, seed, status in runs]
    return "\n".join(lines) + "\n"


def write_report(out: Path, stream: str | None = None) -> list[Path]:
    """Rebuild ``table.md``, ``table.csv``, ``runtime.csv`` and ``perf_vs_memory.png`` in
    ``out`` from every finished run under ``out/runs``. Returns the files written.

    Raises:
        FileNotFoundError: no finished run under ``out/runs``.
    """
    out = Path(out)
    records = load_records(out)
    missing = unfinished_runs(out)
    if not records and not missing:
        raise FileNotFoundError(
            f"no finished runs ({RUNS_DIR}/<method>/seed<S>/{RunDir.RESULTS}) under {out}"
        )
    if stream is None:
        plan = out / PLAN_FILE
        stream = json.loads(plan.read_text()).get("stream", "") if plan.exists() else ""
    rows, notes = aggregate(records)
    written = []
    for name, text in (
        ("table.md", table_markdown(rows, notes, stream) + unfinished_markdown(missing)),
        ("table.csv", table_csv(rows)),
        ("runtime.csv", runtime_csv(records)),
    ):
        atomic_write_text(out / name, text)
        written.append(out / name)
    decisions = decisions_markdown(records, stream)
    if decisions:
        (out / "decisions.md").write_text(decisions)
        written.append(out / "decisions.md")
    if plot_perf_vs_memory(rows, out / "perf_vs_memory.png", stream):
        written.append(out / "perf_vs_memory.png")
    return written


EMBED_BEGIN = "<!-- report: "  # <!-- report: docs/results/pointmaze-1/table.md -->
EMBED_END = "<!-- end report -->"


def embed_reports(doc: Path, root: Path = Path(".")) -> str:
    """``doc``'s text with every embedded report rebuilt: a block opened by
    ``<!-- report: DIR/NAME -->`` and closed by ``<!-- end report -->`` gets the file ``NAME``
    that :func:`write_report` builds from the runs under ``DIR`` (relative to ``root``), without
    its title line. Keeps a documentation page equal to what its committed run files give."""
    import tempfile

    lines, out, i = Path(doc).read_text().splitlines(), [], 0
    while i < len(lines):
        line = lines[i]
        out.append(line)
        i += 1
        if not line.startswith(EMBED_BEGIN):
            continue
        target = Path(root) / line[len(EMBED_BEGIN) :].removesuffix("-->").strip()
        with tempfile.TemporaryDirectory() as tmp:
            # a copy, so the committed report files are left as they are
            for name in RunDir.EXPORTED:
                for src in target.parent.glob(f"*/seed*/{name}"):
                    dst = Path(tmp) / src.relative_to(target.parent)
                    dst.parent.mkdir(parents=True, exist_ok=True)
                    dst.write_bytes(src.read_bytes())
            stream = (target.parent / PLAN_FILE).exists() and json.loads(
                (target.parent / PLAN_FILE).read_text()
            ).get("stream")
            write_report(Path(tmp), stream or target.parent.name)
            text = (Path(tmp) / target.name).read_text().splitlines()
        out += [x for x in text[1:] if x or out[-1]]  # without the title, no doubled blank
        while i < len(lines) and lines[i] != EMBED_END:
            i += 1
        if i == len(lines):
            raise ValueError(f"{doc}: {line} has no closing {EMBED_END}")
    return "\n".join(out) + "\n"


# --- running ----------------------------------------------------------------------------------


def _tail(path: Path, lines: int = TAIL_LINES) -> str:
    if not Path(path).exists():
        return ""
    return "\n".join(Path(path).read_text(errors="replace").splitlines()[-lines:])


def execute_run(
    argv: Sequence[str],
    log_path: str,
    results_path: str,
    env: dict[str, str] | None = None,
    on_start: Callable[[subprocess.Popen], None] | None = None,
) -> dict:
    """Run ``python <argv>`` with this interpreter, stdout and stderr appended to
    ``log_path``; return ``returncode``, ``results`` (the ``results.json`` dict, None on
    failure), ``log_tail`` and ``seconds``. The Ray launcher runs this on its workers."""
    log = Path(log_path)
    log.parent.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, *argv]
    start = time.perf_counter()
    with log.open("a") as f:
        f.write(f"=== {time.strftime('%Y-%m-%d %H:%M:%S')} {shlex.join(command)}\n")
        f.flush()
        proc = subprocess.Popen(
            command, stdout=f, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})}
        )
        if on_start is not None:
            on_start(proc)
        returncode = proc.wait()
    results = None
    if returncode == 0 and Path(results_path).exists():
        results = json.loads(Path(results_path).read_text())
    return {
        "returncode": returncode,
        "results": results,
        "log_tail": "" if results is not None else _tail(log),
        "seconds": time.perf_counter() - start,
    }


def run_env(num_threads: int) -> dict[str, str]:
    """Environment for each run: unbuffered output (the log tail is current) and OpenMP
    threads matching ``--num-threads``; the Minari store path travels to Ray workers."""
    env = {"PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": str(num_threads)}
    if "MINARI_DATASETS_PATH" in os.environ:
        env["MINARI_DATASETS_PATH"] = os.environ["MINARI_DATASETS_PATH"]
    return env


class Reporter:
    """A tqdm bar over runs (skipped ones count as done) and a printed line per finished or
    failed run; a failure shows its log path and the tail of the log."""

    def __init__(self, total: int, done: int = 0) -> None:
        from tqdm.auto import tqdm

        self._write = tqdm.write
        self.bar = tqdm(total=total, initial=done, desc="benchmark", unit="run")
        self.failed: list[PlannedRun] = []

    def __call__(self, run: PlannedRun, outcome: dict) -> None:
        results = outcome["results"]
        if results is not None:
            minutes = sum(results.get("wall_time_s", [])) / 60
            self._write(
                f"[benchmark] {run.method} seed {run.seed}: PER {100 * results['PER']:.1f}  "
                f"{minutes:.1f} min"
            )
        else:
            self.failed.append(run)
            why = f"exit {outcome['returncode']}" + (
                f", no {RunDir.RESULTS}" if outcome["returncode"] == 0 else ""
            )
            record_status(run, f"failed ({why}); log: {run.log_path}")
            tail = "\n".join("    " + line for line in outcome["log_tail"].splitlines())
            self._write(
                f"[benchmark] FAILED {run.method} seed {run.seed} ({why}); log: {run.log_path}\n"
                f"{tail}"
            )
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()


def record_status(run: PlannedRun, status: str) -> None:
    """Note a run's outcome in its ``run.json`` (the tables list failed runs with it)."""
    run_dir = RunDir(run.run_dir)
    try:
        meta = run_dir.read_run_record()
        meta["status"] = status
        run_dir.write_run_record(meta)
    except (OSError, ValueError):  # the record is a convenience; the log says the rest
        pass


def run_local(
    runs: Sequence[PlannedRun],
    workers: int,
    report: Callable[[PlannedRun, dict], None],
    env: dict[str, str] | None = None,
) -> None:
    """Each run as a subprocess, ``workers`` at a time; on Ctrl-C the live runs are
    terminated (a rerun resumes them)."""
    live: set[subprocess.Popen] = set()
    lock = threading.Lock()

    def start(proc: subprocess.Popen) -> None:
        with lock:
            live.add(proc)

    def job(run: PlannedRun) -> dict:
        return execute_run(run.argv, str(run.log_path), str(run.results_path), env, start)

    pool = ThreadPoolExecutor(max_workers=max(1, workers))
    try:
        futures = {pool.submit(job, run): run for run in runs}
        for future in as_completed(futures):
            run = futures[future]
            try:
                outcome = future.result()
            except Exception as e:  # the launch itself failed (e.g. the log is unwritable)
                outcome = {"returncode": -1, "results": None, "log_tail": repr(e)}
            report(run, outcome)
    except KeyboardInterrupt:
        with lock:
            for proc in live:
                proc.terminate()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def run_ray(
    runs: Sequence[PlannedRun],
    num_threads: int,
    report: Callable[[PlannedRun, dict], None],
    address: str | None = None,
    local_cpus: int | None = None,
    env: dict[str, str] | None = None,
) -> None:
    """Each run as a Ray remote task of ``num_threads`` CPUs (Ray schedules them) running the
    same ``fit`` subprocess on a worker. ``address``: ``local`` starts a private instance of
    ``local_cpus`` CPUs, ``auto`` / ``ray://host:10001`` joins a cluster, None lets Ray decide
    (``RAY_ADDRESS``, else local). Workers need the repository, the package and the data at
    the same paths as here (a shared filesystem). A run's ``results.json`` comes back with
    the task and is written here too if the worker's file is not visible.
    """
    try:
        import ray
    except ImportError:
        raise SystemExit(
            "the ray launcher needs Ray: pip install 'hispo-pl[ray]' (or 'ray>=2.9')"
        ) from None
    started = not ray.is_initialized()
    if started:
        options: dict = {"log_to_driver": False}
        if address == "local":
            options.update(include_dashboard=False, num_cpus=local_cpus)
        ray.init(address=address, **options)
    task = ray.remote(num_cpus=num_threads)(execute_run)
    pending = {
        task.remote(list(run.argv), str(run.log_path), str(run.results_path), env): run
        for run in runs
    }
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            run = pending.pop(done[0])
            try:
                outcome = ray.get(done[0])
            except Exception as e:  # the task or its worker died
                outcome = {"returncode": -1, "results": None, "log_tail": f"{e}"}
            if outcome["results"] is not None and not run.results_path.exists():
                run.run_dir.mkdir(parents=True, exist_ok=True)
                RunDir(run.run_dir).write_results(outcome["results"])
            report(run, outcome)
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    finally:
        if started:
            ray.shutdown()


# --- the command ------------------------------------------------------------------------------


def _cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hispo-pl benchmark",
        usage="hispo-pl benchmark --stream STREAM --out OUT [options] [-- fit overrides...]",
        description=(
            "Run every (method, seed) of a stream as a `hispo-pl fit` subprocess logging to\n"
            "OUT/runs/<method>/seed<S>/ (resumable: runs with a results.json are skipped,\n"
            "interrupted ones resume), then write OUT/table.md and table.csv (PER, BWT, FWT\n"
            "x100 and MEM, mean ± std over seeds), runtime.csv and perf_vs_memory.png.\n"
            "Arguments after `--` are passed to every `hispo-pl fit`."
        ),
        epilog=(
            "examples:\n"
            "  hispo-pl benchmark --stream pointmaze-1 --methods all --seeds 3 "
            "--out results/pointmaze-1\n"
            "  hispo-pl benchmark --stream pointmaze-2 --methods hispo,scn --seeds 0,4 "
            "--out results/pm2 -- --data.batch_size 512\n"
            "  hispo-pl benchmark --stream pointmaze-1 --methods all --seeds 3 --out "
            "results/pointmaze-1 --launcher ray --address auto\n"
            "  hispo-pl benchmark --out results/pointmaze-1 --report-only"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--stream", help="stream name (CONFIG_DIR/streams/<name>.yaml) or a YAML path"
    )
    parser.add_argument(
        "--methods",
        default="all",
        help="'all' (every CONFIG_DIR/methods/*.yaml, sorted) or a comma list (default: all)",
    )
    parser.add_argument(
        "--seeds",
        default="3",
        help="a count N (seeds 0..N-1) or a comma list such as 0,4 (default: 3)",
    )
    parser.add_argument("--out", help="output folder (runs/, tables, figure)")
    parser.add_argument(
        "--steps-per-task",
        type=int,
        default=None,
        help="gradient steps per task (--trainer.max_steps); default: the stream config's own "
        "value (6000 in configs/streams/pointmaze-*.yaml; the paper's is 100000)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        help="local: runs at a time (default: CPU cores // threads, at least 1); ray with "
        "--address local: the private instance gets workers x threads CPUs",
    )
    parser.add_argument(
        "--num-threads",
        type=int,
        default=1,
        help="torch threads (and Ray CPUs) per run (default: 1)",
    )
    parser.add_argument(
        "--launcher",
        choices=("local", "ray"),
        default="local",
        help="local: parallel processes on this machine (default); ray: one Ray remote task "
        "per run",
    )
    parser.add_argument(
        "--address",
        default=None,
        help="ray: 'local' (a private instance), 'auto' (the running cluster) or "
        "ray://host:10001; default: RAY_ADDRESS, else a local instance",
    )
    parser.add_argument(
        "--config-dir",
        default="configs",
        help="where streams/ and methods/ live (default: configs)",
    )
    parser.add_argument(
        "--dry-run", action="store_true", help="print the planned fit commands; run nothing"
    )
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="only rebuild the tables and figure in OUT from the finished runs",
    )
    parser.add_argument(
        "--docs",
        metavar="PAGE",
        default=None,
        help="with --report-only: rebuild every report embedded in a documentation page "
        "(e.g. docs/results.md) from its committed run files",
    )
    parser.add_argument(
        "--export",
        metavar="DEST",
        default=None,
        help="copy every finished run's small files (results, decisions, config) to "
        "DEST/<method>/seed<S>/ and write the report there (e.g. docs/results/pointmaze-1)",
    )
    return parser


def _split_extra(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    argv = list(argv)
    if "--" in argv:
        i = argv.index("--")
        return argv[:i], argv[i + 1 :]
    return argv, []


def _print_report(out: Path, stream: str | None) -> None:
    for path in write_report(out, stream):
        print(f"[benchmark] wrote {path}")


def pending_runs(runs: Sequence[PlannedRun], stream: str) -> list[PlannedRun]:
    """The runs without a ``results.json`` (new or interrupted), each with a fresh
    ``run.json`` (method, seed, budget, command); prints a line for each skipped or resumed
    run, noting when its command changed since the first launch."""
    todo = []
    for run in runs:
        run_dir = RunDir(run.run_dir)
        old = run_dir.read_run_record() if run_dir.run_record_file.exists() else None
        changed = old is not None and old.get("argv") != list(run.argv)
        if run_dir.has_results():
            note = " (it was launched with another command)" if changed else ""
            print(f"[benchmark] {run.name}: skipped, {RunDir.RESULTS} exists{note}")
            continue
        if run_dir.progress_file.exists():
            note = "; note: the command differs from its first launch" if changed else ""
            print(f"[benchmark] {run.name}: resuming an interrupted run{note}")
        run.run_dir.mkdir(parents=True, exist_ok=True)
        meta = {
            "method": run.method,
            "seed": run.seed,
            "stream": stream,
            "steps_per_task": run.steps_per_task,
            "argv": list(run.argv),
            "command": shlex.join(run.command(sys.executable)),
        }
        run_dir.write_run_record(meta)
        todo.append(run)
    return todo


def main(argv: Sequence[str] | None = None) -> int:
    own, extra = _split_extra(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(own)
    if args.report_only and args.docs:
        Path(args.docs).write_text(embed_reports(Path(args.docs)))
        print(f"[benchmark] rebuilt the reports embedded in {args.docs}")
        return 0
    if not args.out:
        parser.error("--out is required (unless --report-only --docs PAGE)")
    out = Path(args.out)
    if args.report_only:
        try:
            if args.export:
                copied = export_runs(out, Path(args.export))
                print(f"[benchmark] exported {len(copied)} files to {args.export}")
                out = Path(args.export)
            _print_report(out, args.stream)
        except FileNotFoundError as e:
            parser.error(str(e))
        return 0
    if not args.stream:
        parser.error("--stream is required (unless --report-only)")
    if args.num_threads < 1 or (args.workers is not None and args.workers < 1):
        parser.error("--num-threads and --workers must be >= 1")
    if args.address is not None and args.launcher != "ray":
        parser.error("--address is for --launcher ray")
    config_dir = Path(args.config_dir)
    if not (config_dir / "methods").is_dir():
        parser.error(
            f"no {config_dir / 'methods'}: run from the repository root or pass --config-dir"
        )
    try:
        stream_config = stream_config_path(args.stream, config_dir)
        methods = select_methods(args.methods, known_methods(config_dir))
        seeds = parse_seeds(args.seeds)
    except (ValueError, FileNotFoundError) as e:
        parser.error(str(e))
    workers = args.workers or max(1, _cpu_count() // args.num_threads)
    runs = plan_runs(
        stream_config,
        config_dir,
        methods,
        seeds,
        out,
        args.num_threads,
        args.steps_per_task,
        extra,
    )
    if args.dry_run:
        from .cli import check_fit_args

        problems = 0
        checked: dict[str, str | None] = {}
        for run in runs:
            state = "done" if run.results_path.exists() else "to run"
            print(f"[benchmark] {run.name} ({state}): {shlex.join(run.command(sys.executable))}")
            if run.method not in checked:  # seeds differ only in the seed and run dir
                checked[run.method] = check_fit_args(list(run.argv[len(FIT_MODULE) :]))
            if checked[run.method] is not None:
                problems += 1
                print(f"[benchmark] {run.name}: invalid: {checked[run.method]}", file=sys.stderr)
        return 2 if problems else 0
    out.mkdir(parents=True, exist_ok=True)
    stream_name = stream_config.stem
    plan = {
        "stream": stream_name,
        "stream_config": str(stream_config),
        "methods": methods,
        "seeds": seeds,
        "steps_per_task": args.steps_per_task,
        "extra": extra,
    }
    atomic_write_text(out / PLAN_FILE, json.dumps(plan, indent=1))

    todo = pending_runs(runs, stream_name)
    print(
        f"[benchmark] {len(runs)} runs ({len(methods)} methods x {len(seeds)} seeds), "
        f"{len(todo)} to run with the {args.launcher} launcher, {args.num_threads} thread(s) "
        "each" + (f", {workers} at a time" if args.launcher == "local" else "")
    )
    needed: dict[str, int] = {}
    for run in todo:
        for name, episodes in datasets_needed(run.configs, run.argv).items():
            needed[name] = max(needed.get(name, 0), episodes)
    prepare_datasets(needed)
    reporter = Reporter(total=len(runs), done=len(runs) - len(todo))
    env = run_env(args.num_threads)
    try:
        if todo and args.launcher == "local":
            run_local(todo, workers, reporter, env)
        elif todo:
            run_ray(
                todo,
                args.num_threads,
                reporter,
                args.address,
                workers * args.num_threads if args.workers else None,
                env,
            )
    except KeyboardInterrupt:
        reporter.close()
        print("[benchmark] interrupted: rerun the same command to resume")
        return 130
    reporter.close()
    try:
        if args.export:
            copied = export_runs(out, Path(args.export))
            print(f"[benchmark] exported {len(copied)} files to {args.export}")
            _print_report(Path(args.export), stream_name)
        _print_report(out, stream_name)
    except FileNotFoundError as e:
        print(f"[benchmark] no tables: {e}")
    if reporter.failed:
        print(
            f"[benchmark] {len(reporter.failed)} run(s) failed: "
            + ", ".join(f"{r.name} ({r.log_path})" for r in reporter.failed)
        )
        return 1
    return 0
