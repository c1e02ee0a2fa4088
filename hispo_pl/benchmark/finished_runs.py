"""Finished runs as found on disk, and their aggregation: FWT against the from-scratch run
of the same seed, mean ± std over seeds per method."""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import RunDirError
from ..io import copy_files, make_folder, real_folder, refuse_linked
from ..metrics import METRICS, continual_metrics, mean_std
from ..results import Decision, LaunchRecord, StreamResults, fwt_reference
from ..rundir import RunDir
from .configs import configured_value, episodes_here
from .plan import PLAN_FILE, RUNS_DIR, PlannedRun, planned_stream, warn_provenance


@dataclass
class RunRecord:
    """A finished run as found on disk: its ``results.json``, its decision records and, if the
    benchmark launched it, its ``run.json``."""

    method: str
    seed: int
    results: StreamResults
    meta: LaunchRecord = field(default_factory=LaunchRecord)
    decisions: list[Decision] = field(default_factory=list)
    derived_from: str | None = None
    """The method whose run of the same stream and seed this run was derived from instead of
    trained (:mod:`.derive`; :func:`derived_source` of its ``run.json``), None if it trained."""


def derived_source(method: str, meta: LaunchRecord) -> str | None:
    """The method whose run ``method``'s run was derived from (``run.json``'s
    ``derived_from``: ``<stream>/<label>/seed<S>`` or a run directory); None for a run that
    trained: one without ``derived_from``, or a seed copied from its own method's sweep
    (``<method>-<sweep><value>``: that sweep run trained, this is the same run).

    Example:
        >>> derived_source("ft1", LaunchRecord(derived_from="videogame-1/ftn/seed0"))
        'ftn'
        >>> source = LaunchRecord(derived_from="pointmaze-1/l2-lambda0.01/seed0")
        >>> derived_source("l2", source) is None
        True
    """
    source = meta.derived_from
    if not source:
        return None
    parts = Path(str(source)).parts
    label = parts[-2] if len(parts) > 1 else parts[-1]
    return None if label == method or label.startswith(f"{method}-") else label


def finished_run_dirs(out: Path, results: str = RunDir.RESULTS) -> list[Path]:
    """Run folders with a ``results.json`` (``results``: the file that marks a finished run,
    ``RunDir.RESULT`` for single-task fits): ``OUT/runs/<method>/seed<S>`` (where the
    benchmark runs them) or ``OUT/<method>/seed<S>`` (an exported copy, ``--export``)."""
    out = Path(out)
    found = list(out.glob(f"{RUNS_DIR}/*/seed*/{results}"))
    found += [p for p in out.glob(f"*/seed*/{results}") if p.parts[-3] != RUNS_DIR]
    return sorted(p.parent for p in found)


def load_records(out: Path) -> tuple[list[RunRecord], list[str]]:
    """Every finished run under ``out`` (:func:`finished_run_dirs`), sorted by method then
    seed, and a line for each whose files cannot be read (kept out of the tables).

    Raises:
        RunDirError: the readable runs are of more than one stream."""
    records, unreadable = [], []
    for seed_dir in finished_run_dirs(out):
        try:
            seed = int(seed_dir.name.removeprefix("seed"))
        except ValueError:
            continue
        run = RunDir(seed_dir)
        try:
            meta, results = run.read_run_record(), run.stream_results()
        except RunDirError as err:
            unreadable.append(f"{seed_dir.parent.name}/{seed_dir.name}: {err}")
            continue
        method = seed_dir.parent.name
        derived = derived_source(method, meta)
        records.append(RunRecord(method, seed, results, meta, run.decisions(), derived))
    streams = {tuple(r.results.stream): r for r in records}
    if len(streams) > 1:
        (a, first), (b, second) = list(streams.items())[:2]
        raise RunDirError(
            f"{out} holds runs of different streams: {first.method}/seed{first.seed} "
            f"({' -> '.join(a)}) and {second.method}/seed{second.seed} ({' -> '.join(b)}); "
            "a table compares runs of one stream, so keep each stream under its own folder"
        )
    return sorted(records, key=lambda r: (r.method, r.seed)), unreadable


def _stream_of(run: RunDir) -> tuple[str | None, tuple[str, ...] | None]:
    """A finished run's stream: the name its ``run.json`` records and the tasks of its
    ``results.json``, each None where the file does not say."""
    try:
        name = run.read_run_record().stream
    except RunDirError:
        name = None
    try:
        tasks = tuple(run.stream_results().stream)
    except RunDirError:
        tasks = None
    return name, tasks


def foreign_exports(out: Path, dest: Path) -> list[str]:
    """What exporting ``out`` to ``dest`` would overwrite of another stream, described for a
    message: ``dest``'s runs of the same method and seed whose stream differs (by name or
    tasks), and its ``benchmark.json`` when it names another stream than ``out``'s."""
    found = []
    for seed_dir in finished_run_dirs(out):
        there = RunDir(Path(dest) / seed_dir.parent.name / seed_dir.name)
        if not there.has_results():
            continue
        ours, theirs = _stream_of(RunDir(seed_dir)), _stream_of(there)
        pairs = zip(ours, theirs, strict=True)
        if any(a is not None and b is not None and a != b for a, b in pairs):
            name, tasks = theirs
            found.append(f"{seed_dir.parent.name}/{seed_dir.name} ({name or ' -> '.join(tasks)})")
    new, old = planned_stream(out), planned_stream(dest)
    if new is not None and old is not None and new != old:
        found.append(f"{PLAN_FILE} ({old})")
    return found


def refuse_foreign_export(found: Sequence[str], dest: Path) -> None:
    """Refuse an export that would overwrite ``found`` (:func:`foreign_exports`).

    Raises:
        RunDirError: naming them and what to do."""
    if found:
        raise RunDirError(
            f"{dest} holds runs of another stream: {', '.join(found)}. Exported runs are named "
            "by method and seed, so give this stream its own --export"
        )


def export_runs(out: Path, dest: Path) -> list[Path]:
    """Copy the small files of every finished run under ``out`` (results, decisions, config,
    run record; never checkpoints or event files) to ``dest/<method>/seed<S>/``, the layout
    that is kept (committed, shared) and read back by ``--report-only``.
    A link among them is refused before anything is copied; a link in ``dest`` is replaced.

    Raises:
        LinkedFileError: a file to copy is a symbolic link.
        RunDirError: ``dest`` holds runs of another stream (:func:`foreign_exports`); nothing
            is copied."""
    out, dest = Path(out), Path(dest)
    refuse_foreign_export(foreign_exports(out, dest), dest)
    pairs = []
    if os.path.lexists(out / PLAN_FILE):  # the report's title
        pairs.append((out / PLAN_FILE, dest / PLAN_FILE))
    runs = {d: dest / d.parent.name / d.name for d in finished_run_dirs(out)}
    for seed_dir, target in runs.items():
        for name in RunDir.EXPORTED:
            if os.path.lexists(seed_dir / name):
                pairs.append((seed_dir / name, target / name))
    refuse_linked(src for src, _ in pairs)
    make_folder(dest)
    for target in runs.values():
        real_folder(target, dest)
    written = copy_files(pairs)
    for seed_dir, target in runs.items():
        if RunDir(target).run_record_file.exists():
            warn_provenance(RunDir(target).read_run_record(), f"exporting {seed_dir}")
    return written


DatasetRead = tuple[str, int]
"""A dataset as a run read it: its Minari id and how many of its episodes."""


def episodes_read(records: Sequence[RunRecord]) -> dict[DatasetRead, dict[str, set[str]]]:
    """Which episodes each run read: for every dataset (and episode count) the runs read, the
    digests their ``results.json`` records (``datasets[i].digest``), each with the runs (``hispo
    seed 0``) that read those episodes. Runs that recorded no digest are left out."""
    found: dict[DatasetRead, dict[str, set[str]]] = {}
    for r in records:
        for used in r.results.datasets or ():
            if not isinstance(used, dict) or not used.get("digest") or not used.get("dataset"):
                continue
            by_digest = found.setdefault((used["dataset"], int(used.get("episodes") or 0)), {})
            by_digest.setdefault(used["digest"], set()).add(f"{r.method} seed {r.seed}")
    return found


def _who(by_digest: dict[str, set[str]]) -> str:
    """``a52c for cspo seed 0, hispo seed 0; 6c4b for scn seed 0``."""
    ordered = sorted(by_digest.items(), key=lambda kv: sorted(kv[1]))
    return "; ".join(f"{digest} for {', '.join(sorted(names))}" for digest, names in ordered)


def other_episodes(records: Sequence[RunRecord]) -> list[str]:
    """Where runs of one stream read the same dataset but recorded other episodes: for each
    dataset whose digests differ between runs (:func:`episodes_read`), a line naming the runs
    behind each digest. A dataset made again on another machine can hold other episodes, and a
    table comparing such runs compares methods on different data.

    Example:
        >>> def run(method, digest):
        ...     used = [{"dataset": "hispo/antmaze-large-expert-v0", "episodes": 500} | digest]
        ...     results = StreamResults(stream=["antmaze-large-PO"], R=[[1.0]], datasets=used)
        ...     return RunRecord(method, 0, results)
        >>> other_episodes([run("hispo", {"digest": "a52c"}), run("scn", {"digest": "6c4b"})])
        ['hispo/antmaze-large-expert-v0 (500 episodes): a52c for hispo seed 0; 6c4b for scn seed 0']
        >>> other_episodes([run("hispo", {"digest": "a52c"}), run("scn", {})])
        []
    """
    return [
        f"{dataset} ({episodes} episodes): {_who(by_digest)}"
        for (dataset, episodes), by_digest in sorted(episodes_read(records).items())
        if len(by_digest) > 1
    ]


def unlike_here(records: Sequence[RunRecord], here: dict[DatasetRead, str]) -> list[str]:
    """The datasets that hold other episodes on this machine (``here``: each dataset's digest,
    as a run would record it) than ``records`` read: a line for each, naming both digests and
    the runs that read the other one. Runs trained now would train on other data than them.

    Example:
        >>> used = [{"dataset": "hispo/antmaze-large-expert-v0", "episodes": 500, "digest": "a52c"}]
        >>> hispo = RunRecord("hispo", 0, StreamResults(stream=["a"], R=[[1.0]], datasets=used))
        >>> unlike_here([hispo], {("hispo/antmaze-large-expert-v0", 500): "6c4b"})
        ['hispo/antmaze-large-expert-v0 (500 episodes) holds 6c4b here; read a52c for hispo seed 0']
        >>> unlike_here([hispo], {("hispo/antmaze-large-expert-v0", 500): "a52c"})
        []
    """
    read = episodes_read(records)
    lines = []
    for (dataset, episodes), digest in sorted(here.items()):
        others = {d: names for d, names in read.get((dataset, episodes), {}).items() if d != digest}
        if others:
            held = f"{dataset} ({episodes} episodes) holds {digest} here"
            lines.append(f"{held}; read {_who(others)}")
    return lines


def warn_of_other_episodes(name: str, runs: Sequence[PlannedRun], kept: Sequence[Path]) -> None:
    """Say before the runs start where this machine's datasets hold other episodes than the
    finished runs of the stream under ``kept`` read (a dataset made again elsewhere can differ,
    docs/data.md): ``runs``, the stream's runs about to train, would train on other data than
    those they are compared with."""
    stream = configured_value(runs[0].configs, runs[0].argv, "data.stream") if runs else None
    records = []
    for folder in kept:
        try:
            records += load_records(Path(folder))[0] if Path(folder).is_dir() else []
        except RunDirError:  # another stream's runs: not what these runs are compared with
            continue
    if not stream or not episodes_read(records):
        return
    for line in unlike_here(records, episodes_here(stream)):
        print(
            f"[benchmark] {name}: {line}. The runs starting now train on other episodes than "
            "those, and the stream's table will list them apart (docs/data.md, \"Reproducing "
            'a dataset")'
        )


def scratch_method_for(method: str, available: Iterable[str]) -> str | None:
    """The from-scratch run whose R diagonal is ``method``'s FWT reference: ``scn``, else
    ``sc1``; for flat-BC methods (``bc-*``) ``bc-scn``, else ``bc-sc1``; None if none ran."""
    prefix = "bc-" if method.startswith("bc-") else ""
    available = set(available)
    for candidate in (f"{prefix}scn", f"{prefix}sc1"):
        if candidate in available:
            return candidate
    return None


def run_metrics(results: StreamResults, scratch_results: StreamResults | None = None) -> dict:
    """Every metric of :data:`~hispo_pl.metrics.METRICS` of a run: those of R by
    :func:`~hispo_pl.metrics.continual_metrics` (FWT against ``scratch_results``'s diagonal,
    :func:`~hispo_pl.results.fwt_reference`), those measured on the model as the run recorded
    them; and its anchors. Fractions, not ×100."""
    out: dict = continual_metrics(results.matrix, fwt_reference(scratch_results, len(results.R)))
    for metric in METRICS:
        if metric.of_model and results.metrics.get(metric.name) is not None:
            out[metric.name] = float(results.metrics[metric.name])
    if results.anchors:
        out["anchors"] = {k: float(v) for k, v in results.anchors.items()}
    return out


def format_mean_std(mean: float, std: float, scale: float = 100.0, digits: int = 1) -> str:
    """``81.0 ± 1.2``: mean ± std × ``scale`` (×100 for success fractions, as the paper)."""
    return f"{scale * mean:.{digits}f} ± {scale * std:.{digits}f}"


@dataclass
class MethodRow:
    """One method's line of the table: each metric of :data:`~hispo_pl.metrics.METRICS` that
    every seed has, as (mean, std) over seeds in fractions (PER, BWT, FWT) or ratios (MEM);
    the anchors per subspace; the run FWT was measured against; the seeds whose run was
    derived from another method's instead of trained (:attr:`RunRecord.derived_from`)."""

    method: str
    seeds: list[int]
    metrics: dict[str, tuple[float, float]] = field(default_factory=dict)
    anchors: dict[str, tuple[float, float]] = field(default_factory=dict)
    fwt_reference: str | None = None
    derived: dict[int, str] = field(default_factory=dict)  # seed -> the method it derives from


def per_run_metrics(records: Sequence[RunRecord]) -> list[tuple[RunRecord, dict, str | None]]:
    """Each run's metrics (:func:`run_metrics`), FWT against the from-scratch run of the same
    seed (:func:`scratch_method_for`) where there is one, and the name of that reference."""
    by_seed: dict[int, dict[str, RunRecord]] = {}
    for r in records:
        by_seed.setdefault(r.seed, {})[r.method] = r
    found = []
    for r in records:
        ref = scratch_method_for(r.method, by_seed[r.seed])
        scratch = by_seed[r.seed][ref].results if ref else None
        found.append((r, run_metrics(r.results, scratch), ref))
    return found


def aggregate(
    records: Sequence[RunRecord], measured: Sequence[tuple[RunRecord, dict, str | None]] = ()
) -> tuple[list[MethodRow], list[str]]:
    """One row per method (sorted) and footnotes; ``measured``: :func:`per_run_metrics` of
    ``records``, when the caller has it already.

    FWT of a method uses, for each seed, the R diagonal of the from-scratch run of the same
    seed (:func:`scratch_method_for`); it is left empty, with a footnote, unless every seed of
    the method has one.
    """
    measured = measured or per_run_metrics(records)
    rows, notes = [], []
    for method in sorted({r.method for r in records}):
        mine = [(r, m, ref) for r, m, ref in measured if r.method == method]
        metrics = [m for _, m, _ in mine]
        row = MethodRow(method, [r.seed for r, _, _ in mine])
        row.derived = {r.seed: r.derived_from for r, _, _ in mine if r.derived_from}
        for metric in METRICS:
            if all(metric.name in m for m in metrics):
                row.metrics[metric.name] = mean_std([m[metric.name] for m in metrics])
        missing = [r.seed for r, m, _ in mine if "FWT" not in m]
        if missing:
            prefix = "bc-" if method.startswith("bc-") else ""
            seeds = ", ".join(str(s) for s in missing)
            notes.append(
                f"{method}: no FWT, no {prefix}scn or {prefix}sc1 run (with the same stream) "
                f"for seed {seeds}"
            )
        else:
            row.fwt_reference = ", ".join(sorted({ref for _, _, ref in mine}))
        names = sorted({k for m in metrics for k in m.get("anchors", {})})
        for name in names:
            if all(name in m.get("anchors", {}) for m in metrics):
                row.anchors[name] = mean_std([m["anchors"][name] for m in metrics])
        rows.append(row)
    return rows, notes
