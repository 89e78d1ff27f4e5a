"""The house rules of docs/ARCHITECTURE.md, read from the source: who may import whom.

The sans-IO core (wire codec, session, controllers, protection, admission) never imports asyncio, a
clock, the emulator, the simulator or the command line; nothing imports the command line; the package
has no import circle; the root holds only the public face; no module grows past 900 lines. Imports
under ``if TYPE_CHECKING:`` are annotations only and do not count.

Three walls a reader would trip over are checked by name: the slave's front door (admission) imports
nothing from the session, whose connection imports it (what both use lives below both, in
``tdtp.wire`` and ``tdtp.config``); the core loads its optional C extension through
``tdtp._extensions``, never through ``tdtp._build`` (which decides the build for the package face);
and no module calls a private method of a class defined in another module.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "tdtp"

LAYERS: dict[str, int] = {
    # foundation: errors and the wire format
    "tdtp.errors": 0,
    "tdtp.wire": 0,
    "tdtp._extensions": 0,
    "tdtp._moved_modules": 0,
    # the sans-IO core, bottom up: protection and controllers; the configuration; the slave's front
    # door; the session itself
    "tdtp.protection": 1,
    "tdtp.control": 1,
    "tdtp.config": 2,
    "tdtp.admission": 4,
    "tdtp.session": 5,
    "tdtp.rendezvous": 5,
    # sans-IO pieces beside the core, for its drivers and for applications
    "tdtp.netem": 1,
    "tdtp.teleop": 1,
    "tdtp.analysis": 1,
    "tdtp.capture": 1,
    # the drivers: real sockets and virtual time
    "tdtp.aio": 6,
    "tdtp.sim": 6,
    # the public face (which build of the core runs, decided first), then the command line on top
    "tdtp._build": 6,
    "tdtp": 7,
    "tdtp.cli": 8,
    "tdtp.__main__": 9,
}
"""A module may import modules of a lower layer and of its own group, nothing above."""

CORE = (
    "tdtp.wire",
    "tdtp.protection",
    "tdtp.control",
    "tdtp.admission",
    "tdtp.session",
    "tdtp.rendezvous",
)
CORE_MUST_NOT_IMPORT = (
    "asyncio",
    "uvloop",
    "socket",
    "selectors",
    "time",
    "datetime",
    "tdtp.aio",
    "tdtp.netem",
    "tdtp.sim",
    "tdtp.cli",
)
"""I/O, clocks, the emulator, the simulator and the command line: none of them reach the core."""

ROOT_ALLOWED = {"__init__", "__main__", "_build", "_extensions"}
MAX_ROOT_MODULES = 5
MAX_LINES = 900


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _imports(tree: ast.AST) -> Iterator[str]:
    """Every module imported, at any depth, except under ``if TYPE_CHECKING:``."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            yield from (name for child in node.orelse for name in _imports_of(child))
            continue
        yield from _imports_of(node)


def _imports_of(node: ast.AST) -> Iterator[str]:
    if isinstance(node, ast.Import):
        yield from (alias.name for alias in node.names)
    elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
        yield node.module
        for alias in node.names:  # ``from tdtp.wire import header`` imports tdtp.wire.header
            if f"{node.module}.{alias.name}" in MODULES:
                yield f"{node.module}.{alias.name}"
    else:
        yield from _imports(node)


TREES = {name: ast.parse(path.read_text()) for name, path in MODULES.items()}
IMPORTS = {name: sorted(set(_imports(tree))) for name, tree in TREES.items()}


def _group(module: str) -> str:
    best = ""
    for group in LAYERS:
        if (module == group or module.startswith(group + ".")) and len(group) > len(best):
            best = group
    return best


def test_every_module_belongs_to_a_layer() -> None:
    assert [m for m in MODULES if not _group(m)] == []


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_point_down_the_layers(module: str) -> None:
    group = _group(module)
    upward = [
        imported
        for imported in IMPORTS[module]
        if imported.startswith("tdtp")
        and _group(imported) != group
        and LAYERS[_group(imported)] >= LAYERS[group]
    ]
    assert upward == [], f"{module} ({group}, layer {LAYERS[group]}) imports upward: {upward}"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m.startswith(CORE)))
def test_the_core_stays_sans_io(module: str) -> None:
    banned = [
        imported
        for imported in IMPORTS[module]
        if any(imported == b or imported.startswith(b + ".") for b in CORE_MUST_NOT_IMPORT)
    ]
    assert banned == [], f"the sans-IO core module {module} imports {banned}"


def test_nothing_imports_the_command_line() -> None:
    importers = sorted(
        module
        for module, imported in IMPORTS.items()
        if not (module == "tdtp.cli" or module.startswith("tdtp.cli.") or module == "tdtp.__main__")
        and any(i == "tdtp.cli" or i.startswith("tdtp.cli.") for i in imported)
    )
    assert importers == []


def test_no_import_circle() -> None:
    graph = {m: [i for i in IMPORTS[m] if i in MODULES and i != m] for m in MODULES}
    # A package's __init__ is imported with each of its modules; an edge to a package stands for it.
    state: dict[str, int] = {}
    stack: list[str] = []
    circles: list[list[str]] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in graph[node]:
            if state.get(nxt) == 1:
                circles.append([*stack[stack.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module)
    # ``tdtp`` (the public face) imports its own packages, whose modules import e.g. tdtp.errors, not
    # ``tdtp`` itself: a circle through ``tdtp`` would show here too.
    assert circles == []


def _in(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _in(m, "tdtp.admission")))
def test_admission_imports_nothing_from_the_session(module: str) -> None:
    """The session's connection imports admission; admission takes what both use (``Address``,
    ``DropReason``, ``ConnectionConfig``) from below both, so neither depends on the other."""
    assert [i for i in IMPORTS[module] if _in(i, "tdtp.session")] == []


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m.startswith(CORE)))
def test_the_core_loads_its_extensions_without_the_package_face(module: str) -> None:
    """``tdtp._build`` decides the build for the package face (``tdtp/__init__``); the core's one
    loader of optional C extensions is ``tdtp._extensions``, which imports nothing of tdtp."""
    assert [i for i in IMPORTS[module] if i in ("tdtp", "tdtp._build")] == []


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _private_methods(tree: ast.AST) -> set[str]:
    """The private methods (and properties) the classes of a module define."""
    return {
        item.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ClassDef)
        for item in node.body
        if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef) and _is_private(item.name)
    }


def _private_calls(tree: ast.AST) -> Iterator[tuple[int, str]]:
    """``x._name(...)`` on anything but ``self``, ``cls`` or ``super()``: (line, ``_name``)."""
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)):
            continue
        receiver = node.func.value
        if isinstance(receiver, ast.Name) and receiver.id in ("self", "cls"):
            continue
        if isinstance(receiver, ast.Call) and ast.unparse(receiver.func) == "super":
            continue
        if _is_private(node.func.attr):
            yield node.lineno, node.func.attr


PRIVATE_METHODS = {name: _private_methods(tree) for name, tree in TREES.items()}


def _foreign_private_calls(module: str, tree: ast.AST) -> list[str]:
    own = PRIVATE_METHODS[module]
    found = []
    for line, name in _private_calls(tree):
        owners = sorted(m for m, methods in PRIVATE_METHODS.items() if name in methods)
        if owners and name not in own:
            found.append(f"line {line}: .{name}() of {', '.join(owners)}")
    return found


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_module_calls_another_modules_private_method(module: str) -> None:
    """A class's private methods are its own module's business: another module that needs one
    gets a public hook (``Endpoint.flush``, ``deliver_tick``). Judged by name: a call of
    ``._name()`` on anything but ``self``/``cls``/``super()`` when only other modules define a
    method ``_name``."""
    assert _foreign_private_calls(module, TREES[module]) == []


def test_the_root_holds_only_the_public_face() -> None:
    loose = sorted(p.stem for p in PACKAGE.glob("*.py") if p.stem not in ROOT_ALLOWED)
    assert len(loose) <= MAX_ROOT_MODULES, loose


def test_no_module_over_900_lines() -> None:
    long = {
        name: n
        for name, path in MODULES.items()
        if (n := len(path.read_text().splitlines())) > MAX_LINES
    }
    assert long == {}


def test_the_layer_check_sees_an_upward_import() -> None:
    """The checks above can fail: a core module importing asyncio or the CLI is caught."""
    tree = ast.parse("import asyncio\nfrom tdtp.cli.main import main\n")
    assert list(_imports(tree)) == ["asyncio", "tdtp.cli.main"]
    guarded = ast.parse("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import asyncio\n")
    assert list(_imports(guarded)) == ["typing"]


def test_the_private_call_check_sees_a_foreign_call() -> None:
    """``ticker._deliver(...)`` from another module is caught; ``self._deliver(...)`` is not."""
    tree = ast.parse("def f(ticker, self):\n    ticker._flush_now()\n    self._flush_now()\n")
    PRIVATE_METHODS["tdtp.tests_probe"] = {"_flush_now"}
    try:
        assert _foreign_private_calls("tdtp.session.events", tree) == [
            "line 2: ._flush_now() of tdtp.tests_probe"
        ]
        assert _foreign_private_calls("tdtp.tests_probe", tree) == []
    finally:
        del PRIVATE_METHODS["tdtp.tests_probe"]
