"""What tdtp offers its users, in one list: the package face (``tdtp.__all__``) and the submodules
whose names are documented for direct use. The API reference (docs/reference/) covers exactly these
(tests/test_docs.py), and every public function, method and property of them has a docstring in
both builds (tests/test_docstrings.py)."""

from __future__ import annotations

import ast
import importlib
import inspect
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

PUBLIC_MODULES = (
    "tdtp",
    "tdtp.teleop.schema",
    "tdtp.teleop.deadband",
    "tdtp.teleop.haptic_sample",
    "tdtp.control",
    "tdtp.netem",
    "tdtp.aio.relay",
    "tdtp.wire",
    "tdtp.capture.pcap",
    "tdtp.analysis.bandwidth",
    "tdtp.sim",
)
"""The face first, then the submodules for applications (typed samples, deadband, the demo's
haptic record), for researchers (controllers, the emulator and its relay, the simulator, the
bandwidth model) and for implementers (the wire format, captures)."""


def public_names(module: ModuleType) -> list[str]:
    """The names ``module`` offers: its ``__all__`` (every public module declares one)."""
    names = getattr(module, "__all__", None)
    assert names is not None, f"{module.__name__} declares no __all__"
    return [str(name) for name in names]


def public_objects() -> Iterator[tuple[str, str, object]]:
    """(module, name, object) for every public name of every public module."""
    for module_name in PUBLIC_MODULES:
        module = importlib.import_module(module_name)
        for name in public_names(module):
            yield module_name, name, getattr(module, name)


def _source_members(cls: type) -> dict[str, str | None]:
    """The public functions a class's body defines (methods, properties, class and static
    methods) and their docstrings, read from its source: the same set in both builds, where the
    compiled build's runtime types cannot tell a property from an attribute."""
    package = Path(__file__).resolve().parent.parent
    base = package.joinpath(*cls.__module__.split("."))
    source = base / "__init__.py" if base.is_dir() else base.with_suffix(".py")
    if not source.is_file():
        return {}
    tree = ast.parse(source.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef) and node.name == cls.__name__:
            return {
                item.name: ast.get_docstring(item)
                for item in node.body
                if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef)
                and not item.name.startswith("_")
            }
    return {}


def public_members(cls: type) -> Iterator[tuple[str, object, str | None]]:
    """(name, member, its docstring in the source) for the public methods and properties of
    ``cls`` that tdtp defines, its own and those inherited from tdtp's classes."""
    seen: set[str] = set()
    for klass in cls.__mro__:
        if not klass.__module__.startswith("tdtp"):
            continue
        for name, doc in sorted(_source_members(klass).items()):
            if name not in seen:
                seen.add(name)
                yield name, inspect.getattr_static(cls, name), doc
