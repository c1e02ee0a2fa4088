"""The YAML configs hispo-pl ships (streams, methods, single-task HBC / BC, the demo), found
the same way in a checkout (``./configs``) and in an installed package (``hispo_pl.configs``),
and the ``hispo-pl config`` verb that lists, shows and copies them."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from .cli_errors import VerbParser
from .errors import UserError
from .io import atomic_write_text, make_folder

MAX_CONFIG_NODES = 100_000  # a hand-written config has hundreds; aliases must not explode


def expanded_size(path: Path) -> int:
    """How many YAML nodes ``path`` holds once every alias is expanded, counted on the
    composed graph (where an alias is one shared node) without expanding anything."""
    import yaml

    root = yaml.compose(path.read_text())
    sizes: dict[int, int] = {}

    def size(node) -> int:
        if id(node) not in sizes:
            sizes[id(node)] = 0  # a recursive alias counts once
            children = node.value if isinstance(node.value, list) else []
            items = [
                c for child in children for c in (child if isinstance(child, tuple) else (child,))
            ]
            sizes[id(node)] = 1 + sum(size(c) for c in items)
        return sizes[id(node)]

    return size(root) if root is not None else 0


def check_config_files(argv: list[str]) -> None:
    """Refuse a ``--config`` file that does not exist (saying how to get the shipped ones), or
    whose aliases expand past :data:`MAX_CONFIG_NODES` before the parser expands it (a few
    lines can make billions of nodes and exhaust the memory).

    Raises:
        UserError: naming the file, and what to do or its expanded size."""
    import yaml

    for i, arg in enumerate(argv):
        if arg == "--config" and i + 1 < len(argv):
            value = argv[i + 1]
        elif arg.startswith("--config="):
            value = arg.split("=", 1)[1]
        else:
            continue
        path = Path(value)
        if not path.exists():
            raise UserError(missing_config_message(value))
        if not path.is_file():
            continue  # the parser says what is wrong with it
        try:
            n = expanded_size(path)
        except (yaml.YAMLError, UnicodeDecodeError, RecursionError):
            continue  # likewise
        if n > MAX_CONFIG_NODES:
            raise UserError(
                f"--config {path}: its aliases expand to {n:,} YAML nodes (a config holds a "
                f"few hundred; the limit is {MAX_CONFIG_NODES:,}); write the values out "
                "instead of nesting aliases"
            )


def missing_config_message(value: str) -> str:
    """One line for a ``--config`` file that does not exist: where the shipped configs are
    (outside a checkout ``configs/`` is not there until ``hispo-pl config copy`` makes it)."""
    stem = Path(value).with_suffix("").as_posix().removeprefix("configs/")
    shipped = stem in config_names()
    what = "a shipped config, but this folder has no copy of it" if shipped else "no such file"
    return (
        f"--config {value}: {what}; `hispo-pl config copy configs` copies the shipped configs "
        "here (`hispo-pl config list` names them)"
    )


def config_root() -> Path:
    """``./configs`` when run from a checkout (so edits there apply), else the packaged copy."""
    local = Path("configs")
    if (local / "methods").is_dir() and (local / "streams").is_dir():
        return local
    return Path(str(resources.files("hispo_pl.configs")))


def config_names(root: Path | None = None) -> list[str]:
    """Every shipped config as ``group/name`` (``methods/hispo``) or ``name`` (``demo``)."""
    root = root or config_root()
    return sorted(p.relative_to(root).with_suffix("").as_posix() for p in root.rglob("*.yaml"))


def config_path(name: str, root: Path | None = None) -> Path:
    """The file of a config named ``methods/hispo``, ``hispo`` (when one group has it) or a
    path; an unknown or ambiguous name is a user error listing what exists."""
    root = root or config_root()
    if Path(name).suffix in (".yaml", ".yml") and Path(name).is_file():
        return Path(name)
    names = config_names(root)
    stem = name.removesuffix(".yaml")
    matches = [n for n in names if n == stem or n.rsplit("/", 1)[-1] == stem]
    if len(matches) == 1:
        return root / f"{matches[0]}.yaml"
    if not matches:
        raise UserError(f"no config named {name!r}; shipped configs: {', '.join(names)}")
    raise UserError(f"{name!r} names several configs ({', '.join(matches)}); give one of them")


def check_copy_destination(dest: Path) -> None:
    """Refuse a destination ``config copy`` must not fill: a file, a name that looks like one
    (``my.yaml`` would become a folder of configs), a folder with files in it.

    Raises:
        UserError: naming the destination, and what to give instead."""
    if dest.suffix in (".yaml", ".yml") or (dest.exists() and not dest.is_dir()):
        what = "is a file" if dest.exists() else "names a file"
        raise UserError(
            f"{dest} {what}; config copy fills a folder with every shipped config: name a new "
            f"folder (hispo-pl config show NAME > {dest} writes one config)"
        )
    if dest.exists() and any(dest.iterdir()):
        raise UserError(f"{dest} exists and is not empty; choose a new folder")


def config_main(argv: list[str]) -> int:
    """``hispo-pl config list|show NAME|copy DEST``."""
    parser = VerbParser(
        prog="hispo-pl config",
        description="The configs hispo-pl ships: streams, methods, single-task HBC/BC, the demo",
    )
    sub = parser.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="every shipped config, by name")
    show = sub.add_parser("show", help="print a config (e.g. methods/hispo, pointmaze-1)")
    show.add_argument("name")
    copy = sub.add_parser("copy", help="copy every shipped config into DEST, to edit them")
    copy.add_argument("dest", type=Path)
    args = parser.parse_args(argv)
    root = config_root()
    if args.cmd == "list":
        print(f"# {root}")
        print("\n".join(config_names(root)))
    elif args.cmd == "show":
        print(config_path(args.name, root).read_text(), end="")
    else:
        check_copy_destination(args.dest)
        make_folder(args.dest)
        for name in config_names(root):
            target = args.dest / f"{name}.yaml"
            make_folder(target.parent)
            atomic_write_text(target, (root / f"{name}.yaml").read_text())
        print(f"copied {len(config_names(root))} configs to {args.dest}")
    return 0
