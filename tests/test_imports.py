"""The package has no import circle: every module of ``hispo_pl`` is read with ``ast``, every
import counts (at module level, inside a function or under ``TYPE_CHECKING``), and no two
modules may reach each other."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "hispo_pl"


def package_modules(root: Path = ROOT) -> dict[str, Path]:
    """Module name -> file for every module of ``hispo_pl``; a package is its ``__init__``."""
    modules: dict[str, Path] = {}
    for path in sorted((root / PACKAGE).rglob("*.py")):
        parts = path.relative_to(root / PACKAGE).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        modules[".".join((PACKAGE, *parts))] = path
    return modules


def imported_modules(name: str, path: Path, known: set[str]) -> dict[str, int]:
    """The modules of ``known`` that module ``name`` imports, with the line of the first such
    import. ``from X import y`` imports ``X.y`` when it is a module, else ``X`` itself."""
    is_package = path.name == "__init__.py"
    found: dict[str, int] = {}

    def add(target: str, line: int) -> None:
        while target and target not in known:  # import a.b.c: the deepest module we know
            target = target.rpartition(".")[0]
        if target and target != name:
            found.setdefault(target, line)

    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = name if is_package else name.rpartition(".")[0]
                for _ in range(node.level - 1):
                    parent = parent.rpartition(".")[0]
                base = f"{parent}.{base}" if base else parent
            if not base.startswith(PACKAGE):
                continue
            for alias in node.names:
                child = f"{base}.{alias.name}"
                add(child if child in known else base, node.lineno)
    return found


def import_graph(root: Path = ROOT) -> dict[str, dict[str, str]]:
    """module -> {imported module: ``file:line`` of the import}."""
    modules = package_modules(root)
    known = set(modules)
    return {
        name: {
            target: f"{path.relative_to(root)}:{line}"
            for target, line in imported_modules(name, path, known).items()
        }
        for name, path in modules.items()
    }


def circles(graph: dict[str, dict[str, str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, {}):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def one_circle(graph: dict[str, dict[str, str]], component: list[str]) -> list[str]:
    """A shortest path from the component's first module back to itself, each step as
    ``a -> b (file:line)``: the imports to cut."""
    start, members = component[0], set(component)
    came_from: dict[str, str] = {}
    frontier = [start]
    while frontier and start not in came_from:
        following = []
        for node in frontier:
            for target in sorted(graph[node]):
                if target in members and target not in came_from:
                    came_from[target] = node
                    following.append(target)
        frontier = following
    path = [start]
    while len(path) == 1 or path[-1] != start:
        path.append(came_from[path[-1]])
    path.reverse()
    return [f"{a} -> {b} ({graph[a][b]})" for a, b in zip(path[:-1], path[1:], strict=True)]


def describe(graph: dict[str, dict[str, str]], found: list[list[str]]) -> str:
    return "\n".join(
        f"import circle among {', '.join(component)}:\n  "
        + "\n  ".join(one_circle(graph, component))
        for component in found
    )


def test_the_package_has_no_import_circle():
    graph = import_graph()
    found = circles(graph)
    assert not found, describe(graph, found)


def test_the_graph_holds_the_package_imports():
    """The walk sees relative, absolute and lazy imports, the callbacks' among them."""
    graph = import_graph()
    assert "hispo_pl.callbacks.loss_search" in graph
    assert "hispo_pl.tasks" in graph["hispo_pl.data.datasets"]  # from ..tasks import
    assert "hispo_pl.fit" in graph["hispo_pl.benchmark.command_line"]  # inside a function
    assert "hispo_pl.cli" not in graph["hispo_pl.benchmark.command_line"]
    assert "hispo_pl.data.generation" not in graph["hispo_pl.data.datasets"]


def test_a_circle_through_a_function_or_a_package_is_found(tmp_path):
    """A lazy import still closes a circle, and ``from . import x`` of a name the package's
    ``__init__`` defines goes through the ``__init__``."""
    package = tmp_path / PACKAGE
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("from .b import f\n")
    (package / "b.py").write_text("def f():\n    from . import a\n")
    (package / "sub" / "__init__.py").write_text("from .one import One\n")
    (package / "sub" / "one.py").write_text("from . import One as Again\n")
    (package / "sub" / "two.py").write_text("from . import one\n")  # the module, not __init__
    graph = import_graph(tmp_path)
    found = circles(graph)
    assert found == [["hispo_pl.a", "hispo_pl.b"], ["hispo_pl.sub", "hispo_pl.sub.one"]]
    message = describe(graph, found)
    assert "hispo_pl.b -> hispo_pl.a (hispo_pl/b.py:2)" in message
    assert graph["hispo_pl.sub.two"] == {"hispo_pl.sub.one": "hispo_pl/sub/two.py:1"}
