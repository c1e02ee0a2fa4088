"""A benchmark grid: every (stream, method, seed) of a named set, planned against what is
already committed, run two lanes at a time and exported as each run finishes, so a grid of
many hours is finished over several sessions by rerunning one command.

    hispo-pl benchmark --grid paper --out results/grid --export docs/results [--part pointmaze]

A grid is a YAML file (``configs/grids/<name>.yaml``): its streams (and named parts of them),
methods, seeds, the budget, and sweeps. A swept method (L2's and EWC's λ) first runs every value
on one seed; its seeds then run at the value with the best PER, and the sweep's own run of that
value stands for the seed it ran, since the two commands differ only in where they log.
Here: the grid's definition; :mod:`.grid_plan` plans it, pure (:func:`~.grid_plan.plan_cells`
reads results through a function); :mod:`.grid_run` runs and exports.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ConfigError
from .branch import BRANCHING_KEYS
from .plan import stream_config_path

GRIDS_DIR = "grids"
GRID_FILE = "grid.json"  # the grid's definition, beside its reports
SWEEPS_DIR = "sweeps"  # <root>/<stream>/sweeps/<label>/seed<S>: kept out of the stream's table


@dataclass(frozen=True)
class Sweep:
    """Values of one setting of a method, each run on ``seed``; the best PER is kept.

    ``key`` is a dotted fit flag (``model.init_args.penalty_lambda``) or several set to the
    same value (``eps_high,eps_low``: one ε for both subspaces). A ``branch`` sweep is of the
    pruning tolerances or the penalty's λ: its first value trains, and every other value's run
    is branched from a finished one over the tasks they train alike (:mod:`.branch`)."""

    method: str
    key: str
    values: tuple[float, ...]
    name: str = "value"  # in run labels: l2-lambda0.1
    seed: int = 0
    branch: bool = False

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(k.strip() for k in self.key.split(","))

    def label(self, value: float) -> str:
        return f"{self.method}-{self.name}{value:g}"


@dataclass(frozen=True)
class Grid:
    """A grid's definition (``configs/grids/<name>.yaml``)."""

    name: str
    streams: tuple[str, ...]
    methods: tuple[str, ...]
    seeds: tuple[int, ...]
    parts: dict[str, tuple[str, ...]] = field(default_factory=dict)
    sweeps: dict[str, Sweep] = field(default_factory=dict)
    steps_per_task: int | None = None
    extra: tuple[str, ...] = ()  # fit arguments of every run
    # named sets of the streams whose aggregate is reported apart, beside the whole grid's
    aggregates: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "streams": list(self.streams),
            "methods": list(self.methods),
            "seeds": list(self.seeds),
            "parts": {k: list(v) for k, v in self.parts.items()},
            "sweeps": {
                m: {
                    "key": s.key,
                    "values": list(s.values),
                    "name": s.name,
                    "seed": s.seed,
                    **({"branch": True} if s.branch else {}),
                }
                for m, s in self.sweeps.items()
            },
            "steps_per_task": self.steps_per_task,
            "extra": list(self.extra),
            **(
                {"aggregates": {k: list(v) for k, v in self.aggregates.items()}}
                if self.aggregates
                else {}
            ),
        }


def _list(raw: dict, key: str, where: str) -> list:
    value = raw.get(key)
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{where}: `{key}` must be a non-empty list")
    return value


def _mapping(raw: dict, key: str, where: str, holds: str) -> dict:
    """``raw[key]``, a mapping (empty when absent).

    Raises:
        ConfigError: anything else, with what it should hold."""
    value = raw.get(key) or {}
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: `{key}` must be a mapping of {holds}")
    return value


def _number(value, what: str, where: str, kind: type = float):
    """``value`` as ``kind`` (a grid's sweep values, seeds, budget).

    Raises:
        ConfigError: not a number of that kind."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: {what} must be a number, not {value!r}")
    if kind is int and value != int(value):
        raise ConfigError(f"{where}: {what} must be an integer, not {value!r}")
    return kind(value)


def grid_from_dict(raw: dict, name: str, where: str = "grid") -> Grid:
    """A :class:`Grid` from its YAML or JSON mapping.

    Raises:
        ConfigError: a missing or malformed entry, named with what to write instead.
    """
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: a grid is a mapping with streams, methods and seeds")
    unknown = set(raw) - {
        "name", "streams", "methods", "seeds", "parts", "sweeps", "steps_per_task", "extra",
        "aggregates",
    }  # fmt: skip
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    streams = [str(s) for s in _list(raw, "streams", where)]
    methods = [str(m) for m in _list(raw, "methods", where)]
    seeds = raw.get("seeds", 3)
    seeds = list(range(seeds)) if isinstance(seeds, int) else seeds
    if not seeds or not all(isinstance(s, int) and s >= 0 for s in seeds):
        raise ConfigError(f"{where}: `seeds` is a count or a list of non-negative integers")
    parts = _stream_sets(raw, "parts", "part", streams, where)
    aggregates = _stream_sets(raw, "aggregates", "aggregate", streams, where)
    sweeps = {}
    for method, spec in _mapping(raw, "sweeps", where, "methods to their sweep").items():
        if method not in methods:
            raise ConfigError(f"{where}: sweep of {method}, which is not among the methods")
        if not isinstance(spec, dict) or "key" not in spec or not spec.get("values"):
            raise ConfigError(f"{where}: sweep of {method} needs `key` and `values`")
        key, values = spec["key"], spec["values"]
        if not isinstance(values, list):
            raise ConfigError(f"{where}: sweep of {method}: `values` must be a list of numbers")
        what = f"sweep of {method}: a value"
        sweeps[method] = Sweep(
            method,
            ",".join(map(str, key)) if isinstance(key, list) else str(key),
            tuple(_number(v, what, where) for v in values),
            str(spec.get("name", "value")),
            _number(spec.get("seed", seeds[0]), f"sweep of {method}: `seed`", where, int),
            bool(spec.get("branch", False)),
        )
        if sweeps[method].branch and not set(sweeps[method].keys) <= set(BRANCHING_KEYS):
            raise ConfigError(
                f"{where}: sweep of {method}: `branch` needs keys among "
                f"{', '.join(BRANCHING_KEYS)} (settings that leave the first tasks' training alike)"
            )
    steps = raw.get("steps_per_task")
    if steps is not None and _number(steps, "`steps_per_task`", where, int) < 1:
        raise ConfigError(f"{where}: `steps_per_task` must be at least 1")
    extra = raw.get("extra") or []
    if not isinstance(extra, list) or not all(isinstance(a, str) for a in extra):
        raise ConfigError(
            f"{where}: `extra` must be a list of fit arguments as strings, e.g. [--preset, paper]"
        )
    return Grid(
        str(raw.get("name", name)),
        tuple(streams),
        tuple(methods),
        tuple(seeds),
        parts,
        sweeps,
        None if steps is None else int(steps),
        tuple(extra),
        aggregates,
    )


def _stream_sets(raw: dict, key: str, what: str, streams: Sequence[str], where: str) -> dict:
    """``raw[key]``: names to lists of the grid's streams (a part, an aggregate's streams).

    Raises:
        ConfigError: not such a mapping, or a stream the grid does not list."""
    sets = _mapping(raw, key, where, f"{what} names to lists of streams")
    if not all(isinstance(v, list) and v for v in sets.values()):
        raise ConfigError(f"{where}: each {what} of `{key}` is a list of the grid's streams")
    named = {str(k): tuple(str(s) for s in v) for k, v in sets.items()}
    for name, members in named.items():
        if set(members) - set(streams):
            raise ConfigError(f"{where}: {what} {name} names streams the grid does not list")
    return named


def load_grid(spec: str, config_dir: Path) -> Grid:
    """The grid ``config_dir/grids/<spec>.yaml``, or the YAML file ``spec``.

    Raises:
        ConfigError: no such grid (the message lists the known ones), or a malformed one.
    """
    import yaml

    path = Path(spec)
    if path.suffix not in (".yaml", ".yml") or not path.is_file():
        path = Path(config_dir) / GRIDS_DIR / f"{spec}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in (Path(config_dir) / GRIDS_DIR).glob("*.yaml"))
        raise ConfigError(
            f"--grid {spec}: no {path}; known grids: {', '.join(known) or 'none'} (or a YAML path)"
        )
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not YAML ({e.__class__.__name__})") from None
    grid = grid_from_dict(raw, path.stem, str(path))
    check_grid_names(grid, config_dir, str(path))
    return grid


def check_grid_names(grid: Grid, config_dir: Path, where: str) -> None:
    """Refuse a grid that names a method or a stream ``config_dir`` does not have.

    Raises:
        ConfigError: the first unknown name, with the known ones."""
    from .plan import known_methods

    known = known_methods(config_dir)
    unknown = [m for m in grid.methods if m not in known]
    if unknown:
        raise ConfigError(
            f"{where}: unknown method(s) {', '.join(unknown)}; known "
            f"({Path(config_dir) / 'methods'}/*.yaml): {', '.join(known) or 'none'}"
        )
    for stream in grid.streams:
        try:
            stream_config_path(stream, config_dir)
        except (ValueError, FileNotFoundError) as err:
            raise ConfigError(f"{where}: stream {stream}: {err}") from None


def grid_streams(grid: Grid, part: str | None) -> list[str]:
    """The streams of ``part``: a part's name, a stream of the grid, or a comma list of
    either; every stream without one.

    Raises:
        ConfigError: a name that is neither (the message lists both)."""
    if not part:
        return list(grid.streams)
    chosen: list[str] = []
    for name in (p.strip() for p in part.split(",") if p.strip()):
        if name in grid.parts:
            chosen += grid.parts[name]
        elif name in grid.streams:
            chosen.append(name)
        else:
            raise ConfigError(
                f"--part {name}: not a part ({', '.join(grid.parts) or 'none'}) or stream "
                f"({', '.join(grid.streams)}) of grid {grid.name}"
            )
    return list(dict.fromkeys(chosen))
