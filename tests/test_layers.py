"""No import cycle among the modules of flexlink and controllers (issue 20), read from the source itself.

``lint-imports`` (pyproject.toml) checks the layers: controllers above flexlink, and within flexlink the
stages in pipeline order.  A layers contract says nothing about two modules of one stage importing each
other, which is what this test adds: the graph of every ``import`` statement, at module level or inside a
function (a lazy import still ties the two modules together), must have no cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("flexlink", "controllers")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, name: str, modules: set[str]) -> set[str]:
    """The project modules ``path`` imports.

    ``from package import name`` is an edge to the sub-module ``package.name`` when that is a module, else to
    the package (the name is one of its ``__init__``'s).
    """
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            subs = {f"{base}.{a.name}" for a in node.names} & modules
            found |= subs
            if len(subs) < len(node.names):
                found.add(base)
    return {m for m in found if m in modules and m != name}


def _graph() -> dict[str, set[str]]:
    files = {_module_name(p): p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py")}
    modules = set(files)
    return {name: _imports(path, name, modules) for name, path in files.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of the graph as a path that closes on itself, or None (depth-first search, three colours)."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)) is not None:
                return found
        stack.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node)) is not None:
            return found
    return None


def test_the_cycle_finder_finds_a_cycle_and_accepts_a_tree():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


def test_the_graph_sees_absolute_relative_and_lazy_imports():
    graph = _graph()
    assert "flexlink.errors" in graph["flexlink.scene.loader"]                  # absolute, module level
    assert "flexlink.mechanics.shapes.base" in graph["flexlink.mechanics.shapes"]   # relative (from .base)
    assert "flexlink.export.fmu" in graph["flexlink.cli"]                       # inside a command function


def test_no_module_imports_itself_through_others():
    cycle = _cycle(_graph())
    assert cycle is None, " -> ".join(cycle or [])


def test_flexlink_never_imports_controllers():
    graph = _graph()
    assert [(m, d) for m, deps in graph.items() if m.startswith("flexlink") for d in deps
            if d.startswith("controllers")] == []


def test_every_package_is_installed():
    """pyproject.toml lists its packages by hand ([tool.setuptools] packages): a package left out is missing from
    a non-editable install (``flexlink.tools.check`` was, with its win64 call server's C files)."""
    import tomllib

    root = Path(__file__).resolve().parent.parent
    listed = set(tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(root).parts) for top in ("flexlink", "controllers")
             for p in (root / top).rglob("__init__.py")}
    assert found - listed == set()
