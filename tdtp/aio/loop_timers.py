"""One deadline timer per event loop for every endpoint on it, and tick groups for the tickers.

Each endpoint wants one timer at its connection's next deadline. With one ``timerfd`` each, a process
serving 50 sessions takes 50 kernel timers, and every expiry is its own trip through ``epoll_wait``: on
a 2-core VM a wake-up costs 20-25 us of CPU, more than the protocol work of a packet. Here every endpoint
of a loop holds a :class:`TimerEntry` in one :class:`LoopTimers` heap, and a single
:class:`~tdtp.aio.timer.DeadlineTimer` is armed at the earliest deadline: deadlines that fall due
together are served in one wake-up.

The same reasoning applies to applications that sample at a fixed rate: a :class:`TickGroup` wakes once
per period for every :class:`~tdtp.aio.ticker.Ticker` of the same rate on the loop, instead of once per
ticker at scattered phases; and it calls the tickers' tick callbacks
(:meth:`~tdtp.aio.ticker.Ticker.call_each`) itself, so that serving every session due costs one wake-up
and one call per session, not one task step each. The handle of such a callback
(:class:`TickHandle`) lives here, compiled with the group: its tick is a native call.
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import math
import weakref
from collections.abc import Callable
from time import thread_time
from typing import TYPE_CHECKING, Final

from mypy_extensions import mypyc_attr

from tdtp.aio.outbox import current_outbox
from tdtp.aio.timer import DeadlineTimer, create_timer, monotonic

if TYPE_CHECKING:  # the ticker imports this module; a handle only reads and writes its attributes
    from tdtp.aio.ticker import Ticker

__all__ = [
    "LoopTimers",
    "TickGroup",
    "TickHandle",
    "TimerEntry",
    "deliver_tick",
    "loop_timers",
    "tick_group",
]

_NEVER: Final = math.inf


class TimerEntry:
    """One user's deadline in a :class:`LoopTimers` (an endpoint's connection timer).

    :attr:`deadline` is the armed deadline (``math.inf`` when disarmed, and after the callback ran).
    Like :class:`~tdtp.aio.timer.DeadlineTimer`, the callback runs once per arming, never before the
    deadline.
    """

    __slots__ = ("_callback", "_owner", "closed", "deadline")

    def __init__(self, owner: LoopTimers, callback: Callable[[], None]) -> None:
        self._owner = owner
        self._callback = callback
        self.deadline = _NEVER
        self.closed = False

    @property
    def kind(self) -> str:
        """The kind of the loop's underlying timer: ``"timerfd"`` or ``"call_at"``."""
        return self._owner.kind

    def arm(self, deadline: float | None) -> None:
        """Call back at ``deadline`` (absolute, on :func:`~tdtp.aio.timer.monotonic`); ``None`` or
        ``math.inf`` disarms. Replaces any deadline armed before."""
        if deadline is None or math.isnan(deadline):
            deadline = _NEVER
        if deadline == self.deadline or self.closed:
            return
        self.deadline = deadline
        if deadline < _NEVER:
            self._owner.push(self, deadline)

    def close(self) -> None:
        """Disarm for good; the loop's timer is released with its last entry. Idempotent."""
        if not self.closed:
            self.closed = True
            self.deadline = _NEVER
            self._owner.release()


# A plain Python class even when compiled, so that the registry below can hold it weakly: the
# registry must not keep a loop (or the endpoints on it) alive. Its work is per wake-up, not per packet.
@mypyc_attr(native_class=False)
class LoopTimers:
    """Every :class:`TimerEntry` of one event loop on one deadline timer (see the module docstring).

    Entries live in a heap of ``(deadline, order, entry)``; moving an entry's deadline pushes a new
    item and leaves the old one to be skipped when it surfaces (its deadline no longer matches), and
    the heap is rebuilt when stale items outnumber live ones.
    """

    def __init__(self, loop: asyncio.AbstractEventLoop, prefer: str) -> None:
        self._loop = loop
        self._prefer = prefer
        self._timer: DeadlineTimer = create_timer(loop, self._fire, prefer=prefer)
        self._heap: list[tuple[float, int, TimerEntry]] = []
        self._order = 0
        self._entries = 0
        self.wakeups = 0
        """Times the underlying timer fired (one for every entry that fell due together)."""

    @property
    def kind(self) -> str:
        return self._timer.kind

    @property
    def entries(self) -> int:
        """Entries not closed yet."""
        return self._entries

    def entry(self, callback: Callable[[], None]) -> TimerEntry:
        self._entries += 1
        return TimerEntry(self, callback)

    def push(self, entry: TimerEntry, deadline: float) -> None:
        self._order += 1
        heap = self._heap
        heapq.heappush(heap, (deadline, self._order, entry))
        armed = self._timer.deadline
        if armed is None or deadline < armed:
            self._timer.arm(deadline)
        if len(heap) > 64 + 4 * self._entries:
            self._compact()

    def release(self) -> None:
        self._entries -= 1
        if self._entries <= 0:
            self._timer.close()
            _forget(self._loop, self._prefer, self)

    def _compact(self) -> None:
        live = [item for item in self._heap if item[2].deadline == item[0]]
        heapq.heapify(live)
        self._heap = live

    def _fire(self) -> None:
        self.wakeups += 1
        now = monotonic()
        heap = self._heap
        due: list[TimerEntry] = []
        while heap and heap[0][0] <= now:
            deadline, _, entry = heapq.heappop(heap)
            if entry.deadline == deadline:  # not moved or disarmed since it was pushed
                entry.deadline = _NEVER
                due.append(entry)
        # Callbacks run after the heap is settled: they re-arm their entries, earlier ones first.
        # One that raises is reported and the others still run: they share this wake-up, and on
        # the batched datagram layer one sendmmsg per socket (tdtp.aio.outbox) when it ends.
        outbox = current_outbox(self._loop) if due else None
        if outbox is not None:
            outbox.hold()
        try:
            for entry in due:
                if not entry.closed:
                    try:
                        entry._callback()
                    except Exception as exc:  # reported, as asyncio reports a callback's
                        self._loop.call_exception_handler(
                            {"message": "a tdtp timer callback raised", "exception": exc}
                        )
        finally:
            if outbox is not None:
                outbox.release()
        heap = self._heap  # a callback may have compacted it
        while heap and heap[0][2].deadline != heap[0][0]:
            heapq.heappop(heap)  # stale tops, so the timer is armed at a live deadline
        if heap and not self._timer.closed:
            armed = self._timer.deadline
            if armed is None or heap[0][0] < armed:
                self._timer.arm(heap[0][0])


@mypyc_attr(native_class=False)  # held weakly by the registry, as LoopTimers
class TickGroup:
    """The ticks of every :class:`~tdtp.aio.ticker.Ticker` of one rate on one loop: deadlines
    ``anchor + n / rate`` for n = 0, 1, 2, ..., one wake-up per tick for all of them.

    Two kinds of members share the wake-up: tasks iterating a ticker (each waits on a future, so a
    tick resumes each task once, one after the other) and *tick callbacks*
    (:meth:`~tdtp.aio.ticker.Ticker.call_each`), which the wake-up calls directly, in the order they
    joined, with the loop's outbox held: no task step, no future, and what they send leaves in one
    ``sendmmsg`` per socket when the last has run.

    ``spin`` (seconds, 0 by default) arms the timer that long before each deadline and waits the
    rest on the CPU (a blocking busy-wait). A virtual CPU that idles until a deadline can be resumed
    late by its host: on this project's VM a bare 1 kHz ``timerfd`` wake-up comes more than 1 ms
    late 2-7 % of the time, and 0.3-0.5 % with the CPU kept from idling (benchmarks/HISTORY.md,
    "Why the slave's ticks are late"). Spinning costs that CPU (up to ``spin * rate`` of a core,
    less when the loop is busy anyway) and backfires when another process wants the core (the
    busy-waiting one loses its time slice): it is for a process that has a core to itself.
    :attr:`spun` counts it.
    """

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        rate: float,
        prefer: str,
        spin: float = 0.0,
        anchor: float | None = None,
    ) -> None:
        self._loop = loop
        self._key = (rate, prefer, spin)
        self.rate = rate
        self.period = 1.0 / rate
        self.spin = spin
        self.anchor = monotonic() if anchor is None else anchor
        self._timer: DeadlineTimer = create_timer(loop, self._fire, prefer=prefer)
        self._waiters: dict[int, list[asyncio.Future[None]]] = {}
        self._callbacks: list[TickHandle] = []
        self._next_tick = 0
        """The first tick the callbacks have not been served (while there are any)."""
        self._members = 0
        self.wakeups = 0
        self.spun = 0.0
        """CPU seconds spent busy-waiting for deadlines (``spin``), for an honest CPU account."""

    @property
    def members(self) -> int:
        return self._members

    def deadline(self, tick: int) -> float:
        """When tick ``tick`` is due (every member computes it this same way, to the bit)."""
        return self.anchor + tick * self.period

    def current_tick(self, now: float) -> int:
        """The last tick due at or before ``now``."""
        tick = math.floor((now - self.anchor) * self.rate)
        while self.deadline(tick + 1) <= now:
            tick += 1
        while tick > 0 and self.deadline(tick) > now:
            tick -= 1
        return max(tick, 0)

    def join(self) -> None:
        self._members += 1

    def leave(self) -> None:
        self._members -= 1
        if self._members <= 0:
            self._timer.close()
            for waiters in self._waiters.values():
                for waiter in waiters:
                    waiter.cancel()
            self._waiters.clear()
            self._callbacks.clear()
            _forget_group(self._loop, self._key, self)

    def add_callback(self, member: TickHandle, first_tick: int) -> None:
        """Call ``member.on_group_tick`` at every wake-up from ``first_tick`` on (the member has
        joined; :meth:`remove_callback` before it leaves)."""
        if not self._callbacks or first_tick < self._next_tick:
            self._next_tick = first_tick
        self._callbacks.append(member)
        self._arm_at(self.deadline(first_tick))

    def remove_callback(self, member: TickHandle) -> None:
        # A list, not a set: members are served in the order they joined. Removal is rare (a
        # session ends); the wake-up, which is not, only iterates.
        with contextlib.suppress(ValueError):
            self._callbacks.remove(member)

    def wait(self, tick: int) -> asyncio.Future[None]:
        """A future done once ``monotonic() >= deadline(tick)``."""
        waiter: asyncio.Future[None] = self._loop.create_future()
        waiters = self._waiters.get(tick)
        if waiters is None:
            self._waiters[tick] = waiters = []
        waiters.append(waiter)
        self._arm_at(self.deadline(tick))
        return waiter

    def _arm_at(self, deadline: float) -> None:
        at = deadline - self.spin
        armed = self._timer.deadline
        if (armed is None or at < armed) and not self._timer.closed:
            self._timer.arm(at)

    def _fire(self) -> None:
        self.wakeups += 1
        now = monotonic()
        callbacks = self._callbacks
        if self.spin > 0.0:
            # Woken ``spin`` before the earliest deadline pending (or later): wait for it on the
            # CPU, not asleep. Never past it: a late wake-up serves what is due at once.
            pending = [self.deadline(min(self._waiters))] if self._waiters else []
            if callbacks:
                pending.append(self.deadline(self._next_tick))
            due_at = min(pending, default=now)
            if due_at - now > self.spin:
                self._arm_at(due_at)  # woken too early (a spurious readiness): sleep on
                return
            # Counted in this thread's CPU time: the wait's wall time would also count the time
            # another process had the core meanwhile (a spinner loses its time slice).
            spent = thread_time()
            while now < due_at:
                now = monotonic()
            self.spun += thread_time() - spent
        due = [tick for tick in self._waiters if self.deadline(tick) <= now]
        outbox = current_outbox(self._loop) if due or callbacks else None
        if outbox is not None:
            outbox.hold()
        try:
            for tick in sorted(due):
                for waiter in self._waiters.pop(tick):
                    if not waiter.done():
                        waiter.set_result(None)
            if callbacks and self.deadline(self._next_tick) <= now:
                self._next_tick = self.current_tick(now) + 1
                self._run_callbacks(now)
        finally:
            if outbox is not None:
                if due:
                    # The tasks just woken run next, one after the other; what they send leaves
                    # in one sendmmsg per socket once all of them have (tdtp.aio.outbox).
                    outbox.hold_until_ready_ran(self._loop)
                outbox.release()
        if self._timer.closed:
            return
        if self._callbacks:
            self._arm_at(self.deadline(self._next_tick))
        if self._waiters:
            self._arm_at(self.deadline(min(self._waiters)))

    def _run_callbacks(self, now: float) -> None:
        # A copy: a callback may cancel itself or another, or add one (served from the next tick).
        for member in list(self._callbacks):
            try:
                member.on_group_tick(now)
            except Exception as exc:  # reported, as asyncio reports a callback's; the rest run
                self._loop.call_exception_handler(
                    {"message": "a tdtp tick callback raised", "exception": exc}
                )


class TickHandle:
    """A :meth:`Ticker.call_each` in progress: :meth:`cancel` stops it."""

    # Compiled with the group that calls it (one call per session per tick in a slave): the
    # schedule is read from the group once, and the ticker's accounting is written as
    # ``async for`` writes it.

    def __init__(
        self, ticker: Ticker, group: TickGroup, first: int, callback: Callable[[int], None]
    ) -> None:
        self._ticker = ticker
        self._group = group
        self._first = first
        self._callback = callback
        self._index = 0
        self._anchor: float = group.anchor
        self._period: float = group.period
        self._rate: float = ticker.rate
        self._max_catch_up: int = ticker.max_catch_up
        self._max_lateness: float = ticker.max_lateness  # at most the ticker's (which only grows)
        self.cancelled = False

    @property
    def ticker(self) -> Ticker:
        """The :class:`~tdtp.Ticker` whose ticks call this handle's callback."""
        return self._ticker

    def cancel(self) -> None:
        """No more calls (from now: one cancelled by another callback of the same wake-up is not
        called in it). Idempotent."""
        if not self.cancelled:
            self.cancelled = True
            self._group.remove_callback(self)
            self._group.leave()

    def _deadline_of(self, tick: int) -> float:
        return self._group.deadline(self._first + tick)

    def on_group_tick(self, now: float) -> None:
        """The group's wake-up at ``now``: every tick of ours due by then, as ``async for``
        would deliver them (a stall within ``max_catch_up`` periods gives each missed tick, a
        longer one skips to the tick due now)."""
        ticker = self._ticker
        callback = self._callback
        anchor = self._anchor
        period = self._period
        while not self.cancelled:
            index = self._index
            # = TickGroup.deadline(first + index), to the bit
            deadline = anchor + (self._first + index) * period
            if deadline > now:
                return
            late = now - deadline
            if int(late * self._rate) > self._max_catch_up:
                index = deliver_tick(ticker, now, index, self._deadline_of)
            else:
                if late > self._max_lateness:  # (read from the ticker only then)
                    self._max_lateness = late = max(late, ticker.max_lateness)
                    ticker.max_lateness = late
                ticker.ticks += 1
                ticker.deadline = deadline
            self._index = index + 1
            callback(index)


def deliver_tick(
    ticker: Ticker, now: float, index: int, deadline_of: Callable[[int], float]
) -> int:
    """Account for ``ticker``'s tick ``index`` delivered at ``now``, by the rules both of its
    schedules share (``async for`` and :class:`TickHandle`): after a stall of more than
    ``max_catch_up`` periods, skip to the tick due now (counted in ``skipped``). Returns the tick
    given. ``deadline_of(tick)`` is when the ticker's tick ``tick`` is due."""
    deadline = deadline_of(index)
    behind = int((now - deadline) * ticker.rate)
    if behind > ticker.max_catch_up:
        ticker.skipped += behind
        index += behind
        deadline = deadline_of(index)
    ticker.max_lateness = max(ticker.max_lateness, now - deadline)
    ticker.ticks += 1
    ticker.deadline = deadline
    return index


# Each loop's timers and tick groups, held weakly on both sides: a loop whose endpoints were never
# closed (an exception path, a forgotten close(), a test suite that runs asyncio.run() many times) is
# collected with them, as it would be if every endpoint had a timer of its own.
_LOOP_TIMERS: weakref.WeakKeyDictionary[
    asyncio.AbstractEventLoop, weakref.WeakValueDictionary[str, LoopTimers]
] = weakref.WeakKeyDictionary()
_TICK_GROUPS: weakref.WeakKeyDictionary[
    asyncio.AbstractEventLoop, weakref.WeakValueDictionary[tuple[float, str, float], TickGroup]
] = weakref.WeakKeyDictionary()


def loop_timers(loop: asyncio.AbstractEventLoop, prefer: str = "auto") -> LoopTimers:
    """The loop's shared timers of the preferred kind (created on first use, released with the
    last entry). Raises what :func:`~tdtp.aio.timer.create_timer` raises."""
    by_kind = _LOOP_TIMERS.get(loop)
    if by_kind is None:
        _LOOP_TIMERS[loop] = by_kind = weakref.WeakValueDictionary()
    timers = by_kind.get(prefer)
    if timers is None:
        by_kind[prefer] = timers = LoopTimers(loop, prefer)
    return timers


def tick_group(
    loop: asyncio.AbstractEventLoop, rate: float, prefer: str = "auto", spin: float = 0.0
) -> TickGroup:
    """The loop's tick group for ``rate`` (and timer kind and spin window: tickers that differ
    in those do not share; created on first use, released with its last member)."""
    groups = _TICK_GROUPS.get(loop)
    if groups is None:
        _TICK_GROUPS[loop] = groups = weakref.WeakValueDictionary()
    key = (rate, prefer, spin)
    group = groups.get(key)
    if group is None:
        groups[key] = group = TickGroup(loop, rate, prefer, spin)
    return group


def _forget(loop: asyncio.AbstractEventLoop, prefer: str, timers: LoopTimers) -> None:
    by_kind = _LOOP_TIMERS.get(loop)
    if by_kind is not None and by_kind.get(prefer) is timers:
        del by_kind[prefer]


def _forget_group(
    loop: asyncio.AbstractEventLoop, key: tuple[float, str, float], group: TickGroup
) -> None:
    groups = _TICK_GROUPS.get(loop)
    if groups is not None and groups.get(key) is group:
        del groups[key]
