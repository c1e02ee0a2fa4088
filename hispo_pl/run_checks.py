"""A run's configuration before anything trains: the method knobs written into the callbacks
that take them, the checks that refuse values which would train nothing or wrongly, and the
fingerprint that keeps a resumed stream on the settings it started with."""

from __future__ import annotations

import json

from .decisions import tolerance_problem
from .errors import ConfigError


def apply_method_knobs(config) -> None:
    """Write each knob flag given (``--eps_low 0.2``) into the init_args of the configured
    callbacks that take it (:class:`~hispo_pl.methods.Knob`), then clear the flag, so the
    saved config and the run's fingerprint hold the effective values whichever way they
    were set.

    Raises:
        ConfigError: a knob that no callback of the configured method takes.
    """
    from .methods import all_knobs, config_callbacks

    callbacks = config_callbacks(config)
    for flag, knob in all_knobs().items():
        value = config.get(flag)
        if value is None:
            continue
        hit = False
        for cls, callback in callbacks:
            for target, param in knob.targets.items():
                if cls is not None and issubclass(cls, target):
                    callback["init_args"][param] = value
                    hit = True
        if not hit:
            names = [cls.__name__ for cls, _ in callbacks if cls is not None]
            raise ConfigError(
                f"--{flag}: no callback of this method takes it (its callbacks: "
                f"{', '.join(names) or 'none'}); it applies to "
                f"{', '.join(t.__name__ for t in knob.targets)}"
            )
        config[flag] = None


def _config_problems(node, path: str = "", key: str = "", parent: str = "") -> list[str]:
    """Out-of-range values anywhere in a parsed configuration, by key name (model and callback
    ``init_args`` included): each problem as ``key = value: what is allowed``."""
    problems: list[str] = []
    if isinstance(node, dict):
        for name, value in node.items():
            where = f"{path}.{name}" if path else str(name)
            problems += _config_problems(value, where, str(name), key)
        return problems
    if isinstance(node, list):
        for i, value in enumerate(node):
            problems += _config_problems(value, f"{path}[{i}]", key, parent)
        return problems
    if isinstance(node, bool) or not isinstance(node, int | float):
        return problems
    rules = {
        "batch_size": (lambda v: v >= 1, "must be >= 1"),
        "steps_per_epoch": (lambda v: v >= 1, "must be >= 1"),
        "episodes": (lambda v: v >= 1, "must be >= 1"),
        "n_candidates": (lambda v: v >= 1, "must be >= 1"),
        "n_batches": (lambda v: v >= 1, "must be >= 1"),
        "eval_every": (lambda v: v >= 0, "must be >= 0 (0: only at the end)"),
        "dropout": (lambda v: 0 <= v < 1, "must be in [0, 1)"),
        "holdout": (lambda v: 0 <= v < 1, "must be in [0, 1) (a share of episodes)"),
        "convergence_window": (lambda v: 0 <= v < 1, "must be in [0, 1) (a share of steps)"),
        "lr": (lambda v: v > 0 and v == v, "must be > 0"),
    }
    if key in rules:
        ok, allowed = rules[key]
    elif key.startswith("eps") or parent == "eps":  # tolerances: ε of every rule and test
        ok, allowed = (lambda v: tolerance_problem(v) is None), tolerance_problem(-1)
    else:
        return problems
    if not ok(node):
        problems.append(f"{path} = {node}: {allowed}")
    return problems


def callback_order_problem(config: dict) -> str | None:
    """Why a configuration's callbacks are in an order that would measure the wrong policy, or
    None: callbacks run their hooks in list order, so a task-end callback (one a method
    declares, :attr:`~hispo_pl.methods.MethodSpec.task_end`) listed after
    ``RolloutEvaluation`` would change the policy after the success row was measured."""
    from .callbacks import RolloutEvaluation
    from .methods import config_callbacks, config_spec, task_end_callbacks

    classes = [cls for cls, _ in config_callbacks(config) if cls is not None]
    evaluation = [i for i, cls in enumerate(classes) if issubclass(cls, RolloutEvaluation)]
    if not evaluation:
        return None
    spec = config_spec(config)
    task_end = (*task_end_callbacks(), *(spec.task_end if spec is not None else ()))
    late = [c.__name__ for c in classes[evaluation[0] + 1 :] if issubclass(c, task_end)]
    if not late:
        return None
    return (
        f"trainer.callbacks: {', '.join(late)} after RolloutEvaluation would act after each "
        "task's evaluation; callbacks run in list order, so list RolloutEvaluation last"
    )


def lightning_optimizer_problem(config: dict) -> str | None:
    """Lightning's ``--optimizer`` / ``--lr_scheduler`` would replace the method's Adam and
    schedule (``optim:``), and a divergence would then be blamed on ``optim.lr``."""
    given = [k for k in ("optimizer", "lr_scheduler") if config.get(k) is not None]
    if not given:
        return None
    return (
        f"{' and '.join(f'--{k}' for k in given)}: hispo-pl methods build their optimiser "
        "from optim: (Adam); set --model.init_args.optim.lr and "
        "--model.init_args.optim.schedule instead"
    )


def stream_checkpoint_problem(config: dict) -> str | None:
    """A checkpoint callback in a stream: every task's Trainer runs without one, since the
    stream saves its own checkpoints (atomically, where a rerun resumes from them)."""
    if not (config.get("data") or {}).get("stream"):
        return None
    from lightning.pytorch.callbacks import Checkpoint

    from .methods import config_callbacks

    for cls, _ in config_callbacks(config):
        if cls is not None and issubclass(cls, Checkpoint):
            return (
                f"trainer.callbacks: {cls.__name__} has no effect in a stream, which "
                "saves task_XX.ckpt after each task and task_XX.partial.ckpt every "
                "--checkpoint_every steps in its run directory; remove it"
            )
    return None


def validate_config(config: dict) -> None:
    """Refuse, before any data is made or any step trained, values that would train nothing
    or train wrongly (batch 0, no steps, dropout 1, a negative tolerance...), and options that
    a stream would silently ignore.

    Raises:
        ConfigError: one message listing every problem; one line for an option that
        hispo-pl would bypass or ignore (Lightning's optimiser flags, a stream's checkpoint
        callback).
    """
    for problem in (lightning_optimizer_problem(config), stream_checkpoint_problem(config)):
        if problem is not None:
            raise ConfigError(problem)
    problems = _config_problems({k: v for k, v in config.items() if k != "config"})
    trainer = config.get("trainer") or {}
    max_steps, max_epochs = trainer.get("max_steps"), trainer.get("max_epochs")
    by_epochs = max_steps == -1 and max_epochs is not None and max_epochs > 0
    if max_steps is not None and max_steps < 1 and not by_epochs:
        problems.append(f"trainer.max_steps = {max_steps}: must be >= 1 (gradient steps per task)")
    if (config.get("checkpoint_every") or 0) < 0:
        problems.append(f"checkpoint_every = {config['checkpoint_every']}: must be >= 0 (0: off)")
    if (config.get("data") or {}).get("stream") and config.get("ckpt_path"):
        problems.append(
            f"ckpt_path = {config['ckpt_path']}: a stream resumes by itself; rerun the same "
            "command without --ckpt_path (its run directory holds the finished tasks)"
        )
    order = callback_order_problem(config)
    if order is not None:
        problems.append(order)
    if problems:
        raise ConfigError("invalid configuration:\n  " + "\n  ".join(problems))


# settings that change neither what a run trains nor what it measures: a rerun may change them
NOT_IN_FINGERPRINT = (
    "config",
    "num_threads",
    "ckpt_path",
    "scratch_results",  # FWT's reference, applied when the results are written
    "checkpoint_every",
    "trainer.logger",
    "trainer.enable_progress_bar",
    "trainer.enable_model_summary",
    "trainer.log_every_n_steps",
    "trainer.default_root_dir",
    "trainer.enable_checkpointing",
    "trainer.profiler",
)


def plain_config(config: dict) -> dict:
    """A parsed configuration as JSON values (paths and other objects as strings)."""
    return json.loads(json.dumps(config, default=str))


def class_label(class_path: str) -> str:
    """The last part of a class path: how a fingerprint's keys name a callback
    (``trainer.callbacks[SubspacePruning]``), the format of every stored fingerprint; it
    names, it never finds a class."""
    return str(class_path).rpartition(".")[2]


def callback_labels(class_paths: list[str]) -> list[str]:
    """How the fingerprint names each callback of a list: its class name, with ``#2``, ``#3``...
    for a later instance of the same class, so moving a callback in the list keeps its name.

    Example:
        >>> callback_labels(["a.RolloutEvaluation", "a.SubspacePruning", "a.RolloutEvaluation"])
        ['RolloutEvaluation', 'SubspacePruning', 'RolloutEvaluation#2']
    """
    seen: dict[str, int] = {}
    labels = []
    for path in class_paths:
        name = class_label(path)
        seen[name] = seen.get(name, 0) + 1
        labels.append(name if seen[name] == 1 else f"{name}#{seen[name]}")
    return labels


def run_fingerprint(config: dict) -> dict:
    """Every setting that defines a stream run, flat (``model.init_args.optim.lr: 0.001``,
    ``trainer.callbacks[SubspacePruning].init_args.eps_high: 0.1``), without
    :data:`NOT_IN_FINGERPRINT`. Callbacks are named by class (:func:`callback_labels`), not by
    position: the orders that change what a run does are refused by the callbacks' ``setup``
    and :func:`callback_order_problem`, so a list that passes them trains the same in any
    order."""
    flat: dict = {}

    def walk(node, path: str) -> None:
        if any(path == k or path.startswith(k + ".") for k in NOT_IN_FINGERPRINT):
            return
        callbacks = path == "trainer.callbacks" and isinstance(node, list) and node
        if callbacks and all(isinstance(c, dict) for c in node):
            labels = callback_labels([c.get("class_path", "") for c in node])
            for label, callback in zip(labels, node, strict=True):
                walk(callback, f"{path}[{label}]")
            return
        if isinstance(node, dict):
            for key, value in node.items():
                walk(value, f"{path}.{key}" if path else str(key))
        elif isinstance(node, list) and any(isinstance(v, dict | list) for v in node):
            for i, value in enumerate(node):
                walk(value, f"{path}[{i}]")
        else:
            flat[path] = node

    walk(plain_config(config), "")
    return flat
