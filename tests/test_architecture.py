"""The package's shape (docs/architecture.md): no import cycle between harness modules, every import points
down the declared layer order, and no module reaches into another's private names. (Modules are split along
seams, not at a line count: no length is checked.)

The import graph is read from the source with ``ast``: every ``import`` counts, at module level, inside a
function, or under ``TYPE_CHECKING`` — a cycle hidden in a function is still a cycle.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "harness"

LAYERS: tuple[tuple[str, ...], ...] = (
    ("harness.core",),
    ("harness.wire",),
    ("harness.fdm",),
    ("harness.autopilot",),
    ("harness.channel",),
    ("harness.simclock",),
    ("harness.net", "harness.metrics"),
    ("harness.record",),
    ("harness.scenario",),
    ("harness.run",),
    ("harness.sweep",),
    ("harness.cli", "harness.cli_run", "harness.cli_types", "harness.pytest_plugin", "harness.bundled"),
)
"""Bottom to top: a module may import from its own layer and the layers below, never from one above.
The longest matching prefix decides (``harness.cli_run`` is not ``harness.cli``'s submodule: it is listed)."""


def module_files(package: Path = PACKAGE) -> dict[str, Path]:
    out = {}
    for path in sorted(package.rglob("*.py")):
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _owner(name: str, modules: Mapping[str, Path]) -> str | None:
    """The harness module an imported name lives in (``harness.a.b.Thing`` -> ``harness.a.b``)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def _imported(tree: ast.AST, module: str, is_package: bool) -> Iterator[str]:
    """Every dotted name imported: ``from a.b import c`` gives ``a.b.c`` (a submodule, or a name of ``a.b``)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".") if is_package else module.split(".")[:-1]
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            yield from (f"{base}.{alias.name}" for alias in node.names)


def import_graph(modules: Mapping[str, Path]) -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        deps = set()
        for imported in _imported(tree, name, path.name == "__init__.py"):
            if imported == "harness" or imported.startswith("harness."):
                owner = _owner(imported, modules)
                if owner is not None and owner != name:
                    deps.add(owner)
        graph[name] = deps
    return graph


def find_cycle(graph: Mapping[str, set[str]]) -> list[str] | None:
    """One import cycle (as a path that returns to its start), or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for dep in sorted(graph.get(node, ())):
            if state.get(dep) == 1:
                return [*path[path.index(dep) :], dep]
            if dep not in state:
                found = visit(dep)
                if found:
                    return found
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state:
            found = visit(start)
            if found:
                return found
    return None


def layer_of(module: str) -> int | None:
    best: tuple[int, int] | None = None  # (prefix length, layer)
    for index, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and (best is None or len(prefix) > best[0]):
                best = (len(prefix), index)
    if best is None:
        return 0 if module == "harness" else None
    return best[1]


def upward_imports(graph: Mapping[str, set[str]]) -> list[str]:
    out = []
    for module, deps in sorted(graph.items()):
        mine = layer_of(module)
        for dep in sorted(deps):
            theirs = layer_of(dep)
            if mine is not None and theirs is not None and theirs > mine:
                out.append(f"{module} (layer {mine}) imports {dep} (layer {theirs})")
    return out


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph(module_files())


def test_the_graph_sees_function_level_and_type_checking_imports(tmp_path: Path) -> None:
    pkg = tmp_path / "harness"
    (pkg / "a").mkdir(parents=True)
    for f in ("__init__.py", "a/__init__.py"):
        (pkg / f).write_text("")
    (pkg / "a" / "x.py").write_text("def f():\n    from harness.a.y import g\n")
    (pkg / "a" / "y.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from harness.a import x\n"
    )
    (pkg / "a" / "z.py").write_text("from . import y\nimport harness.a.x\n")
    g = import_graph(module_files(pkg))
    assert g["harness.a.x"] == {"harness.a.y"}
    assert g["harness.a.y"] == {"harness.a.x"}
    assert g["harness.a.z"] == {"harness.a.y", "harness.a.x"}
    cycle = find_cycle(g)
    assert cycle is not None and cycle[0] == cycle[-1] and set(cycle) == {"harness.a.x", "harness.a.y"}


def test_upward_imports_are_found() -> None:
    assert upward_imports({"harness.fdm.link": {"harness.channel.shell"}}) == [
        "harness.fdm.link (layer 2) imports harness.channel.shell (layer 4)"
    ]
    assert upward_imports({"harness.run.launcher": {"harness.fdm.link", "harness.core.clock"}}) == []
    assert layer_of("harness.wire.protocol") == 1 and layer_of("harness.simclock.runtime") == 5
    assert layer_of("harness.cli_types") == layer_of("harness.cli")


def test_no_import_cycle(graph: dict[str, set[str]]) -> None:
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or ())


def test_every_module_has_a_layer(graph: dict[str, set[str]]) -> None:
    assert [m for m in graph if layer_of(m) is None] == [], "add the new package to LAYERS (and docs/architecture.md)"


def test_layers_depend_downward_only(graph: dict[str, set[str]]) -> None:
    assert upward_imports(graph) == []


def _private_names_defined(tree: ast.AST) -> set[str]:
    """The private names a module defines: functions, classes, module globals, attributes it assigns, slots."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            out.add(node.attr)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            out.add(node.id)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            out.add(node.value)  # __slots__ entries
    return {n for n in out if n.startswith("_") and not n.startswith("__")}


def private_accesses(modules: Mapping[str, Path]) -> list[str]:
    """Every ``x._name`` (x not ``self`` / ``cls``) whose ``_name`` another harness module defines and this one
    does not: one module reaching into another's private state. (Privates of the standard library or of
    third-party packages, ``os._exit``, are not counted: their owners are not ours to reshape.)"""
    trees = {name: ast.parse(path.read_text(), str(path)) for name, path in modules.items()}
    defined = {name: _private_names_defined(tree) for name, tree in trees.items()}
    ours = set().union(*defined.values())
    out = []
    for name, tree in trees.items():
        for node in ast.walk(tree):
            if not isinstance(node, ast.Attribute) or not node.attr.startswith("_") or node.attr.startswith("__"):
                continue
            if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                continue
            if node.attr in ours and node.attr not in defined[name]:
                out.append(f"{name}:{node.lineno}: {ast.unparse(node)}")
    return sorted(out)


KNOWN_PRIVATE_ACCESSES: dict[str, str] = {}
"""Modules allowed to reach into another's private state: none (the mission runtime's blocker registry, once read
as ``rt._tracked``, is public since issue 33: ``threads.Registry``, ``SimRuntime.on_sim_time``). Nothing may be
added here."""


def test_private_accesses_are_found(tmp_path: Path) -> None:
    pkg = tmp_path / "harness"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text(
        "class A:\n    def __init__(self):\n        self._x = 1\n\n    def same(self, o):\n        return o._x\n"
    )
    (pkg / "b.py").write_text("import os\n\ndef f(a):\n    os._exit(a._x)\n")
    assert private_accesses(module_files(pkg)) == ["harness.b:4: a._x"]


THIRD_PARTY_PRIVATES = {("harness.record.world", "chunk.record_writer._buffer")}
"""Accesses to a third-party object's private name that happens to be spelled like one of ours (``mcap``'s chunk
buffer, written to directly by ``record/world.py``'s fast path, which checks its type and falls back to
``Writer.add_message`` when it is not there): not one harness module reaching into another."""


def test_no_module_touches_another_modules_private_names() -> None:
    found = [
        hit
        for hit in private_accesses(module_files())
        if KNOWN_PRIVATE_ACCESSES.get(hit.partition(":")[0]) != hit.rpartition(": ")[2]
        and (hit.partition(":")[0], hit.rpartition(": ")[2]) not in THIRD_PARTY_PRIVATES
    ]
    assert found == [], "use (or add) a public method instead of reaching into another module's private state"
