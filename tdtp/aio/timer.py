"""Precise one-shot deadline timers for asyncio, on the stock event loop and on uvloop.

The asyncio adapter keeps one timer armed at the sans-IO core's next deadline
(:meth:`tdtp.Connection.get_timer`). At 1 kHz the ordinary asyncio timers are not good enough: the
stock loop's ``epoll`` timeouts and libuv's timers are whole milliseconds, so a 1 ms period comes
out with deviations up to about 1 ms, and ``loop.call_at`` can even fire early (CPython #127859,
uvloop #233).

Two implementations share the :class:`DeadlineTimer` interface; :func:`create_timer` picks one:

``timerfd`` (:class:`TimerfdTimer`, Linux)
    A ``timerfd`` on ``CLOCK_MONOTONIC`` armed with an *absolute* deadline in nanoseconds
    (``TFD_TIMER_ABSTIME``) and watched with ``loop.add_reader``. The kernel wakes the loop at the
    deadline, so there is no spinning and no millisecond rounding; the loop sleeps in ``epoll_wait``
    until then. ``os.timerfd_create`` is used where it exists (Python 3.13+), ``ctypes`` on libc
    otherwise.

``call_at`` (:class:`CallAtTimer`, anywhere)
    ``loop.call_at`` converted to ``loop.time()``, optionally aimed a *spin window* before the
    deadline and finished by ``call_soon`` polling of the clock. By default it does not spin: its
    timing is then plain ``call_at``'s (up to ~1 ms late on millisecond loops) but never early. A
    1.2 ms window (:data:`PRECISE_SPIN_WINDOW`) gives microsecond precision for about a full core at
    1 kHz. See :class:`CallAtTimer` for the measurements behind that default.

Both invoke the callback only once ``monotonic() >= deadline``: a wake-up before the deadline (early
``call_at``, spurious readiness, a rounding nanosecond) re-arms for the remainder instead.

The clock
    Deadlines are absolute times on :func:`monotonic`, which is :func:`time.monotonic`
    (``CLOCK_MONOTONIC`` on Linux, the clock ``timerfd`` counts on). ``loop.time()`` is not used as
    the reference because it depends on the loop: uvloop's is libuv's cached millisecond clock,
    refreshed once per loop iteration (uvloop #359), so deadlines computed from it are up to a
    millisecond stale. One loop-independent nanosecond clock lets the sans-IO core see the same
    times on either loop.

Timers are not thread-safe: create, arm and close them on the loop's thread.
"""

from __future__ import annotations

import abc
import asyncio
import contextlib
import math
import os
import sys
import time
import warnings
from collections.abc import Callable
from typing import Final, Literal, get_args

from tdtp.errors import InvalidArgumentError, TdtpError

__all__ = [
    "DEFAULT_SPIN_WINDOW",
    "PRECISE_SPIN_WINDOW",
    "CallAtTimer",
    "DeadlineTimer",
    "TimerClosedError",
    "TimerPreference",
    "TimerUnavailableError",
    "TimerfdTimer",
    "check_timer_preference",
    "create_timer",
    "monotonic",
    "timerfd_unavailable_reason",
]

#: :class:`CallAtTimer`'s default spin window (seconds before the deadline at which it stops
#: sleeping and polls the clock): none. Spinning buys precision at the price of about a core.
DEFAULT_SPIN_WINDOW = 0.0

#: A spin window that makes :class:`CallAtTimer` precise on millisecond loops (stock Linux asyncio,
#: uvloop), whose timers wake up to about 1 ms late: p99 ~3 us, at ~100 % of a core at 1 kHz.
PRECISE_SPIN_WINDOW = 1.2e-3

# Spin windows above this are a configuration mistake (they would poll for most of a period).
_MAX_SPIN_WINDOW = 0.05

# Deadlines are clamped to this many seconds (68 years of uptime), which fits a 32-bit time_t.
_MAX_TIMERFD_SECONDS = (1 << 31) - 1

_NS_PER_S = 1_000_000_000


#: The clock deadlines are on: :func:`time.monotonic` itself, in seconds (the C function, not a
#: wrapper around it: it is read once per packet on the hot paths).
#:
#: On Linux this is ``CLOCK_MONOTONIC``, the clock the ``timerfd`` counts on, so a deadline and the
#: kernel's expiry agree to the nanosecond. It is deliberately not ``loop.time()``: that belongs to
#: one loop, and uvloop's is a millisecond clock cached per iteration.
monotonic: Final[Callable[[], float]] = time.monotonic


class TimerUnavailableError(TdtpError, RuntimeError):
    """The requested timer cannot run here; use ``prefer="auto"`` or ``prefer="call_at"``."""


class TimerClosedError(TdtpError, RuntimeError):
    """The timer was closed; create a new one."""


class DeadlineTimer(abc.ABC):
    """A one-shot timer calling ``callback()`` once :func:`monotonic` reaches an absolute deadline.

    :meth:`arm` sets, moves or (with ``None``) clears the deadline; the callback runs at most once
    per arming, from the event loop, never before the deadline. The callback may re-arm the timer.
    Exceptions it raises go to the loop's exception handler. Call :meth:`close` when done.
    """

    #: Which implementation this is: ``"timerfd"`` or ``"call_at"``.
    kind: str

    def __init__(self, loop: asyncio.AbstractEventLoop, callback: Callable[[], None]) -> None:
        self._loop = loop
        self._callback = callback
        self._deadline: float | None = None
        self._closed = False

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        """The event loop the callback runs on."""
        return self._loop

    @property
    def deadline(self) -> float | None:
        """The armed deadline, or ``None`` when disarmed (including after the callback ran)."""
        return self._deadline

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` has been called."""
        return self._closed

    def arm(self, deadline: float | None) -> None:
        """Call back once ``monotonic() >= deadline``; ``None`` (or ``math.inf``) disarms.

        ``deadline`` is an absolute time on :func:`monotonic`'s clock, not a delay. It replaces any
        deadline already armed, earlier or later. Arming the deadline that is already armed is a
        no-op and costs one comparison, so the caller may re-arm after every input. A deadline in
        the past fires as soon as the loop runs. Once the callback has run, the timer is disarmed:
        arming the same deadline again schedules another call.

        Raises :class:`ValueError` for NaN and :class:`RuntimeError` once the timer is closed.
        """
        if deadline == self._deadline:
            return
        if self._closed:
            raise TimerClosedError("the timer is closed; create a new one")
        if deadline is None or deadline == math.inf:
            if self._deadline is not None:
                self._deadline = None
                self._disarm()
            return
        if math.isnan(deadline):
            raise InvalidArgumentError(
                "deadline is NaN; pass an absolute time on tdtp.aio.timer.monotonic()"
            )
        self._deadline = deadline
        self._schedule(deadline)

    def close(self) -> None:
        """Disarm for good and release the file descriptor or loop handle. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._deadline = None
        self._release()

    def _expired(self) -> None:
        """Called by the implementation when it believes the deadline has passed."""
        deadline = self._deadline
        if deadline is None:
            return
        if time.monotonic() < deadline:
            # Woken early (call_at rounding, a stale uvloop clock, a rounded nanosecond): wait more.
            self._schedule(deadline)
            return
        self._deadline = None
        self._callback()

    @abc.abstractmethod
    def _schedule(self, deadline: float) -> None:
        """Make the implementation call :meth:`_expired` at (or before) ``deadline``."""

    @abc.abstractmethod
    def _disarm(self) -> None:
        """Cancel whatever :meth:`_schedule` set up."""

    @abc.abstractmethod
    def _release(self) -> None:
        """Free the implementation's resources (the timer is already disarmed)."""

    def __repr__(self) -> str:
        state = "closed" if self._closed else f"deadline={self._deadline!r}"
        return f"<{type(self).__name__} kind={self.kind!r} {state}>"


# --- timerfd ------------------------------------------------------------------------------------

# CLOCK_MONOTONIC is 1 and TFD_TIMER_ABSTIME is 1 on every Linux architecture; TFD_NONBLOCK and
# TFD_CLOEXEC are defined as O_NONBLOCK and O_CLOEXEC, which differ between architectures.
_CLOCK_MONOTONIC = 1
_TFD_TIMER_ABSTIME = 1


class _TimerfdApi(abc.ABC):
    """``timerfd_create`` and absolute ``timerfd_settime`` with nanosecond deadlines."""

    @abc.abstractmethod
    def create(self) -> int:
        """A new non-blocking, close-on-exec timerfd on ``CLOCK_MONOTONIC``; raises OSError."""

    @abc.abstractmethod
    def absolute_setter(self, fd: int) -> Callable[[int], None]:
        """A function arming ``fd`` to expire once at ``deadline_ns`` (0 disarms)."""


if sys.version_info >= (3, 13):

    class _OsTimerfdApi(_TimerfdApi):
        """The :mod:`os` functions added in Python 3.13."""

        def create(self) -> int:
            return os.timerfd_create(time.CLOCK_MONOTONIC, flags=os.TFD_NONBLOCK | os.TFD_CLOEXEC)

        def absolute_setter(self, fd: int) -> Callable[[int], None]:
            def set_absolute(deadline_ns: int) -> None:
                os.timerfd_settime_ns(fd, flags=os.TFD_TIMER_ABSTIME, initial=deadline_ns)

            return set_absolute


class _CtypesTimerfdApi(_TimerfdApi):
    """libc's ``timerfd_create``/``timerfd_settime`` through :mod:`ctypes` (Python 3.11 and 3.12).

    ``struct timespec`` is declared as two C longs: ``time_t`` is a long on 64-bit Linux, and the
    plain ``timerfd_settime`` symbol takes the 32-bit ``time_t`` on 32-bit glibc.
    """

    def __init__(self) -> None:
        # Imported here: only this path needs it, and some Python builds lack _ctypes.
        import ctypes  # noqa: PLC0415

        class Timespec(ctypes.Structure):
            _fields_ = (("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long))

        class Itimerspec(ctypes.Structure):
            _fields_ = (("it_interval", Timespec), ("it_value", Timespec))

        libc = ctypes.CDLL(None, use_errno=True)
        self._create = libc.timerfd_create  # AttributeError if libc lacks it
        self._create.argtypes = (ctypes.c_int, ctypes.c_int)
        self._create.restype = ctypes.c_int
        self._settime = libc.timerfd_settime
        self._settime.argtypes = (
            ctypes.c_int,
            ctypes.c_int,
            ctypes.POINTER(Itimerspec),
            ctypes.c_void_p,
        )
        self._settime.restype = ctypes.c_int
        self._itimerspec = Itimerspec
        self._byref = ctypes.byref
        self._get_errno = ctypes.get_errno

    def _error(self, call: str) -> OSError:
        err = self._get_errno()
        return OSError(err, f"{call}: {os.strerror(err)}")

    def create(self) -> int:
        fd = int(self._create(_CLOCK_MONOTONIC, os.O_NONBLOCK | os.O_CLOEXEC))
        if fd < 0:
            raise self._error("timerfd_create")
        return fd

    def absolute_setter(self, fd: int) -> Callable[[int], None]:
        # One spec per timer, reused for every arming (the hot path of a 1 kHz pacer). Not shared
        # between timers, which may live on loops in different threads.
        spec = self._itimerspec()
        spec_ref = self._byref(spec)
        value = spec.it_value
        settime = self._settime

        def set_absolute(deadline_ns: int) -> None:
            value.tv_sec, value.tv_nsec = divmod(deadline_ns, _NS_PER_S)
            if settime(fd, _TFD_TIMER_ABSTIME, spec_ref, None) != 0:
                raise self._error("timerfd_settime")

        return set_absolute


_api: _TimerfdApi | None = None
_unavailable_reason: str | None = None
_probed = False


def _load_api() -> _TimerfdApi:
    if sys.version_info >= (3, 13) and hasattr(os, "timerfd_create"):
        return _OsTimerfdApi()
    return _CtypesTimerfdApi()


def timerfd_unavailable_reason() -> str | None:
    """Why :class:`TimerfdTimer` cannot be used here, or ``None`` when it can.

    The first call probes by creating (and closing) one timerfd, which also catches kernels or
    sandboxes (seccomp) that refuse the syscall; the answer is cached.
    """
    global _api, _unavailable_reason, _probed  # noqa: PLW0603 - a process-wide, probe-once cache
    if _probed:
        return _unavailable_reason
    reason: str | None = None
    if not sys.platform.startswith("linux"):
        reason = f"timerfd is Linux-only (this is {sys.platform})"
    else:
        try:
            api = _load_api()
            os.close(api.create())
        except (ImportError, AttributeError, OSError) as exc:
            reason = f"timerfd_create is not usable: {exc}"
        else:
            _api = api
    _unavailable_reason = reason
    _probed = True
    return reason


def _deadline_ns(deadline: float) -> int:
    """``deadline`` in whole nanoseconds, rounded up so the kernel never expires before it.

    0 would disarm an absolute timerfd, so past deadlines become 1 ns (long past: fires at once).
    """
    if deadline <= 0.0:
        return 1
    if deadline >= _MAX_TIMERFD_SECONDS:
        return _MAX_TIMERFD_SECONDS * _NS_PER_S
    seconds = math.floor(deadline)
    # ``deadline - seconds`` is exact; the ceiling keeps the expiry at or after the float deadline.
    return seconds * _NS_PER_S + math.ceil((deadline - seconds) * _NS_PER_S)


class TimerfdTimer(DeadlineTimer):
    """A :class:`DeadlineTimer` on a Linux ``timerfd`` watched with ``loop.add_reader``.

    Arming is one ``timerfd_settime`` syscall with an absolute ``CLOCK_MONOTONIC`` deadline (which
    also resets a pending expiry); the loop sleeps in ``epoll_wait`` until the kernel makes the fd
    readable. No spinning and no millisecond rounding. Readiness is checked with a non-blocking
    8-byte read: ``EAGAIN`` (readiness that is stale because the timer was re-armed or disarmed
    after it expired) is ignored.

    Raises :class:`TimerUnavailableError` off Linux, where the syscall is refused, or on a loop
    without ``add_reader`` (e.g. Windows' proactor loop).
    """

    kind = "timerfd"

    def __init__(self, loop: asyncio.AbstractEventLoop, callback: Callable[[], None]) -> None:
        super().__init__(loop, callback)
        self._fd = -1
        reason = timerfd_unavailable_reason()
        api = _api
        if reason is not None or api is None:
            raise TimerUnavailableError(
                f"the timerfd timer is unavailable: {reason or 'timerfd was not probed'}; "
                "use create_timer(..., prefer='auto') or prefer='call_at' for the portable timer"
            )
        fd = api.create()
        self._set_absolute = api.absolute_setter(fd)
        try:
            loop.add_reader(fd, self._on_readable)
        except NotImplementedError as exc:
            os.close(fd)
            raise TimerUnavailableError(
                f"the timerfd timer needs loop.add_reader, which {type(loop).__name__} lacks; "
                "use prefer='call_at'"
            ) from exc
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd

    @property
    def fd(self) -> int:
        """The timerfd's file descriptor (-1 once closed)."""
        return self._fd

    def _schedule(self, deadline: float) -> None:
        self._set_absolute(_deadline_ns(deadline))

    def _disarm(self) -> None:
        self._set_absolute(0)

    def _on_readable(self) -> None:
        try:
            os.read(self._fd, 8)
        except BlockingIOError:
            return  # re-armed or disarmed between expiry and read, or spurious readiness
        self._expired()

    def _release(self) -> None:
        fd, self._fd = self._fd, -1
        if fd < 0:
            return
        try:
            if not self._loop.is_closed():
                self._loop.remove_reader(fd)
        finally:
            os.close(fd)

    def __del__(self) -> None:
        # The loop holds the reader callback (and so this object) while it is registered; this runs
        # only once the loop let go of it, e.g. after loop.close() without timer.close().
        fd = getattr(self, "_fd", -1)
        if fd >= 0:
            self._fd = -1
            warnings.warn(f"unclosed {self!r}", ResourceWarning, stacklevel=2, source=self)
            with contextlib.suppress(OSError):
                os.close(fd)


# --- call_at fallback ----------------------------------------------------------------------------


class CallAtTimer(DeadlineTimer):
    """A portable :class:`DeadlineTimer` on ``loop.call_at``, never early, optionally spinning.

    The deadline is converted from :func:`monotonic` to ``loop.time()`` at arming and handed to
    ``loop.call_at``, aimed ``spin_window`` seconds early. From there the timer re-checks the clock
    with ``call_soon`` until the deadline passes: each check is one trip round the loop, so I/O and
    other callbacks keep running, and the callback fires within a loop iteration (a few
    microseconds) of the deadline. A wake-up before the deadline (uvloop rounds delays to the
    millisecond from a stale clock and runs delays under 0.5 ms as ``call_soon``; the stock loop
    allows its clock resolution) re-arms for the remainder instead of calling back.

    Choosing ``spin_window`` (benchmarks/pacing.py, 1 kHz, 2-core Linux VM): the stock Linux loop
    and uvloop time out in whole milliseconds, so a window below ~1 ms still leaves deviations of
    hundreds of microseconds, while 1.2 ms (:data:`PRECISE_SPIN_WINDOW`) gets p99 ~3 us but polls
    nearly all the time, ~100 % of a core. Spinning also backfires when cores are busy: the
    scheduler preempts the spinning process for whole time slices, and with two other CPU-bound
    processes on the two cores the spinning timer's p99 grew to ~5 ms against ~1.5 ms without
    spinning. Hence the default, :data:`DEFAULT_SPIN_WINDOW`, is 0: ``call_at`` timing (p50
    0.3-0.6 ms, p99 ~1 ms late), a few % CPU, never early. Pass ``PRECISE_SPIN_WINDOW`` when a core
    can be spared; loops with fine timeouts (kqueue on macOS) need only a small window. Use
    :class:`TimerfdTimer` where it exists.
    """

    kind = "call_at"

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        callback: Callable[[], None],
        *,
        spin_window: float = DEFAULT_SPIN_WINDOW,
    ) -> None:
        if not 0.0 <= spin_window <= _MAX_SPIN_WINDOW:
            raise InvalidArgumentError(
                f"spin_window must be within [0, {_MAX_SPIN_WINDOW}] s, not {spin_window}"
            )
        super().__init__(loop, callback)
        self._spin_window = spin_window
        self._handle: asyncio.Handle | None = None

    @property
    def spin_window(self) -> float:
        """Seconds before the deadline at which sleeping gives way to polling."""
        return self._spin_window

    def _schedule(self, deadline: float) -> None:
        handle = self._handle
        if handle is not None:
            handle.cancel()
        loop = self._loop
        sleep = deadline - time.monotonic() - self._spin_window
        if sleep > 0.0:
            self._handle = loop.call_at(loop.time() + sleep, self._on_wake)
        else:
            self._handle = loop.call_soon(self._on_wake)

    def _disarm(self) -> None:
        handle, self._handle = self._handle, None
        if handle is not None:
            handle.cancel()

    def _release(self) -> None:
        self._disarm()

    def _on_wake(self) -> None:
        self._handle = None
        self._expired()


# --- choice ---------------------------------------------------------------------------------------

TimerPreference = Literal["auto", "timerfd", "call_at"]
"""Which deadline timer to use: the best available, timerfd only, or the portable ``call_at``."""

_PREFERENCES: tuple[str, ...] = get_args(TimerPreference)


def check_timer_preference(prefer: object) -> None:
    """Raise at once for a misspelt preference, or for ``"timerfd"`` where timerfd cannot run
    (rather than on every connection the endpoint opens later)."""
    if not isinstance(prefer, str) or prefer not in _PREFERENCES:
        raise InvalidArgumentError(
            f"timer must be one of {', '.join(map(repr, _PREFERENCES))}, not {prefer!r}"
        )
    if prefer == "timerfd":
        reason = timerfd_unavailable_reason()
        if reason is not None:
            raise TimerUnavailableError(
                f"timerfd is unavailable here ({reason}); use timer='auto' or 'call_at'"
            )


def create_timer(
    loop: asyncio.AbstractEventLoop,
    callback: Callable[[], None],
    *,
    prefer: str = "auto",
) -> DeadlineTimer:
    """The best :class:`DeadlineTimer` for ``loop`` on this platform.

    ``prefer="auto"`` gives a :class:`TimerfdTimer` where timerfd works (Linux, a loop with
    ``add_reader``) and a :class:`CallAtTimer` otherwise; ``"timerfd"`` insists on timerfd and
    raises :class:`TimerUnavailableError` saying why it cannot; ``"call_at"`` forces the portable
    fallback.
    """
    if prefer not in _PREFERENCES:
        raise InvalidArgumentError(
            f"prefer must be one of {', '.join(map(repr, _PREFERENCES))}, not {prefer!r}"
        )
    if prefer == "call_at":
        return CallAtTimer(loop, callback)
    if prefer == "timerfd":
        return TimerfdTimer(loop, callback)
    if timerfd_unavailable_reason() is None:
        try:
            return TimerfdTimer(loop, callback)
        except TimerUnavailableError:
            pass
    return CallAtTimer(loop, callback)
