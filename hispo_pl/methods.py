"""What each method says about itself: its display name, the callbacks that act at a task's
end, the knobs it takes on the command line and what the paper's preset changes for it.

One :class:`MethodSpec` per method class, registered here beside the classes (a method sits
below its callbacks, so the entry that names both lives one floor up). The command line, the
presets, the run checks, the HParams tab and the reports read a run's method through
:func:`config_spec`, which looks the configured class up among the imported ones (never by
its name) and walks its bases, so a subclass of a shipped method is that method unless it
registers its own entry::

    register(MethodSpec(MyMethod, "MyMethod", task_end=(MyCallback,)))
"""

from __future__ import annotations

import copy
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from lightning.pytorch import Callback

from .callbacks import (
    AnchorExtension,
    CriticEvaluation,
    CriticPruning,
    DirichletEvaluation,
    RolloutEvaluation,
    SubspacePruning,
    TaskNetworks,
    WeightConsolidation,
    ZeroShotTransfer,
)
from .modules.columns import NetworkPerTask
from .modules.csp import CSP
from .modules.cspo import CSPO
from .modules.hbc import BC, HBC, GoalConditionedBC, imported_method
from .modules.hilow import HiLOW
from .modules.hispo import HiSPO
from .modules.pnn import PNN
from .modules.regularized import RegularizedFineTuning


@dataclass(frozen=True)
class Knob:
    """A callback argument a run sets with a flag of its own (``--eps_low 0.2``) instead of
    a copy of the method config: the flag, its help, its type, and the argument of each
    callback class it is written into (and checked there, as if the config had said it)."""

    flag: str
    help: str
    kind: type[int] | type[float] | type[bool]
    targets: Mapping[type[Callback], str]


EPS_HIGH = Knob(
    "eps_high",
    "tolerance ε of the high subspace's pruning rule (SubspacePruning)",
    float,
    {SubspacePruning: "eps_high"},
)
EPS_LOW = Knob(
    "eps_low",
    "tolerance ε of the low subspace's pruning rule (SubspacePruning)",
    float,
    {SubspacePruning: "eps_low"},
)
EPS = Knob(
    "eps",
    "tolerance ε of CSP's critic rule (CriticPruning)",
    float,
    {CriticPruning: "eps"},
)
SEARCH = (
    Knob(
        "search_candidates",
        "Dirichlet candidates per subspace search (DirichletEvaluation, CriticEvaluation)",
        int,
        {DirichletEvaluation: "n_candidates", CriticEvaluation: "n_candidates"},
    ),
    Knob(
        "search_batches",
        "held-out batches each candidate is scored on (DirichletEvaluation, CriticEvaluation)",
        int,
        {DirichletEvaluation: "n_batches", CriticEvaluation: "n_batches"},
    ),
)
STORED_POINTS = Knob(
    "search_stored_points",
    "also race the weights earlier tasks act with, so a repeated task finds its own point; "
    "not the paper's search (DirichletEvaluation)",
    bool,
    {DirichletEvaluation: "stored_points"},
)
EVALUATION = (
    Knob(
        "eval_episodes",
        "rollout episodes per task evaluation (RolloutEvaluation)",
        int,
        {RolloutEvaluation: "episodes"},
    ),
    Knob(
        "eval_every",
        "also evaluate the current task every N steps, 0: only at its end (RolloutEvaluation)",
        int,
        {RolloutEvaluation: "eval_every"},
    ),
)


@dataclass(frozen=True)
class PaperOverlay:
    """What ``--preset paper`` sets for one method beyond what it sets for every method
    (:mod:`hispo_pl.presets`)."""

    settings: Mapping[str, Any] = field(default_factory=dict)  # dotted key -> value
    widths: Mapping[str, tuple[int, int]] = field(default_factory=dict)  # family -> (high, low)
    callbacks: Mapping[type[Callback], Mapping[str, Any]] = field(default_factory=dict)


@dataclass(frozen=True)
class KeepLast:
    """A method that keeps only its newest network and trains exactly as its keep-all
    sibling, so its run is derived from the sibling's (:mod:`hispo_pl.benchmark.derive`)."""

    sibling: Callable[[Mapping], dict | None]  # a config -> its keep-all twin (None: keeps all)
    from_sibling: Callable[[dict], None]  # a keep-all config, made the keep-last one in place
    checkpoint: Callable[[dict], dict]  # the sibling's checkpoint as the keep-last run's


@dataclass(frozen=True)
class MethodSpec:
    """One method as the rest of hispo-pl sees it.

    Attributes:
        module: the method's class (its subclasses are the method too, unless registered).
        name: its display name, or a function of the run's configuration (plain dict) for a
            class that is several methods by its arguments (NetworkPerTask: SCN, FT1...).
        task_end: the callbacks that change what a task acts with at its end, so they must
            run before ``RolloutEvaluation`` measures it.
        knobs: the flags it takes (:class:`Knob`).
        paper: what the paper's preset sets for it (:class:`PaperOverlay`).
        keep_last: how a keep-last variant of the method follows from its keep-all
            sibling's run (:class:`KeepLast`); None: the method has none.
    """

    module: type[GoalConditionedBC]
    name: str | Callable[[Mapping], str]
    task_end: tuple[type[Callback], ...] = ()
    knobs: tuple[Knob, ...] = EVALUATION
    paper: PaperOverlay = PaperOverlay()
    keep_last: KeepLast | None = None

    def display_name(self, config: Mapping) -> str:
        """The method's name for a run of ``config`` (a plain ``fit`` configuration)."""
        return self.name if isinstance(self.name, str) else self.name(config)


_SPECS: dict[type, MethodSpec] = {}


def register(spec: MethodSpec) -> MethodSpec:
    """Make ``spec`` what hispo-pl reads for its class (and the subclasses that register none)."""
    _SPECS[spec.module] = spec
    return spec


def method_spec(cls: type) -> MethodSpec:
    """The registered entry of ``cls`` or of its nearest registered base."""
    for base in cls.__mro__:
        if base in _SPECS:
            return _SPECS[base]
    raise KeyError(f"{cls.__qualname__} is not a hispo-pl method")


def registered() -> tuple[MethodSpec, ...]:
    """Every registered method."""
    return tuple(_SPECS.values())


def all_knobs() -> dict[str, Knob]:
    """Every registered method's knobs, by flag: the flags ``hispo-pl fit`` takes."""
    return {knob.flag: knob for spec in registered() for knob in spec.knobs}


def imported_class(class_path: Any) -> type | None:
    """The class a configuration names, if its module is imported (nothing is imported)."""
    module, _, name = str(class_path).rpartition(".")
    found = getattr(sys.modules.get(module), name, None) if module else None
    return found if isinstance(found, type) else None


def config_spec(config) -> MethodSpec | None:
    """The entry of the method a ``fit`` configuration (a plain dict or the parser's
    namespace) names; None when its model is not an imported hispo-pl method."""
    path = (config.get("model") or {}).get("class_path")
    cls = imported_method(str(path)) if path else None
    return method_spec(cls) if cls is not None else None


def config_callbacks(config) -> list[tuple[type | None, Any]]:
    """A configuration's callbacks as (class, the entry itself), in list order."""
    callbacks = (config.get("trainer") or {}).get("callbacks") or []
    if not isinstance(callbacks, list):
        callbacks = [callbacks]
    return [(imported_class(c.get("class_path")), c) for c in callbacks if not isinstance(c, str)]


def has_callback(config: Mapping, kind: type) -> bool:
    """Whether a configuration lists a callback of class ``kind`` (or a subclass)."""
    return any(cls is not None and issubclass(cls, kind) for cls, _ in config_callbacks(config))


def method_name(config: Mapping) -> str | None:
    """The display name of a configuration's method (None: not a hispo-pl method)."""
    spec = config_spec(config)
    return spec.display_name(config) if spec is not None else None


def shipped_method_name(method: str) -> str:
    """The display name of a shipped method config (``scn`` -> ``SCN``, ``hispo-pac`` ->
    ``HiSPO-PAC``), as its registry entry gives it."""
    import yaml

    from .config_files import config_path

    config = yaml.safe_load(config_path(f"methods/{method}").read_text()) or {}
    return method_name(config) or method


def task_end_callbacks() -> tuple[type[Callback], ...]:
    """Every registered method's task-end callbacks."""
    return tuple(dict.fromkeys(cb for spec in registered() for cb in spec.task_end))


# --- the shipped methods --------------------------------------------------------------------


def _init_args(config: Mapping) -> Mapping:
    return (config.get("model") or {}).get("init_args") or {}


def _flat(config: Mapping, name: str) -> str:
    """``name`` of a method on the flat BC backbone as the BC-vs-HBC table names it."""
    kind = (_init_args(config).get("backbone") or {}).get("kind")
    return f"BC-{name}" if kind == "bc" else name


def _network_per_task_name(config: Mapping) -> str:
    args = _init_args(config)
    trains = [c.get("init_args") or {} for cls, c in config_callbacks(config) if cls is not None]
    trains = [a.get("train") for a in trains if "train" in a]
    if (config.get("data") or {}).get("replay"):
        name = "RPL"
    elif "first" in trains:
        name = "FRZ"
    else:
        start = "SC" if args.get("init", "fresh") == "fresh" else "FT"
        name = start + ("N" if args.get("keep", "all") == "all" else "1")
    return _flat(config, name)


def _network_per_task_keep(config: dict, keep: str) -> None:
    config["model"].setdefault("init_args", {})["keep"] = keep


def _network_per_task_keep_all(config: Mapping) -> dict | None:
    if _init_args(config).get("keep", "all") != "last":
        return None
    twin = copy.deepcopy(dict(config))
    _network_per_task_keep(twin, "all")
    return twin


NETWORK_PER_TASK_KEEP_LAST = KeepLast(
    _network_per_task_keep_all,
    lambda config: _network_per_task_keep(config, "last"),
    NetworkPerTask.keep_last_checkpoint,
)


def method_class_name(config: Mapping) -> str:
    """The configured class's own name: the display name of a method that registers none."""
    cls = imported_method(str(((config.get("model") or {}).get("class_path")) or ""))
    return cls.__name__ if cls is not None else "?"


def _hispo_name(config: Mapping) -> str:
    return "HiSPO-PAC" if has_callback(config, ZeroShotTransfer) else "HiSPO"


SUBSPACE_SEARCH = (AnchorExtension, DirichletEvaluation, SubspacePruning)
# the paper's HiSPO rules: one tolerance of its grid {0.01, 0.05, 0.1, 0.25} for both
# subspaces, and the trained weights as alpha_curr
PAPER_SUBSPACE_CALLBACKS = {
    DirichletEvaluation: {"refine_current": False},
    SubspacePruning: {"eps_high": 0.1, "eps_low": 0.1},
}
SUBSPACE_KNOBS = (EPS_HIGH, EPS_LOW, *SEARCH, STORED_POINTS, *EVALUATION)

register(MethodSpec(GoalConditionedBC, method_class_name))
register(MethodSpec(HBC, "HBC"))
register(MethodSpec(BC, "BC"))
register(
    MethodSpec(
        NetworkPerTask,
        _network_per_task_name,
        task_end=(TaskNetworks,),
        keep_last=NETWORK_PER_TASK_KEEP_LAST,
    )
)
register(
    MethodSpec(
        RegularizedFineTuning,
        lambda config: str(_init_args(config).get("penalty", "l2")).upper(),
        task_end=(TaskNetworks, WeightConsolidation),
    )
)
register(MethodSpec(PNN, lambda config: _flat(config, "PNN"), task_end=(TaskNetworks,)))
register(
    MethodSpec(
        HiSPO,
        _hispo_name,
        task_end=(ZeroShotTransfer, *SUBSPACE_SEARCH),
        knobs=SUBSPACE_KNOBS,
        paper=PaperOverlay(
            # a new anchor at random, the trained weights as alpha_curr; wider networks
            settings={"model.init_args.anchor_init": "random"},
            widths={"antmaze": (70, 300), "amazeville": (70, 300), "simpletown": (70, 300)},
            callbacks=PAPER_SUBSPACE_CALLBACKS,
        ),
    )
)
register(
    MethodSpec(
        HiLOW,
        "HiLOW",
        task_end=SUBSPACE_SEARCH,
        knobs=SUBSPACE_KNOBS,
        paper=PaperOverlay(callbacks=PAPER_SUBSPACE_CALLBACKS),
    )
)
register(
    MethodSpec(
        CSPO,
        "CSPO",
        task_end=SUBSPACE_SEARCH,
        knobs=SUBSPACE_KNOBS,
        paper=PaperOverlay(callbacks=PAPER_SUBSPACE_CALLBACKS),
    )
)
register(
    MethodSpec(
        CSP,
        "CSP",
        task_end=(AnchorExtension, CriticEvaluation, CriticPruning),
        knobs=(EPS, *SEARCH, *EVALUATION),
    )
)
