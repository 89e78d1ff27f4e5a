"""Which build of the core this process runs: the mypyc-compiled extensions or plain Python.

The sans-IO core (:data:`COMPILED_MODULES`) is compiled with mypyc when tdtp is installed on a machine
with a C compiler (``setup.py``); every compiled module keeps its ``.py`` source beside the extension,
and the two behave the same (the whole test suite runs against both). Python's import system prefers
an extension to a source file, so the compiled build runs wherever it was built, and the pure build
where it was not, with no switch needed. Two things make the pure modules run although extensions
exist:

* ``TDTP_PURE_PYTHON=1`` in the environment (like aiohttp's ``AIOHTTP_NO_EXTENSIONS``): for testing,
  profiling the Python code, or ruling the compiled code out when hunting a bug;
* an in-place development build older than a source it compiled (a checkout where ``make build`` has
  not run since the edit). Running stale machine code would silently ignore the edit, so the pure
  modules run instead and a warning says how to recompile.

This module is imported first by ``tdtp/__init__.py``, before any compiled module, and is itself never
compiled. The optional plain-C extensions beside the core are loaded by :mod:`tdtp._extensions`
(re-exported here), which the core imports without this module.
"""

from __future__ import annotations

import ast
import importlib.abc
import importlib.machinery
import importlib.util
import os
import re
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType
from typing import Final

from tdtp._extensions import PURE_ENV, load_extension, pure_requested

__all__ = ["COMPILED_MODULES", "PURE_ENV", "BuildInfo", "build_info", "load_extension"]

COMPILED_MODULES: Final = (
    "tdtp.wire.header",
    "tdtp.wire.hold",
    "tdtp.wire.seqnum",
    "tdtp.wire.protected",
    "tdtp.session.connection",
    "tdtp.session.events",
    "tdtp.session.stats",
    "tdtp.session.sent_log",
    "tdtp.session.receive_window",
    "tdtp.session.reorder_buffer",
    "tdtp.session.delivery",
    "tdtp.session.rtt",
    "tdtp.session.loss_rate",
    "tdtp.session.handshake",
    "tdtp.session.liveness",
    "tdtp.session.recovery",
    "tdtp.session.event_queue",
    "tdtp.session.outbox",
    "tdtp.session.ack_scheduler",
    "tdtp.session.sender",
    "tdtp.session.control_channel",
    "tdtp.session.timer_hint",
    "tdtp.session.reset_guard",
    "tdtp.session.path",
    "tdtp.session.state",
    "tdtp.session.view",
    "tdtp.session.sample_age",
    "tdtp.session.one_way",
    "tdtp.protection.replay_window",
    "tdtp.protection.packet_protection",
    "tdtp.control.base",
    "tdtp.control.equations",
    "tdtp.control.fixed",
    "tdtp.control.teleop",
    "tdtp.control.teleop_config",
    "tdtp.control.one_way_signal",
    "tdtp.control.competition",
    "tdtp.control.tfrc",
    "tdtp.control.trinomial",
    "tdtp.control.registry",
    "tdtp.control.send_meter",
    "tdtp.control.start_window",
    "tdtp.aio.outbox",
    "tdtp.aio.loop_timers",
    "tdtp.aio.endpoint",
    "tdtp.aio.demultiplexer",
)
"""The modules setup.py compiles (a test checks that both lists agree)."""

_PACKAGE_DIR: Final = Path(__file__).resolve().parent
_SHARED_LIB: Final = "_core__mypyc"


class BuildInfo:
    """What :func:`build_info` reports: ``build`` is ``"compiled"`` or ``"pure"``, ``reason`` says why
    the pure build runs (``""`` for the compiled one)."""

    __slots__ = ("build", "reason")

    def __init__(self, build: str, reason: str) -> None:
        self.build = build
        self.reason = reason

    @property
    def compiled(self) -> bool:
        """Whether the mypyc-compiled core runs."""
        return self.build == "compiled"

    def describe(self) -> str:
        """One phrase for a banner: ``compiled (mypyc)`` or ``pure Python (why)``."""
        return "compiled (mypyc)" if self.compiled else f"pure Python ({self.reason})"

    def as_dict(self) -> dict[str, str]:
        """``{"build": ..., "reason": ...}``, for a JSON summary."""
        return {"build": self.build, "reason": self.reason}

    def __repr__(self) -> str:
        return f"BuildInfo(build={self.build!r}, reason={self.reason!r})"


class _SourceFinder(importlib.abc.MetaPathFinder):
    """Loads the compiled modules from their ``.py`` sources, ahead of the extension finder."""

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None,
        target: ModuleType | None = None,
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname not in _COMPILED_SET:
            return None
        leaf = fullname.rpartition(".")[2] + ".py"
        for entry in path or ():
            candidate = os.path.join(entry, leaf)
            if os.path.isfile(candidate):
                return importlib.util.spec_from_file_location(fullname, candidate)
        return None


_COMPILED_SET: Final = frozenset(COMPILED_MODULES)


def _shared_library() -> Path | None:
    for candidate in _PACKAGE_DIR.glob(_SHARED_LIB + ".*"):
        if candidate.suffix in (".so", ".pyd"):
            return candidate
    return None


def _stale_source(library: Path) -> str | None:
    """In a checkout (setup.py beside the package) built in place: a compiled source edited after
    the build, else ``None``. Installed packages are never judged stale."""
    if not (_PACKAGE_DIR.parent / "setup.py").is_file():
        return None
    built = library.stat().st_mtime
    for name in COMPILED_MODULES:
        source = _PACKAGE_DIR.parent.joinpath(*name.split(".")).with_suffix(".py")
        try:
            if source.stat().st_mtime > built:
                return str(source.relative_to(_PACKAGE_DIR.parent))
        except OSError:
            continue
    return None


def _choose() -> BuildInfo:
    library = _shared_library()
    if pure_requested():
        reason = f"{PURE_ENV} is set"
    elif library is None:
        reason = "no compiled extensions: installed without a C compiler, or with TDTP_PURE_BUILD"
    else:
        stale = _stale_source(library)
        if stale is None:
            return BuildInfo("compiled", "")
        reason = f"the compiled core is older than {stale}; run `make build` to recompile"
        warnings.warn(f"tdtp: {reason}", RuntimeWarning, stacklevel=3)
    if library is not None:
        sys.meta_path.insert(0, _SourceFinder())
    return BuildInfo("pure", reason)


_INFO: Final = _choose()


def build_info() -> BuildInfo:
    """Which build of the core runs in this process, and why."""
    if _INFO.compiled:
        connection = sys.modules.get("tdtp.session.connection")
        origin = getattr(connection, "__file__", None) or ""
        if origin.endswith(".py"):  # the shared library is there, this module's extension is not
            return BuildInfo("pure", "the compiled extensions are incomplete; reinstall tdtp")
    return _INFO


_CLASS_DOC: Final = re.compile(
    r'^class (\w+)\b[^\n]*:\n(?:    #[^\n]*\n)*    ([rRbBuU]?(?:"""|\'\'\').*?(?:"""|\'\'\'))',
    re.M | re.S,
)
"""A top-level class and the string literal that opens its body: its docstring."""


def restore_class_docstrings(modules: Sequence[str] = COMPILED_MODULES) -> int:
    """Give the classes of the compiled modules their docstrings back, from the ``.py`` beside them.

    mypyc drops docstrings. setup.py writes those of the functions, methods, properties and
    native classes into the compiled tables as it builds; the classes mypyc leaves plain Python
    (``mypyc_attr(native_class=False)``, dataclasses, enums) get ``"mypyc filler docstring"``, so
    ``help(tdtp.DataReceived)`` would say nothing in the compiled build. A scan of the sources (a
    regular expression, not a parse: about a millisecond for the whole core) puts theirs back (and
    any a build missed). Returns how many classes got theirs; does nothing in the pure build, where
    Python kept them.
    """
    if not _INFO.compiled:
        return 0
    restored = 0
    for name in modules:
        module = sys.modules.get(name)
        origin = getattr(module, "__file__", None) or ""
        if module is None or origin.endswith(".py"):
            continue
        source = _PACKAGE_DIR.parent.joinpath(*name.split(".")).with_suffix(".py")
        try:
            text = source.read_text(encoding="utf-8")
        except OSError:  # an install without sources beside the extensions: nothing to restore
            continue
        for match in _CLASS_DOC.finditer(text):
            cls = getattr(module, match.group(1), None)
            if isinstance(cls, type) and (not cls.__doc__ or cls.__doc__.startswith("mypyc")):
                try:
                    cls.__doc__ = ast.literal_eval(match.group(2))
                    restored += 1
                except (ValueError, SyntaxError, TypeError, AttributeError):
                    continue
    return restored
