"""Presets: a named set of settings written over a run's configuration before it is built.

``--preset paper`` runs any method as the paper specifies it (its hyperparameter table and
method text), instead of the house defaults the method configs carry; the budget (steps per
task) stays the stream config's. It replaces what config files say; a dotted flag given on the
command line wins over it. ``docs/method.md`` lists both side by side. A preset is
applied before the run's fingerprint is taken, so a resumed run keeps it.
"""

from __future__ import annotations

from collections.abc import Sequence

from .errors import ConfigError
from .methods import PaperOverlay, config_callbacks, config_spec
from .tasks import parse_stream, parse_task

PRESETS = ("paper",)

# the paper's settings for every method: (config key, value); callbacks' by class name below
PAPER_COMMON: tuple[tuple[str, object], ...] = (
    ("model.init_args.optim.lr", 3e-4),
    ("model.init_args.optim.schedule", "cosine"),
    ("model.init_args.backbone.high_log_std", None),  # a learned std: the Gaussian NLL
    ("model.init_args.backbone.low_log_std", None),
    ("model.init_args.backbone.dropout", 0.1),
    ("data.waysteps", None),  # the per-maze waysteps and HER temperatures of its table
    ("data.her_temperature", None),
    ("data.goal_horizon", "episode"),  # goals relabelled up to the episode's end
    ("data.holdout", 0.0),  # no held-out split: decisions scored on the training data
    ("data.low_inputs", "observation"),  # its input sizes: observation, position and goal
    ("data.high_inputs", "observation"),
)
# widths (high, low): 64 / 256 unless the method's overlay says otherwise for a family
# (:attr:`hispo_pl.methods.PaperOverlay.widths`: HiSPO's 70 / 300 on AntMaze and the games)
PAPER_WIDTHS = (64, 256)
PAPER_BATCH = {"pointmaze": 1024, "antmaze": 1024, "amazeville": 64, "simpletown": 64}


def _family(config) -> str:
    data = config.get("data") or {}
    if data.get("stream"):
        return parse_stream(data["stream"])[0].family
    return parse_task(data.get("task") or "pointmaze-umaze").family


def _set(config, key: str, value) -> None:
    """Set a dotted key of a parsed configuration, making the dicts on the way."""
    *parents, last = key.split(".")
    node = config
    for part in parents:
        if node.get(part) is None:
            node[part] = {}
        node = node[part]
    node[last] = value


def given_keys(args: Sequence[str]) -> set[str]:
    """The dotted keys that the flags of a ``fit`` command line set, written without
    ``init_args`` (``--model.optim.lr`` and ``--model.init_args.optim.lr`` are one key);
    configuration files and top-level flags (``--config``, ``--preset``) are not among them.

    Example:
        >>> sorted(given_keys(["--config", "a.yaml", "--data.batch_size", "64",
        ...                    "--model.init_args.optim.lr=0.01", "--preset", "paper"]))
        ['data.batch_size', 'model.optim.lr']
    """
    flags = (a[2:].split("=", 1)[0] for a in args if a.startswith("--"))
    return {_short(flag) for flag in flags if "." in flag}


def _short(key: str) -> str:
    return key.replace(".init_args.", ".")


def _given(key: str, given: set[str]) -> bool:
    """Whether a flag of ``given`` sets ``key`` or a mapping that holds it."""
    short = _short(key)
    return any(short == g or short.startswith(g + ".") for g in given)


def _get(config, key: str):
    node = config
    for part in key.split("."):
        if not hasattr(node, "get") or node.get(part) is None:
            return None
        node = node[part]
    return node


def paper_overlay(config) -> PaperOverlay:
    """What the paper's preset sets for the method ``config`` names, beyond what it sets for
    every method (its :class:`~hispo_pl.methods.MethodSpec`; nothing for an unknown one)."""
    spec = config_spec(config)
    return spec.paper if spec is not None else PaperOverlay()


def preset_settings(config, name: str) -> list[tuple[str, object]]:
    """Preset ``name``'s settings of ``config`` (a parsed ``fit`` configuration) as (dotted
    key, value), its callbacks' apart (:attr:`~hispo_pl.methods.PaperOverlay.callbacks`).

    Raises:
        ConfigError: an unknown preset."""
    if name not in PRESETS:
        raise ConfigError(f"--preset {name}: unknown preset; the presets are {', '.join(PRESETS)}")
    family = _family(config)
    overlay = paper_overlay(config)
    high, low = overlay.widths.get(family, PAPER_WIDTHS)
    return [
        *PAPER_COMMON,
        ("model.init_args.backbone.high_hidden", high),
        ("model.init_args.backbone.low_hidden", low),
        ("data.batch_size", PAPER_BATCH[family]),
        *overlay.settings.items(),
    ]


def apply_preset(config, name: str | None, given: set[str] = frozenset()) -> dict:
    """Write preset ``name``'s settings into ``config`` (a parsed ``fit`` configuration), but
    those of the keys the command line's flags set (``given``, :func:`given_keys`): an
    explicit flag wins over the preset, a configuration file does not. Returns the kept keys
    whose value differs from the preset's, as key -> (value used, the preset's value)."""
    if name is None:
        return {}
    kept = {}
    for key, value in preset_settings(config, name):
        if not _given(key, given):
            _set(config, key, value)
        elif _get(config, key) != value:
            kept[key] = (_get(config, key), value)
    for cls, callback in config_callbacks(config):
        for target, settings in paper_overlay(config).callbacks.items():
            if cls is not None and issubclass(cls, target):
                for key, value in settings.items():
                    callback["init_args"][key] = value
    return kept


def kept_note(name: str, kept: dict) -> str:
    """The line a run prints when flags of its command line win over preset ``name``."""
    said = ", ".join(f"{k} {v} (the preset: {p})" for k, (v, p) in kept.items())
    return f"[hispo-pl] --preset {name}: the command line's flags are kept: {said}"
