"""Builds tdtp's compiled core: the sans-IO modules below, compiled to C extensions with mypyc.

Everything else (the asyncio layer, the CLI, the simulator, configuration and errors) stays Python, and
every compiled module keeps its ``.py`` source beside the extension: where the extension is missing (no
C compiler, ``TDTP_PURE_BUILD=1`` at install time) or switched off (``TDTP_PURE_PYTHON=1`` at run time)
the same code runs as plain Python. ``tdtp.build_info()`` says which one a process runs.

``pip install .`` (a wheel) and ``pip install -e .`` (extensions built in place, beside the sources)
both compile; ``make build`` recompiles in place after a source changed. The project metadata lives in
pyproject.toml; this file only adds the extensions.

Beside the core, one hand-written C extension: ``tdtp.aio._datagram``, the batched datagram engine
(``recvmmsg``/``sendmmsg``, Linux). It is optional in the same way: where it does not compile, the
core is still built and ``tdtp.aio.datagram`` runs its pure-Python engine.
"""

from __future__ import annotations

import ast
import inspect
import itertools
import os
import re
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

COMPILED = [
    "tdtp/wire/header.py",
    "tdtp/wire/hold.py",
    "tdtp/wire/seqnum.py",
    "tdtp/wire/protected.py",
    "tdtp/session/connection.py",
    "tdtp/session/events.py",
    "tdtp/session/stats.py",
    "tdtp/session/sent_log.py",
    "tdtp/session/receive_window.py",
    "tdtp/session/reorder_buffer.py",
    "tdtp/session/delivery.py",
    "tdtp/session/rtt.py",
    "tdtp/session/loss_rate.py",
    "tdtp/session/handshake.py",
    "tdtp/session/liveness.py",
    "tdtp/session/recovery.py",
    "tdtp/session/event_queue.py",
    "tdtp/session/outbox.py",
    "tdtp/session/ack_scheduler.py",
    "tdtp/session/sender.py",
    "tdtp/session/control_channel.py",
    "tdtp/session/timer_hint.py",
    "tdtp/session/reset_guard.py",
    "tdtp/session/path.py",
    "tdtp/session/state.py",
    "tdtp/session/view.py",
    "tdtp/session/sample_age.py",
    "tdtp/session/one_way.py",
    "tdtp/protection/replay_window.py",
    "tdtp/protection/packet_protection.py",
    "tdtp/control/base.py",
    "tdtp/control/equations.py",
    "tdtp/control/fixed.py",
    "tdtp/control/teleop.py",
    "tdtp/control/teleop_config.py",
    "tdtp/control/one_way_signal.py",
    "tdtp/control/competition.py",
    "tdtp/control/tfrc.py",
    "tdtp/control/trinomial.py",
    "tdtp/control/registry.py",
    "tdtp/control/send_meter.py",
    "tdtp/control/start_window.py",
    "tdtp/aio/outbox.py",
    "tdtp/aio/loop_timers.py",
    "tdtp/aio/endpoint.py",
    "tdtp/aio/demultiplexer.py",
]
"""The compiled core (tdtp/_build.py lists the same modules by name; a test checks they agree)."""

DATAGRAM = "tdtp.aio._datagram"
"""The batched datagram engine (recvmmsg/sendmmsg), plain C: optional, tdtp.aio.datagram falls back
to its pure-Python engine where it was not built."""

SLOT_FILLER = "tdtp.session._slot_filler"
"""Builds DataReceived straight into its slots, plain C: optional, tdtp.session.events falls back to
the slots' descriptors where it was not built."""
OPTIONAL_C = (DATAGRAM, SLOT_FILLER)

GROUP = "tdtp._core"
"""One shared library for the whole core, inside the package: tdtp/_core__mypyc.*.so."""


def _warn(message: str) -> None:
    print(f"tdtp: {message}; installing the pure-Python build", file=sys.stderr)


class OptionalBuildExt(build_ext):
    """Compile the core if a C compiler works; otherwise leave the pure-Python modules in place."""

    def run(self) -> None:
        try:
            super().run()
        except Exception as exc:
            _warn(f"the compiled core could not be built ({exc})")

    def build_extension(self, ext: object) -> None:
        name = getattr(ext, "name", None)
        if name in OPTIONAL_C:
            try:
                super().build_extension(ext)  # type: ignore[arg-type]
            except Exception as exc:  # the core still builds; the pure-Python fallback runs
                print(
                    f"tdtp: could not compile {name} ({exc}); its pure-Python fallback runs",
                    file=sys.stderr,
                )
            return
        try:
            super().build_extension(ext)  # type: ignore[arg-type]
        except Exception as exc:
            _warn(f"could not compile {getattr(ext, 'name', ext)} ({exc})")
            raise


def _datagram_extension() -> list[object]:
    """The C datagram engine, on Linux only (recvmmsg, sendmmsg, SO_TIMESTAMPNS)."""
    if not sys.platform.startswith("linux"):
        return []
    return [Extension(DATAGRAM, ["tdtp/aio/_datagram.c"], extra_compile_args=["-O2", "-std=gnu11"])]


def _slot_filler_extension() -> list[object]:
    """DataReceived built straight into its slots (portable C, any platform)."""
    return [Extension(SLOT_FILLER, ["tdtp/session/_slot_filler.c"], extra_compile_args=["-O2"])]


def _extensions() -> list[object]:
    if os.environ.get("TDTP_PURE_BUILD"):
        return []
    return _datagram_extension() + _slot_filler_extension() + _core_extensions()


def _docstrings(paths: list[str]) -> dict[tuple[str, str | None, str], str]:
    """Every docstring of the compiled modules' functions, methods, properties and attributes,
    keyed ``(module, class or None, name)``: a method's from its body, an attribute's from the
    string literal after its assignment (in the class body or as ``self.name`` in ``__init__``)."""
    docs: dict[tuple[str, str | None, str], str] = {}

    def add(module: str, cls: str | None, name: str, doc: str | None) -> None:
        if doc and (module, cls, name) not in docs:  # a property's getter, not its setter
            docs[module, cls, name] = inspect.cleandoc(doc)

    def attribute_docs(module: str, cls: str, body: list[ast.stmt], owner: str | None) -> None:
        for statement, following in itertools.pairwise(body):
            if not (
                isinstance(following, ast.Expr)
                and isinstance(following.value, ast.Constant)
                and isinstance(following.value.value, str)
            ):
                continue
            targets = (
                statement.targets
                if isinstance(statement, ast.Assign)
                else [statement.target]
                if isinstance(statement, ast.AnnAssign)
                else []
            )
            for target in targets:
                if owner is None and isinstance(target, ast.Name):
                    add(module, cls, target.id, following.value.value)
                elif (
                    isinstance(target, ast.Attribute)
                    and isinstance(target.value, ast.Name)
                    and target.value.id == owner
                ):
                    add(module, cls, target.attr, following.value.value)

    for path in paths:
        module = path.removesuffix(".py").replace("/", ".")
        tree = ast.parse(Path(path).read_text(encoding="utf-8"))
        for node in tree.body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                add(module, None, node.name, ast.get_docstring(node, clean=False))
            elif isinstance(node, ast.ClassDef):
                add(module, None, node.name, ast.get_docstring(node, clean=False))
                attribute_docs(module, node.name, node.body, None)
                for item in node.body:
                    if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef):
                        add(module, node.name, item.name, ast.get_docstring(item, clean=False))
                        if item.name == "__init__" and item.args.args:
                            attribute_docs(module, node.name, item.body, item.args.args[0].arg)
    return docs


def _c_string(text: str) -> str:
    """``text`` as a C string literal (UTF-8; octal escapes, so no hex run-on, no trigraph)."""
    simple = {ord("\\"): "\\\\", ord('"'): '\\"', ord("\n"): "\\n", ord("?"): "\\?"}
    out = []
    for byte in text.encode("utf-8"):
        if byte in simple:
            out.append(simple[byte])
        elif 32 <= byte < 127:
            out.append(chr(byte))
        else:
            out.append(f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


_C_LITERAL = r'(?:NULL|"(?:[^"\\]|\\.)*")'
_METHOD_ENTRY = re.compile(
    r"(?P<head>\(PyCFunction\)CPyPy_(?P<c>\w+),\s*[A-Z_| ]+,\s*PyDoc_STR\()(?P<doc>"
    + _C_LITERAL
    + r")\)"
)
"""A ``PyMethodDef`` entry of a compiled function or method, its doc a text signature or NULL."""
_GETSET_ENTRY = re.compile(
    r'\{"(?P<attr>\w+)",\s*\(getter\)(?P<c>\w+?)_get_(?P=attr),(?P<mid>[^{}]*?)'
    r"(?P<tail>NULL, NULL, NULL\}|NULL, NULL\})"
)
"""A ``PyGetSetDef`` entry: a property (setter, doc, closure) or an attribute (doc, closure)."""
_TYPE_DOC = re.compile(
    r"(?P<head>CPyType_(?P<c>\w+)_template_ = \{[^{}]*?\.tp_doc = PyDoc_STR\()(?P<doc>"
    + _C_LITERAL
    + r")\)"
)
"""A type's ``tp_doc``: a native class's, or that of the callable object carrying a method of a
class left plain Python."""


def _c_names(docs: dict[tuple[str, str | None, str], str]) -> dict[str, str]:
    """The docstrings by the C names mypyc gives their objects: a module's prefix is the shortest
    unique tail of its dotted name (``endpoint___``, ``session___outbox___``); every tail is
    listed, only the one mypyc chose is ever looked up."""
    by_c: dict[str, str] = {}
    for (module, cls, name), doc in docs.items():
        parts = module.split(".")
        for k in range(1, len(parts) + 1):
            prefix = "___".join(parts[-k:])
            if cls is None:
                by_c[f"{prefix}___{name}"] = doc  # a function, or a class's own docstring
            else:
                by_c[f"{prefix}___{cls}___{name}"] = doc  # method
                by_c[f"{prefix}___{name}_{cls}_obj"] = doc  # a plain class's method object
                by_c[f"{prefix}___{cls}\0{name}"] = doc  # property or attribute
    return by_c


def _document_c(text: str, by_c: dict[str, str]) -> str:
    """mypyc's generated C with the docstrings written into its tables."""

    def method(match: re.Match[str]) -> str:
        doc = by_c.get(match["c"])
        if doc is None:
            return match[0]
        current, end = match["doc"], "\\n--\\n\\n"  # a text signature ends so
        signature = current[: current.index(end) + len(end)] if end in current else None
        literal = _c_string(doc) if signature is None else signature + _c_string(doc)[1:]
        return f"{match['head']}{literal})"

    def getset(match: re.Match[str]) -> str:
        doc = by_c.get(f"{match['c']}\0{match['attr']}")
        if doc is None:
            return match[0]
        literal = f"PyDoc_STR({_c_string(doc)})"
        tail = (
            f"NULL, {literal}, NULL}}" if match["tail"].count("NULL") == 3 else f"{literal}, NULL}}"
        )
        return match[0][: match.start("tail") - match.start()] + tail

    text = _METHOD_ENTRY.sub(method, text)
    text = _GETSET_ENTRY.sub(getset, text)
    return _TYPE_DOC.sub(method, text)


class _DocumentedC:
    """mypyc gives a compiled function, method or property no docstring (only a text signature),
    so ``help(ep.send_control)`` would be empty in the compiled build. mypyc is itself compiled, so
    its code generator cannot be patched; instead the C it writes gets the sources' docstrings in
    its tables (``PyMethodDef``, ``PyGetSetDef``, ``tp_doc``) before the C compiler sees it. When
    the result equals what the last build left, the file keeps its old time, so that a build with
    no change to the compiled sources compiles nothing. tests/test_build.py checks the result."""

    def __init__(self, paths: list[str]) -> None:
        self._by_c = _c_names(_docstrings(paths))
        self._before: dict[Path, tuple[str, os.stat_result]] = {}

    def remember(self, sources: list[Path]) -> None:
        for source in sources:
            if source.is_file():
                self._before[source] = (source.read_text(encoding="utf-8"), source.stat())

    def apply(self, sources: list[Path]) -> None:
        for source in sources:
            documented = _document_c(source.read_text(encoding="utf-8"), self._by_c)
            before = self._before.get(source)
            source.write_text(documented, encoding="utf-8")
            if before is not None and before[0] == documented:
                os.utime(source, ns=(before[1].st_atime_ns, before[1].st_mtime_ns))


def _core_extensions() -> list[object]:
    try:
        from mypyc.build import mypycify  # noqa: PLC0415 - a build-time dependency only
    except ImportError:
        _warn("mypyc is not installed")
        return []
    documented = _DocumentedC(COMPILED)
    documented.remember(sorted(Path("build").glob("**/__native*.c")))
    try:
        extensions = list(mypycify(COMPILED, opt_level="3", group_name=GROUP))
    except (Exception, SystemExit) as exc:  # mypyc exits when its type check fails
        _warn(f"mypyc could not prepare the core ({exc!r})")
        return []
    generated = {
        Path(source)
        for extension in extensions
        for source in getattr(extension, "sources", [])
        if Path(source).name.startswith("__native") and source.endswith(".c")
    }
    try:
        documented.apply(sorted(generated))
    except (OSError, UnicodeError, re.error) as exc:
        print(f"tdtp: compiled without docstrings ({exc!r})", file=sys.stderr)
    return extensions


setup(ext_modules=_extensions(), cmdclass={"build_ext": OptionalBuildExt})
