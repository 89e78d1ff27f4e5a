"""The old import paths of modules that moved in 0.2.0, kept working for one release with a warning.

tdtp 0.2.0 (the release after 0.1.0) gathered the modules that used to lie loose in the package into packages named for what
they hold (CHANGELOG.md, docs/ARCHITECTURE.md). ``import tdtp.connection`` and
``from tdtp.events import DataReceived`` still work: a finder on ``sys.meta_path`` answers each old name
with the module at its new place (the same module object, so ``isinstance`` checks and monkeypatching
behave) and emits a :class:`DeprecationWarning` naming the new path. The names exported by ``tdtp``
itself (``tdtp.Connection``, ``tdtp.DataReceived``, ...) did not move and give no warning.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from collections.abc import Sequence
from types import ModuleType
from typing import Final

__all__ = ["MOVED_MODULES", "install"]

MOVED_MODULES: Final = {
    "tdtp.connection": "tdtp.session.connection",
    "tdtp.events": "tdtp.session.events",
    "tdtp.stats": "tdtp.session.stats",
    "tdtp.sent_log": "tdtp.session.sent_log",
    "tdtp.receive_window": "tdtp.session.receive_window",
    "tdtp.rtt": "tdtp.session.rtt",
    "tdtp.loss_rate": "tdtp.session.loss_rate",
    "tdtp.cli_keys": "tdtp.cli.keys",
    "tdtp.cli_summary": "tdtp.cli.summary",
    "tdtp.cli_parser": "tdtp.cli.parser",
    "tdtp.bandwidth_cli": "tdtp.cli.bandwidth",
    "tdtp.live_stats": "tdtp.cli.live_stats",
    "tdtp.sim.cli": "tdtp.cli.simulate",
    "tdtp.haptic_sample": "tdtp.teleop.haptic_sample",
    "tdtp.bandwidth": "tdtp.analysis.bandwidth",
    "tdtp.pcap": "tdtp.capture.pcap",
}
"""Old module name -> new module name. (``tdtp.cli`` is now a package; ``tdtp.cli.main`` holds ``main``.)"""

REMOVED_IN: Final = "0.3.0"


class _AliasLoader(importlib.abc.Loader):
    """Loads an old name as the module that now lives under the new one."""

    def __init__(self, new: str) -> None:
        self._new = new

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        warnings.warn(
            f"{spec.name} moved to {self._new}; import it from there "
            f"(the old path goes away in tdtp {REMOVED_IN})",
            DeprecationWarning,
            stacklevel=2,
        )
        return importlib.import_module(self._new)

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the module was executed when it was imported under its new name."""


class _MovedModuleFinder(importlib.abc.MetaPathFinder):
    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None,
        target: ModuleType | None = None,
    ) -> importlib.machinery.ModuleSpec | None:
        new = MOVED_MODULES.get(fullname)
        if new is None:
            return None
        return importlib.machinery.ModuleSpec(fullname, _AliasLoader(new))


_FINDER: Final = _MovedModuleFinder()


def install() -> None:
    """Put the finder on ``sys.meta_path`` (once; ``tdtp/__init__.py`` calls this)."""
    if _FINDER not in sys.meta_path:
        sys.meta_path.append(_FINDER)
