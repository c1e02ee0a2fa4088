"""``hispo-pl benchmark``: the command line, tying planning, launching and reporting."""

from __future__ import annotations

import json
import shlex
import sys
from collections.abc import Sequence
from contextlib import suppress
from pathlib import Path

from ..config_files import config_root
from ..errors import Interrupted, RunDirError
from ..io import atomic_write_text, make_folder
from . import plan
from .configs import prepare_datasets, runs_datasets
from .finished_runs import export_runs, refuse_foreign_export, warn_of_other_episodes
from .launch import Reporter, run_env, run_local, run_ray
from .parser import build_parser, cpu_count
from .report import write_report


def _split_extra(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    argv = list(argv)
    if "--" in argv:
        i = argv.index("--")
        return argv[:i], argv[i + 1 :]
    return argv, []


def _print_report(out: Path, stream: str | None) -> None:
    for path in write_report(out, stream):
        print(f"[benchmark] wrote {path}")


def selection_line(grid, chosen, seeds: str | None) -> str:
    """What ``--methods`` and ``--seeds`` selected of ``grid``, said before the plan: a bare
    count is the first seeds, which a user meaning one seed would not see otherwise.

    Example:
        >>> from hispo_pl.benchmark.grid import grid_from_dict
        >>> g = grid_from_dict({"streams": ["pointmaze-1"], "methods": ["scn", "hispo"],
        ...                     "seeds": 3}, "g")
        >>> print(selection_line(g, _grid_selection(g, "scn", "2"), "2"))
        [grid] selected: scn; seeds 0, 1 (--seeds 2 is a count; one seed alone is --seeds 2,)
    """
    said = ", ".join(map(str, chosen.seeds))
    if seeds is not None and "," not in seeds:
        said += f" (--seeds {seeds} is a count; one seed alone is --seeds {seeds.strip()},)"
    return f"[grid] selected: {', '.join(chosen.methods)}; seeds {said}"


def _grid_selection(grid, methods: str, seeds: str | None):
    """The part of ``grid`` that ``--methods`` and ``--seeds`` select, for what to run; the
    reports always cover the whole grid.

    Raises:
        ValueError: a method or seed the grid does not have.
    """
    from dataclasses import replace

    if methods.strip() != "all":
        grid = replace(grid, methods=tuple(plan.select_methods(methods, grid.methods)))
    if seeds is not None:
        chosen = plan.parse_seeds(seeds)
        unknown = [s for s in chosen if s not in grid.seeds]
        if unknown:
            have = ", ".join(map(str, grid.seeds))
            raise ValueError(f"--seeds {seeds}: the grid {grid.name} has seeds {have}")
        grid = replace(grid, seeds=tuple(chosen))
    return grid


def _grid_main(parser, args, extra: list[str]) -> int:
    """``--grid``: plan the grid against ROOT (``--export``), run what is left in WORK
    (``--out``), export each run and rebuild the stream's and the grid's reports."""

    from ..errors import ConfigError
    from .grid import grid_streams, load_grid
    from .grid_report import write_grid_report
    from .grid_run import run_grid
    from .report import write_report

    if args.stream:
        parser.error("--grid and --stream: a grid names its own streams (--part selects some)")
    if not args.export:
        parser.error("--grid needs --export ROOT: where its runs are kept (their small files)")
    if not args.report_only and not args.out:
        parser.error("--grid needs --out WORK: where its runs train (checkpoints, logs)")
    config_dir = Path(args.config_dir) if args.config_dir else config_root()
    try:
        grid = load_grid(args.grid, config_dir)
        streams = grid_streams(grid, args.part)
        chosen = _grid_selection(grid, args.methods, args.seeds)
    except (ConfigError, ValueError) as e:
        parser.error(str(e))
    if chosen != grid:
        print(selection_line(grid, chosen, args.seeds))
    if extra or args.steps_per_task is not None:
        parser.error(
            "--grid runs what its file defines, and skips what was committed with it: put fit "
            "arguments and the budget in the grid file (`extra`, `steps_per_task`), as a grid "
            "of its own with its own --export"
        )
    root = Path(args.export)

    def reports(changed: Sequence[str]) -> None:
        for stream in changed:
            with suppress(FileNotFoundError):  # only sweep runs so far: no table yet
                write_report(root / stream, stream)
        try:
            write_grid_report(grid, root)
        except ImportError:
            print("[grid] no aggregate intervals: pip install 'hispo-pl[stats]' (rliable)")

    if args.report_only:
        for stream in streams:
            with suppress(FileNotFoundError):  # nothing committed for it yet
                for path in write_report(root / stream, stream):
                    print(f"[benchmark] wrote {path}")
        for path in write_grid_report(grid, root):
            print(f"[benchmark] wrote {path}")
        return 0
    if not (config_dir / "methods").is_dir():
        parser.error(f"--config-dir {config_dir}: no methods/ folder in it")
    workers = args.workers or max(1, cpu_count() // args.num_threads)
    try:
        failed = run_grid(
            chosen,
            streams,
            config_dir,
            Path(args.out),
            root,
            workers,
            args.num_threads,
            args.dry_run,
            None if args.dry_run else reports,
        )
    except KeyboardInterrupt:
        raise Interrupted(
            "interrupted: finished runs are exported, the stopped ones saved what they "
            "finished; rerun the same command to resume"
        ) from None
    if failed:
        print(f"[grid] {failed} run(s) failed; their logs are under {args.out}")
    return 1 if failed else 0


def main(argv: Sequence[str] | None = None) -> int:
    own, extra = _split_extra(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args = parser.parse_args(own)
    if args.grid:
        return _grid_main(parser, args, extra)
    if not args.out:
        parser.error("--out is required (unless --grid)")
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
    if args.address is not None and args.launcher != "ray":
        parser.error("--address is for --launcher ray")
    config_dir = Path(args.config_dir) if args.config_dir else config_root()
    if not (config_dir / "methods").is_dir():
        parser.error(f"--config-dir {config_dir}: no methods/ folder in it")
    try:
        stream_config = plan.stream_config_path(args.stream, config_dir)
        methods = plan.select_methods(args.methods, plan.known_methods(config_dir))
        seeds = plan.parse_seeds(args.seeds or "3")
    except (ValueError, FileNotFoundError) as e:
        parser.error(str(e))
    workers = args.workers or max(1, cpu_count() // args.num_threads)
    runs = plan.plan_runs(
        stream_config,
        config_dir,
        methods,
        seeds,
        out,
        args.num_threads,
        args.steps_per_task,
        (*plan.stream_fit_args(args.stream), *extra),
    )
    if args.dry_run:
        from ..fit import check_fit_args

        problems = 0
        checked: dict[str, str | None] = {}
        for run in runs:
            state = "done" if run.results_path.exists() else "to run"
            print(f"[benchmark] {run.name} ({state}): {shlex.join(run.command(sys.executable))}")
            if run.method not in checked:  # seeds differ only in the seed and run dir
                checked[run.method] = check_fit_args(list(run.argv[len(plan.FIT_MODULE) :]))
            if checked[run.method] is not None:
                problems += 1
                print(f"[benchmark] {run.name}: invalid: {checked[run.method]}", file=sys.stderr)
        return 2 if problems else 0
    stream_name = plan.stream_name(args.stream, stream_config)
    foreign = plan.foreign_runs(runs, stream_name)
    if foreign:
        raise RunDirError(
            f"{out} holds runs of another stream: {', '.join(foreign)}. Run directories are "
            f"named by method and seed, so give stream {stream_name} its own --out"
        )
    if args.export:  # refused now rather than after training
        dest = Path(args.export)
        refuse_foreign_export(plan.foreign_export(runs, stream_name, dest), dest)
    make_folder(out)
    settings = {
        "stream": stream_name,
        "stream_config": str(stream_config),
        "methods": methods,
        "seeds": seeds,
        "steps_per_task": args.steps_per_task,
        "extra": extra,
    }
    atomic_write_text(out / plan.PLAN_FILE, json.dumps(settings, indent=1))

    todo = plan.pending_runs(runs, stream_name, plan.provenance())
    print(
        f"[benchmark] {len(runs)} runs ({len(methods)} methods x {len(seeds)} seeds), "
        f"{len(todo)} to run with the {args.launcher} launcher, {args.num_threads} thread(s) "
        "each" + (f", {workers} at a time" if args.launcher == "local" else "")
    )
    prepare_datasets(runs_datasets(todo))
    warn_of_other_episodes(stream_name, todo, [out, *([Path(args.export)] if args.export else [])])
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
        raise Interrupted(
            "interrupted: finished runs are kept, the stopped ones saved what they finished; "
            "rerun the same command to resume"
        ) from None
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
