"""Whether a grid's committed runs were trained as the grid would train them today.

A grid counts a cell done when its committed run trained the stream's tasks at the grid's
budget (:func:`~hispo_pl.benchmark.grid_plan.committed_reader`); it does not compare every
setting, so a run committed before a default changed would be completed with seeds trained
under the new one. This check compares them all: each done cell's saved ``config.yaml`` and the
command the grid plans for it today are both parsed by today's ``hispo-pl fit`` (its defaults
filled in, the preset and the knob flags applied, the classes made, nothing trained) and
compared setting by setting (:func:`~hispo_pl.run_checks.run_fingerprint`). A setting the
configuration leaves to the task family (``anchor_init: null``, a pruning or PAC ε left unset) is
read as the family's value on both sides::

    python -m lab config-drift --grid paper --part antmaze
"""

from __future__ import annotations

import contextlib
import io
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

ANCHOR_INIT = "model.init_args.anchor_init"
PRUNING = "trainer.callbacks[SubspacePruning].init_args."
TRANSFER = "trainer.callbacks[ZeroShotTransfer].init_args."
FIT_SUBCOMMAND_KEYS = ("ckpt_path", "weights_only")
# the packages a saved configuration's classes may come from; any other is refused unimported
CLASS_PACKAGES = ("hispo_pl", "lightning")


def foreign_classes(config) -> list[str]:
    """The ``class_path`` values of a parsed configuration outside :data:`CLASS_PACKAGES`:
    a run file that names them is not parsed, so reading it imports nothing it names."""
    found = []
    if isinstance(config, dict):
        path = config.get("class_path")
        if isinstance(path, str) and path.split(".")[0] not in CLASS_PACKAGES:
            found.append(path)
        for value in config.values():
            found += foreign_classes(value)
    elif isinstance(config, list):
        for value in config:
            found += foreign_classes(value)
    return found


def family_resolved(settings: Mapping, family) -> dict:
    """``settings`` (a run's fingerprint) with the values left to ``family`` written in: what
    each policy reads (``family``), how a new anchor starts, and the pruning ε of each of the
    family's subspaces that neither its own flag nor the ``eps`` mapping sets (as the
    datamodule and :class:`~hispo_pl.callbacks.anchors.SubspacePruning` read the family)."""
    out = dict(settings)
    for key, value in (("data.low_inputs", family.low_inputs),
                       ("data.high_inputs", family.high_inputs)):  # fmt: skip
        if out.get(key) == "family":
            out[key] = value
    if ANCHOR_INIT in out and out[ANCHOR_INIT] is None:
        out[ANCHOR_INIT] = family.anchor_init
    for name, eps in family.pruning_eps.items():
        key, named = f"{PRUNING}eps_{name}", f"{PRUNING}eps.{name}"
        if key in out and out[key] is None and out.get(named) is None:
            out[key] = eps
    for name, eps in family.pac_eps.items():
        key = f"{TRANSFER}eps_{name}"
        if key in out and out[key] is None:
            out[key] = eps
    return out


def setting_drift(committed: Mapping, planned: Mapping) -> dict[str, tuple]:
    """Every setting whose value differs, as key -> (committed, planned); a setting one side
    lacks reads as ``"<absent>"``."""
    absent = "<absent>"
    keys = sorted(set(committed) | set(planned))
    return {
        k: (committed.get(k, absent), planned.get(k, absent))
        for k in keys
        if committed.get(k, absent) != planned.get(k, absent)
    }


def effective_settings(args: Sequence[str]) -> dict:
    """The fingerprint of the run ``hispo-pl fit ARGS`` would train today, its family's
    defaults written in. The logger is pointed at a scratch folder (it is no setting of the
    run), so nothing is written beside a committed run.

    Raises:
        UserError: the arguments are refused today (a setting since removed, a bad value)."""
    import torch

    from hispo_pl.console import lightning_notices_once, quiet_lightning_notices
    from hispo_pl.errors import ConfigError
    from hispo_pl.fit import run_lightning_cli
    from hispo_pl.run_checks import run_fingerprint
    from hispo_pl.tasks import parse_stream

    threads = torch.get_num_threads()
    with tempfile.TemporaryDirectory() as scratch:
        argv = [*args, "--trainer.logger.init_args.save_dir", scratch]
        try:
            with (
                contextlib.redirect_stdout(io.StringIO()),
                contextlib.redirect_stderr(io.StringIO()),
                lightning_notices_once(),  # its seed and accelerator lines are not a run's
            ):
                quiet_lightning_notices()
                cli = run_lightning_cli(argv, run=False)
        except SystemExit as exit:
            raise ConfigError(f"today's hispo-pl fit refuses it (exit {exit.code})") from None
        finally:
            torch.set_num_threads(threads)
    config = cli.config.as_dict()
    stream = (config.get("data") or {}).get("stream")
    settings = run_fingerprint(config)
    if not stream:
        return settings
    return family_resolved(settings, parse_stream(stream)[0].env_family)


@contextlib.contextmanager
def parseable_copy(saved: Path) -> Iterator[tuple[Path, str | None]]:
    """A run's saved ``config.yaml`` as a file that ``hispo-pl fit``'s parser takes without the
    subcommand: checked as ``hispo-pl fit`` checks a config file, refused unparsed when it
    names a class outside hispo-pl and Lightning (so reading it imports nothing it names),
    without the ``fit`` subcommand's keys (no settings of the run) and without its preset. A
    run saves its configuration with its preset and knob flags already written in, so the
    preset is not applied again (its overlay would undo a flag that won over it); its name is
    yielded beside the copy, which lives while the context does.

    Raises:
        UserError: the file names a foreign class, or is refused as a config file."""
    import yaml

    from hispo_pl.config_files import check_config_files
    from hispo_pl.errors import ConfigError

    check_config_files(["--config", str(saved)])
    config = yaml.safe_load(Path(saved).read_text())
    foreign = foreign_classes(config)
    if foreign:
        raise ConfigError(
            f"names classes outside {' and '.join(CLASS_PACKAGES)} ({', '.join(foreign)}); "
            "not imported"
        )
    for key in FIT_SUBCOMMAND_KEYS:
        config.pop(key, None)
    preset = config.pop("preset", None)
    with tempfile.TemporaryDirectory() as scratch:
        copy = Path(scratch) / "config.yaml"
        copy.write_text(yaml.safe_dump(config, sort_keys=False))
        yield copy, preset


def saved_settings(saved: Path) -> dict:
    """:func:`effective_settings` of a run's saved ``config.yaml`` (:func:`parseable_copy`),
    with its preset's name.

    Raises:
        UserError: as :func:`parseable_copy`."""
    with parseable_copy(saved) as (copy, preset):
        return {**effective_settings(["--config", str(copy)]), "preset": preset}


def grid_drift(
    grid_name: str, part: str | None, root: Path
) -> Iterator[tuple[str, dict[str, tuple] | str]]:
    """Per done cell of the grid's ``part`` (its run committed under ``root``): its name and the
    settings that differ between its saved configuration and the grid's command for it today,
    or why its configuration could not be read."""
    from hispo_pl.benchmark.grid import grid_streams, load_grid
    from hispo_pl.benchmark.grid_plan import cell_run, committed_reader, plan_cells
    from hispo_pl.config_files import config_root
    from hispo_pl.errors import UserError
    from hispo_pl.rundir import RunDir

    config_dir = config_root()
    grid = load_grid(grid_name, config_dir)
    plan = plan_cells(grid, grid_streams(grid, part), committed_reader(grid, config_dir, root))
    with tempfile.TemporaryDirectory() as work:
        for cell in plan.done:
            saved = RunDir(cell.result_dir(root)).config_file
            planned = cell_run(cell, grid, config_dir, Path(work))
            try:
                committed = saved_settings(saved)
                today = effective_settings(list(planned.argv[planned.argv.index("fit") + 1 :]))
            except UserError as err:
                yield cell.name, f"{saved}: {err}"
                continue
            yield cell.name, setting_drift(committed, today)


def report_drift(grid_name: str, part: str | None, root: Path) -> int:
    """Print one line per done cell (the same, or what differs); returns how many differ or
    could not be read."""
    differing = 0
    for name, drift in grid_drift(grid_name, part, root):
        if isinstance(drift, str):
            print(f"[lab] {name}: cannot compare: {drift}")
        elif drift:
            said = "; ".join(f"{k}: committed {a!r}, today {b!r}" for k, (a, b) in drift.items())
            print(f"[lab] {name}: differs: {said}")
        else:
            print(f"[lab] {name}: the same configuration")
        differing += bool(drift)
    return differing
