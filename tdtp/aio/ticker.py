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
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import AsyncIterator, Callable

from tdtp.aio.loop_timers import TickGroup, tick_group
from tdtp.aio.timer import DeadlineTimer, create_timer, monotonic
from tdtp.errors import InvalidArgumentError


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
    ) -> None:
        if not (0.0 < rate < math.inf):
            raise InvalidArgumentError(
                f"rate must be a positive, finite number of ticks per second, got {rate!r}"
            )
        if max_catch_up < 0:
            raise InvalidArgumentError(f"max_catch_up must be >= 0, got {max_catch_up}")
        self.rate = rate
        self.period = 1.0 / rate
        self._start = start
        self._max_catch_up = max_catch_up
        self._timer_kind = timer
        self.ticks = 0
        """Ticks delivered so far."""
        self.skipped = 0
        """Ticks dropped after stalls longer than ``max_catch_up`` periods."""
        self.max_lateness = 0.0
        """Largest delay between a deadline and the moment its tick was delivered, seconds."""
        self.deadline = math.nan
        """When the tick last delivered was due (``tdtp.monotonic`` seconds; NaN before the first):
        ``monotonic() - ticker.deadline`` is how late the application runs it."""

    def __aiter__(self) -> AsyncIterator[int]:
        return self._run() if self._start is not None else self._run_grouped()

    async def _run(self) -> AsyncIterator[int]:
        loop = asyncio.get_running_loop()
        waiter: asyncio.Future[None] | None = None

        def wake() -> None:
            if waiter is not None and not waiter.done():
                waiter.set_result(None)

        timer: DeadlineTimer = create_timer(loop, wake, prefer=self._timer_kind)
        start = monotonic() if self._start is None else self._start
        period = self.period

        def deadline_of(tick: int) -> float:
            return start + tick * period

        index = 0
        try:
            while True:
                deadline = deadline_of(index)
                now = monotonic()
                if now < deadline:
                    waiter = loop.create_future()
                    timer.arm(deadline)
                    await waiter
                    now = monotonic()
                index = self._deliver(now, index, deadline_of)
                yield index
                index += 1
        finally:
            timer.close()

    async def _run_grouped(self) -> AsyncIterator[int]:
        """The same schedule rules on the loop's shared tick group for this rate."""
        group: TickGroup = tick_group(asyncio.get_running_loop(), self.rate, self._timer_kind)
        group.join()
        try:
            first = group.current_tick(monotonic())

            def deadline_of(tick: int) -> float:
                return group.deadline(first + tick)

            # The common tick inline (a slave runs one of these per master, every period): the
            # same deadline as group.deadline() to the bit, the same accounting as _deliver().
            anchor, period, rate = group.anchor, group.period, self.rate
            catch_up = self._max_catch_up
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
                    index = self._deliver(now, index, deadline_of)
                else:
                    if late > self.max_lateness:
                        self.max_lateness = late
                    self.ticks += 1
                    self.deadline = deadline
                yield index
                index += 1
        finally:
            group.leave()

    def _deliver(self, now: float, index: int, deadline_of: Callable[[int], float]) -> int:
        """Account for tick ``index`` delivered at ``now`` (both schedules' rules): after a stall
        of more than ``max_catch_up`` periods, skip to the tick due now. Returns the tick given."""
        deadline = deadline_of(index)
        behind = int((now - deadline) * self.rate)
        if behind > self._max_catch_up:
            self.skipped += behind
            index += behind
            deadline = deadline_of(index)
        self.max_lateness = max(self.max_lateness, now - deadline)
        self.ticks += 1
        self.deadline = deadline
        return index
