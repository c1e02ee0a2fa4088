"""What ``hispo-pl`` says when a command line does not parse: one line naming the problem and
the closest flag, instead of the parser's usage dump. Pure functions over the parser's message
and the flags it knows, and :class:`VerbParser`, the argparse parser of every verb but ``fit``
(LightningCLI's, whose errors :mod:`hispo_pl.fit` turns into the same line)."""

from __future__ import annotations

import argparse
import difflib
import re
from collections.abc import Iterable, Mapping

from .errors import ConfigError

HELP = "hispo-pl fit --help lists the flags"
_UNRECOGNIZED = re.compile(r"unrecognized arguments: (--[^\s=]+)")
_PARSER_KEY = re.compile(r'Parser key "([^"]+)"')
_NOT_SUBCLASS = re.compile(r"Import path (\S+) does not correspond to a subclass of (\w+)")
_NO_MODULE = re.compile(r"class_path '([^']+)':\s+No module named '([^']+)'")
_NESTED = re.compile(r"unrecognized arguments: --([^\s=]+)|Option '([^']+)' is not accepted")


def closest_flag(flag: str, known: Iterable[str]) -> str | None:
    """The known flag nearest to ``flag``: the one it abbreviates, if only one, else the
    closest by difflib's ratio (at least 0.6), or None."""
    known = sorted(set(known))
    started = [k for k in known if k.startswith(flag)]
    if len(started) == 1:
        return started[0]
    matches = difflib.get_close_matches(flag, known, n=1, cutoff=0.6)
    return matches[0] if matches else None


def unknown_flag(message: str) -> str | None:
    """The flag a parser message says it does not know, as the user would write it
    (``--trainer.max_stepz``; ``--model.init_args.optim.lrr`` for a class's argument), or
    None when the message is about something else."""
    top = _UNRECOGNIZED.match(message)
    if top:
        return top.group(1)
    key, nested = _PARSER_KEY.match(message), _NESTED.search(message)
    if key and nested and "class_path" in message:
        name = nested.group(1) or nested.group(2)
        return f"--{key.group(1)}.init_args.{name}"
    return None


def parse_error_line(message: str, known: Iterable[str], help_hint: str = HELP) -> str:
    """One line for a parser error: an unknown flag with the closest ``known`` one, or the
    parser's own message with its lines joined."""
    flag = unknown_flag(message)
    wrong_class = _NOT_SUBCLASS.search(message)
    if flag is None and wrong_class and wrong_class.group(2) == "GoalConditionedBC":
        return (
            f"{wrong_class.group(1)} is not a hispo-pl method: a method subclasses "
            "hispo_pl.modules.GoalConditionedBC (docs/extending.md, What to subclass)"
        )
    no_module = _NO_MODULE.search(message)
    if flag is None and no_module:
        return (
            f"{no_module.group(1)}: no module {no_module.group(2)} on the import path; hispo-pl "
            "imports a method from an installed package or PYTHONPATH, never from the working "
            "folder by itself (docs/extending.md)"
        )
    if flag is None:
        return " ".join(line.strip() for line in message.splitlines() if line.strip())
    match = closest_flag(flag, known)
    guess = f"; did you mean {match}?" if match else ""
    return f"unknown flag {flag}{guess} ({help_hint})"


def class_problem_line(message: str, config: Mapping | None = None) -> str | None:
    """One line for a class of the configuration that could not be made (its package is not
    installed, an import in it fails), from jsonargparse's message: the flag that names it,
    the class and the reason (``--trainer.logger lightning.pytorch.loggers.MLFlowLogger
    cannot be made: Requirement 'mlflow>=1.0.0' not met. HINT: ...``); None for another
    message."""
    lines = message.splitlines()
    for i, line in enumerate(lines):
        found = re.search(r"Problem with given class_path '([^']+)':", line)
        if found is None:
            continue
        depth = len(line) - len(line.lstrip())
        reason = []
        for more in lines[i + 1 :]:
            if more.strip() and len(more) - len(more.lstrip()) <= depth:
                break
            reason.append(more.strip())
        class_path = found.group(1)
        where = class_key(config, class_path) if config is not None else None
        said = " ".join(part for part in reason if part) or "it cannot be imported"
        return f"{f'--{where} ' if where else ''}{class_path} cannot be made: {said}"
    return None


def class_key(config: Mapping, class_path: str, prefix: str = "") -> str | None:
    """The dotted key of ``config`` whose value (or one item of whose list) names
    ``class_path``: ``trainer.logger``, ``trainer.callbacks``; None if none does."""
    for key, value in config.items():
        name = f"{prefix}.{key}" if prefix else str(key)
        items = value if isinstance(value, list) else [value]
        if any(isinstance(v, Mapping) and v.get("class_path") == class_path for v in items):
            return name
        if isinstance(value, Mapping):
            found = class_key(value, class_path, name)
            if found is not None:
                return found
    return None


class VerbParser(argparse.ArgumentParser):
    """An argparse parser that takes no abbreviation (``--epi`` is not ``--episodes``) and
    answers a command line it cannot parse with one line (:func:`parse_error_line`: the
    closest flag of the verb and its sub-verbs, and where the help is), raised as a
    :class:`~hispo_pl.errors.ConfigError` for ``hispo-pl`` to print."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def known_flags(self) -> list[str]:
        """Every option string of this parser and of its sub-verbs' parsers."""
        flags = [f for f in self._option_string_actions if f.startswith("--") and f != "--help"]
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                for parser in action.choices.values():
                    flags += parser.known_flags()
        return flags

    def parse_args(self, args=None, namespace=None):
        """Unknown flags are named first, before argparse's complaint about a missing one
        (which a mistyped flag often causes)."""
        if args is not None:
            known = set(self.known_flags()) | {"-h", "--help"}
            for arg in args:
                if arg == "--":
                    break
                flag = arg.split("=", 1)[0]
                if flag.startswith("--") and flag not in known:
                    self.error(f"unrecognized arguments: {flag}")
        return super().parse_args(args, namespace)

    def error(self, message: str):
        line = parse_error_line(message, self.known_flags(), f"{self.prog} --help lists them")
        if unknown_flag(message) is None:
            line += f" ({self.prog} --help)"
        raise ConfigError(line)


def dotted_flags(config: Mapping, prefix: str = "") -> list[str]:
    """Every key of a parsed configuration as the flag that sets it (``--trainer.max_steps``,
    ``--model.init_args.optim.lr``; a list of classes, the callbacks, as
    ``--trainer.callbacks.init_args.episodes``)."""
    flags = []
    for key, value in config.items():
        name = f"{prefix}.{key}" if prefix else str(key)
        flags.append(f"--{name}")
        if isinstance(value, Mapping):
            flags += dotted_flags(value, name)
        elif isinstance(value, list):
            for item in value:
                if isinstance(item, Mapping) and isinstance(item.get("init_args"), Mapping):
                    flags += dotted_flags(item["init_args"], f"{name}.init_args")
    return flags


def without_flag(args: list[str], flag: str) -> list[str]:
    """``args`` less ``flag`` and its value (``--a.b 5`` or ``--a.b=5``; for a class's
    argument also the short form without ``init_args``)."""
    forms = {flag, flag.replace(".init_args.", ".")}
    out, skip = [], False
    for i, arg in enumerate(args):
        if skip:
            skip = False
            continue
        if arg in forms:
            nxt = args[i + 1] if i + 1 < len(args) else None
            skip = nxt is not None and not nxt.startswith("--")
            continue
        if any(arg.startswith(f + "=") for f in forms):
            continue
        out.append(arg)
    return out
