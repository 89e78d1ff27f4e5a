"""Loading tdtp's optional plain-C extensions: the one loader, low enough for the core to use.

Two small C extensions sit beside the mypyc-compiled core, each with a pure-Python fallback:
``tdtp.aio._datagram`` (the batched datagram engine) and ``tdtp.session._slot_filler`` (builds each
``DataReceived`` straight into its slots). :func:`load_extension` decides, for either, whether it runs.
This module imports nothing of tdtp, so the sans-IO core may import it without reaching up to the
package face (:mod:`tdtp._build`, which decides which build of the core runs, imports from here).
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from types import ModuleType
from typing import Final

__all__ = ["PURE_ENV", "load_extension", "pure_requested"]

PURE_ENV: Final = "TDTP_PURE_PYTHON"
"""Set to a non-empty value other than ``0`` to run the pure-Python modules although extensions exist."""

_CHECKOUT: Final = Path(__file__).resolve().parent.parent
"""The directory holding the package: a checkout when ``setup.py`` is there too."""


def pure_requested() -> bool:
    """Whether ``TDTP_PURE_PYTHON`` asks for the pure-Python build in this process."""
    return os.environ.get(PURE_ENV, "") not in ("", "0")


def load_extension(name: str, source: Path) -> tuple[ModuleType | None, str]:
    """One of tdtp's optional plain-C extensions (built by setup.py beside the mypyc core, e.g. the
    datagram engine): the module, or ``None`` and why not. Not with ``TDTP_PURE_PYTHON=1``, not
    where it was not built, and not in a checkout whose ``source`` was edited after the build (as
    for the core, stale machine code would silently ignore the edit)."""
    if pure_requested():
        return None, f"{PURE_ENV} is set"
    try:
        module = importlib.import_module(name)  # optional: setup.py builds it
    except ImportError:
        return None, "the C extension is not built: no C compiler, or TDTP_PURE_BUILD"
    library = getattr(module, "__file__", None) or ""
    try:
        stale = (_CHECKOUT / "setup.py").is_file() and (
            source.stat().st_mtime > Path(library).stat().st_mtime
        )
    except OSError:
        stale = False
    if stale:
        where = source.resolve().relative_to(_CHECKOUT) if source.is_absolute() else source
        return None, f"the C extension is older than {where.as_posix()}; run `make build`"
    return module, ""
