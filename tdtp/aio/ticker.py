"""A periodic ticker on absolute deadlines, for applications that sample at a fixed rate.

``async for tick in Ticker(1000): ep.send(read_sensor())`` wakes at ``start + k / rate`` for k = 0, 1, 2,
... on the precise deadline timer. Deadlines never drift with wake-up lateness: 1000 ticks per second
means 1000. After a stall longer than ``max_catch_up`` periods the missed ticks are skipped and counted
(a teleoperation sample that old is worth nothing) instead of being fired in a burst.

Tickers of the same rate on one loop share their wake-ups: without ``start=``, a ticker joins the loop's
:class:`~tdtp.aio.loop_timers.TickGroup` for its rate, whose deadlines are one schedule for all of them,
so a slave that runs a 1 kHz loop per master wakes once per millisecond, not once per master at
scattered phases. Its first tick is the group's tick at or just before the moment iteration starts
(due at once, as an ungrouped ticker's first tick is). ``start=`` gives a ticker its own schedule and
timer.

Tick callbacks. ``handle = Ticker(1000).call_each(on_tick)`` calls ``on_tick(tick)`` from the group's
wake-up itself, on the same schedule and with the same accounting as iteration, until
``handle.cancel()``. A process that serves many sessions at one rate (a slave: one 1 kHz loop per
master) then pays one wake-up per period and one call per session, where ``async for`` costs a task
step per session (a future resolved, a task resumed, an async generator advanced): the calls run one
after the other inside the wake-up, with the loop's outbox held, so every session's sample leaves in
one ``sendmmsg`` and the last session's tick is not queued behind the others' task switches.

``spin=`` makes the group wait the last ``spin`` seconds before each deadline on the CPU instead of
asleep, for virtual machines whose idle CPUs are resumed late (:class:`~tdtp.aio.loop_timers.TickGroup`).
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import AsyncIterator, Callable

from tdtp.aio.loop_timers import TickGroup, TickHandle, deliver_tick, tick_group
from tdtp.aio.timer import monotonic
from tdtp.errors import InvalidArgumentError

__all__ = ["TickHandle", "Ticker"]


class Ticker:
    """``async for tick in Ticker(rate)``: tick numbers on absolute deadlines ``start + k / rate``,
    late wake-ups never drifting the schedule (see the module docstring)."""

    def __init__(
        self,
        rate: float,
        *,
        start: float | None = None,
        max_catch_up: int = 10,
        timer: str = "auto",
        spin: float = 0.0,
    ) -> None:
        if not (0.0 < rate < math.inf):
            raise InvalidArgumentError(
                f"rate must be a positive, finite number of ticks per second, got {rate!r}"
            )
        if max_catch_up < 0:
            raise InvalidArgumentError(f"max_catch_up must be >= 0, got {max_catch_up}")
        if not (0.0 <= spin <= 1.0 / rate):
            raise InvalidArgumentError(
                f"spin must be within [0, one period = {1.0 / rate}] s, got {spin!r}"
            )
        self.rate = rate
        self.period = 1.0 / rate
        self.spin = spin
        """Seconds before each deadline spent waiting on the CPU (see the module docstring)."""
        self._start = start
        self.max_catch_up = max_catch_up
        """Missed ticks given one by one after a stall; beyond them the ticker skips to the tick due."""
        self._timer_kind = timer
        self.ticks = 0
        """Ticks delivered so far."""
        self.skipped = 0
        """Ticks dropped after stalls longer than ``max_catch_up`` periods."""
        self.max_lateness = 0.0
        """Largest delay between a deadline and the moment its tick was delivered, seconds."""
        self._handle: TickHandle | None = None
        self.deadline = math.nan
        """When the tick last delivered was due (``tdtp.monotonic`` seconds; NaN before the first):
        ``monotonic() - ticker.deadline`` is how late the application runs it."""

    def __aiter__(self) -> AsyncIterator[int]:
        return self._run()

    def _join(self) -> tuple[TickGroup, int]:
        """The group this ticker's schedule is on, joined, and its tick number for our tick 0:
        the loop's shared group for the rate, whose tick due now comes first; or, with
        ``start=``, a group of its own anchored there."""
        loop = asyncio.get_running_loop()
        if self._start is None:
            group = tick_group(loop, self.rate, self._timer_kind, self.spin)
            group.join()
            return group, group.current_tick(monotonic())
        group = TickGroup(loop, self.rate, self._timer_kind, self.spin, anchor=self._start)
        group.join()
        return group, 0

    async def _run(self) -> AsyncIterator[int]:
        group, first = self._join()
        try:

            def deadline_of(tick: int) -> float:
                return group.deadline(first + tick)

            # The common tick inline (a slave runs one of these per master, every period): the
            # same deadline as group.deadline() to the bit, the same accounting as deliver_tick().
            anchor, period, rate = group.anchor, group.period, self.rate
            catch_up = self.max_catch_up
            clock = time.monotonic  # = tdtp.aio.timer.monotonic, without a call in between
            index = 0
            while True:
                deadline = anchor + (first + index) * period
                now = clock()
                if now < deadline:
                    await group.wait(first + index)
                    now = clock()
                late = now - deadline
                if int(late * rate) > catch_up:
                    index = deliver_tick(self, now, index, deadline_of)
                else:
                    if late > self.max_lateness:
                        self.max_lateness = late
                    self.ticks += 1
                    self.deadline = deadline
                yield index
                index += 1
        finally:
            group.leave()

    def call_each(self, callback: Callable[[int], None]) -> TickHandle:
        """Call ``callback(tick)`` at every tick, from the tick group's wake-up, until the
        returned handle's :meth:`~TickHandle.cancel` (see the module docstring). Ticks, deadlines
        and skips are accounted as for ``async for`` (:attr:`deadline` is the tick's during the
        call). A callback that raises is reported to the loop's exception handler and called
        again at the next tick. Call it on the loop's thread; one callback per ticker at a time
        (:class:`~tdtp.InvalidArgumentError` otherwise)."""
        if self._handle is not None and not self._handle.cancelled:
            raise InvalidArgumentError("this ticker calls a callback already; cancel it first")
        group, first = self._join()
        self._handle = handle = TickHandle(self, group, first, callback)
        group.add_callback(handle, first)
        return handle
