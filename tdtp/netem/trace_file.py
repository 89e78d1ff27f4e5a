"""A recorded link capacity in Mahimahi's trace format, read from a file and checked.

A trace file has one line per **delivery opportunity**: the millisecond at which the link may deliver
one packet of up to 1500 bytes. A timestamp that repeats gives several opportunities in that
millisecond; a millisecond that does not appear has none (an outage, if many are missing). Timestamps
never decrease, and the trace **loops** at its last timestamp: the opportunity at ``t`` ms of the
trace recurs at ``t + P``, ``t + 2P``... where ``P`` is the last timestamp (so the last one must be
above zero). This is the format of Mahimahi's ``mm-link`` (``src/frontend/link_queue.cc``) and of the
traces recorded with Saturator for Sprout (Winstein et al., NSDI 2013).

:func:`load_trace` reads a file into a :class:`Trace`, an immutable schedule compared by content.
Loading is linear in the file's size (a 1000-second trace of 200 000 lines takes tens of
milliseconds) and a file already loaded, unchanged since, is not read again.
"""

from __future__ import annotations

import itertools
import operator
import os
import re
from array import array
from bisect import bisect_right
from collections import OrderedDict
from typing import Final

from tdtp.errors import InvalidArgumentError, TdtpError

__all__ = ["OPPORTUNITY_BYTES", "Trace", "TraceFileError", "load_trace"]

OPPORTUNITY_BYTES: Final = 1500
"""Bytes one delivery opportunity carries (one MTU-sized packet, as in the trace format)."""

_CACHE_SIZE: Final = 16
_cache: OrderedDict[tuple[str, int, int], Trace] = OrderedDict()
_WHITESPACE: Final = re.compile(r"\s")


class TraceFileError(TdtpError, ValueError):
    """A trace file that cannot be used: missing or unreadable, a line that is not a millisecond,
    timestamps going backwards, no opportunity at all. The message names the file (and the line)."""

    def __init__(self, message: str, *, path: str, line: int | None = None) -> None:
        super().__init__(message)
        self.path = path
        """The file, as given."""
        self.line = line
        """1-based number of the offending line, when one is to blame."""


class Trace:
    """The delivery opportunities of one recorded link: ``times`` in milliseconds, looping at
    :attr:`period_ms`. Build one with :func:`load_trace`; equal traces have equal paths and times."""

    __slots__ = ("_hash", "_times", "path", "period_ms")

    def __init__(self, path: str, times: array[int]) -> None:
        if _WHITESPACE.search(path) or not path:
            raise InvalidArgumentError(
                f"a trace's path must be non-empty and have no whitespace (netem syntax separates "
                f"options by spaces), got {path!r}: move or link the file to a plain path"
            )
        if not times:
            raise TraceFileError(f"trace file {path!r} has no opportunity (no line)", path=path)
        if times[-1] <= 0:
            raise TraceFileError(
                f"trace file {path!r} lasts no time: its last timestamp must be above 0 ms (the "
                "trace loops there)",
                path=path,
                line=len(times),
            )
        self.path: Final = path
        """The file the trace was read from, as given (relative paths stay relative)."""
        self._times = times
        self.period_ms: Final[int] = times[-1]
        """The trace loops here: its last timestamp, in milliseconds."""
        self._hash = hash((path, len(times), times[0], times[-1], times[len(times) // 2]))

    def __len__(self) -> int:
        """Delivery opportunities in one period."""
        return len(self._times)

    def time_ms(self, index: int) -> int:
        """Millisecond of the ``index``-th opportunity, counting on through the loops (index >= 0)."""
        loops, i = divmod(index, len(self._times))
        return loops * self.period_ms + self._times[i]

    def first_after(self, ms: float) -> int:
        """Index of the first opportunity strictly after millisecond ``ms`` (>= 0) of the trace."""
        loops = int(ms // self.period_ms)
        i = bisect_right(self._times, ms - loops * self.period_ms)
        return loops * len(self._times) + i  # i == len means the next loop's first: same index

    def opportunities_between(self, start_ms: float, end_ms: float) -> int:
        """Opportunities with a time in ``(start_ms, end_ms]`` of the trace (both >= 0)."""
        if end_ms <= start_ms:
            return 0
        return self.first_after(end_ms) - self.first_after(start_ms)

    @property
    def mean_rate_bps(self) -> float:
        """The trace's capacity averaged over one period, in bits per second."""
        return len(self._times) * OPPORTUNITY_BYTES * 8 * 1000.0 / self.period_ms

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Trace):
            return NotImplemented
        return self.path == other.path and self._times == other._times

    def __hash__(self) -> int:
        return self._hash

    def __repr__(self) -> str:
        return (
            f"Trace({self.path!r}, {len(self._times)} opportunities over {self.period_ms} ms, "
            f"{self.mean_rate_bps / 1e6:.2f} Mbit/s)"
        )


def _parse(path: str, text: str) -> array[int]:
    lines = text.split("\n")
    while lines and not lines[-1].strip():
        lines.pop()  # a file ending with newlines is fine; blank lines inside are not
    try:
        times = array("q", map(int, lines))
    except (ValueError, OverflowError):
        times = None
    if times is None or (times and min(times) < 0):
        bad = next(n for n, line in enumerate(lines, 1) if not _is_millisecond(line))
        shown = lines[bad - 1].strip()
        what = "an empty line" if not shown else repr(shown[:40])
        raise TraceFileError(
            f"line {bad} of trace file {path!r} is {what}: each line must be a whole number of "
            "milliseconds (one delivery opportunity)",
            path=path,
            line=bad,
        )
    if not all(map(operator.le, times, itertools.islice(times, 1, None))):
        n = next(n for n in range(1, len(times)) if times[n] < times[n - 1])
        raise TraceFileError(
            f"line {n + 1} of trace file {path!r} goes back in time ({times[n]} ms after "
            f"{times[n - 1]} ms): timestamps must never decrease",
            path=path,
            line=n + 1,
        )
    return times


def _is_millisecond(line: str) -> bool:
    text = line.strip()
    return text.isdigit() and text.isascii()


def load_trace(path: str | os.PathLike[str]) -> Trace:
    """Read a Mahimahi trace file. :class:`TraceFileError` says what is wrong with it."""
    name = os.fspath(path)
    if not isinstance(name, str):
        raise InvalidArgumentError(f"a trace's path must be text, got {name!r}")
    try:
        info = os.stat(name)
        key = (os.path.abspath(name), info.st_mtime_ns, info.st_size)
        cached = _cache.get(key)
        if cached is not None and cached.path == name:
            _cache.move_to_end(key)
            return cached
        with open(name, encoding="ascii", errors="replace") as file:
            text = file.read()
    except FileNotFoundError:
        raise TraceFileError(f"trace file {name!r} does not exist", path=name) from None
    except IsADirectoryError:
        raise TraceFileError(f"trace file {name!r} is a directory", path=name) from None
    except OSError as exc:
        raise TraceFileError(
            f"trace file {name!r} cannot be read: {exc.strerror or exc}", path=name
        ) from None
    trace = Trace(name, _parse(name, text))
    _cache[key] = trace
    while len(_cache) > _CACHE_SIZE:
        _cache.popitem(last=False)
    return trace
