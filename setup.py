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

import os
import sys

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


def _core_extensions() -> list[object]:
    try:
        from mypyc.build import mypycify  # noqa: PLC0415 - a build-time dependency only
    except ImportError:
        _warn("mypyc is not installed")
        return []
    try:
        return list(mypycify(COMPILED, opt_level="3", group_name=GROUP))
    except (Exception, SystemExit) as exc:  # mypyc exits when its type check fails
        _warn(f"mypyc could not prepare the core ({exc!r})")
        return []


setup(ext_modules=_extensions(), cmdclass={"build_ext": OptionalBuildExt})
