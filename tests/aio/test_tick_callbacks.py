"""Tick callbacks (``Ticker.call_each``): the loop's tick group calls every session's callback in
one wake-up, on the same schedule and with the same accounting as ``async for``; and the group's
spin window (``Ticker(spin=)``). What is checked is what the run recorded (which calls came in which
wake-up, at what time against which deadline), never how many ticks the wall clock allowed."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from tdtp import InvalidArgumentError, Ticker, TickHandle
from tdtp.aio.loop_timers import tick_group
from tdtp.aio.timer import monotonic

CALLS = 10


class Recorder:
    """One ticker's callback: the ticks it got, the group wake-up each came in, whether it came
    at or after its deadline; ``done`` once it has had ``CALLS``."""

    def __init__(self, ticker: Ticker, rate: float, spin: float = 0.0) -> None:
        self.ticker = ticker
        self.loop = asyncio.get_running_loop()
        self.group = tick_group(self.loop, rate, "auto", spin) if ticker._start is None else None
        self.ticks: list[int] = []
        self.wakeups: list[int] = []
        self.early: list[float] = []
        self.deadlines: list[float] = []
        self.done: asyncio.Future[None] = self.loop.create_future()
        self.handle: TickHandle | None = None

    def __call__(self, tick: int) -> None:
        now = monotonic()
        if now < self.ticker.deadline:
            self.early.append(self.ticker.deadline - now)
        self.ticks.append(tick)
        self.deadlines.append(self.ticker.deadline)
        if self.group is not None:
            self.wakeups.append(self.group.wakeups)
        if len(self.ticks) == CALLS and not self.done.done():
            self.done.set_result(None)


@pytest.mark.asyncio
async def test_tick_callbacks_of_one_rate_are_served_by_one_wake_up() -> None:
    recorders = [Recorder(Ticker(500.0), 500.0) for _ in range(3)]
    for recorder in recorders:
        recorder.handle = recorder.ticker.call_each(recorder)
    group = recorders[0].group
    assert group is not None and all(r.group is group for r in recorders)
    assert group.members == 3
    await asyncio.gather(*(r.done for r in recorders))
    for recorder in recorders:
        assert recorder.handle is not None
        recorder.handle.cancel()
        recorder.handle.cancel()  # idempotent
    assert group.members == 0
    assert tick_group(asyncio.get_running_loop(), 500.0) is not group  # released with the last
    for recorder in recorders:
        ticker = recorder.ticker
        ticks = recorder.ticks
        assert recorder.early == []  # never before the deadline
        assert ticks == sorted(set(ticks))
        # Every tick between the first and the last was given, or skipped after a stall and
        # counted; the deadline given with each is the group's schedule.
        assert ticks[-1] - ticks[0] + 1 == len(ticks) + ticker.skipped
        assert ticker.ticks == len(ticks) >= CALLS
        for tick, deadline in zip(ticks, recorder.deadlines, strict=True):
            assert deadline - recorder.deadlines[0] == pytest.approx(
                (tick - ticks[0]) * ticker.period
            )
    # The three had their ticks in the same wake-ups: one wake-up per tick for all of them.
    first = recorders[0]
    for other in recorders[1:]:
        common = set(first.ticks) & set(other.ticks)
        for tick in common:
            assert first.wakeups[first.ticks.index(tick)] == other.wakeups[other.ticks.index(tick)]


@pytest.mark.asyncio
async def test_a_ticker_with_a_start_calls_back_on_its_own_schedule() -> None:
    start = monotonic() + 0.005
    recorder = Recorder(Ticker(1000.0, start=start), 1000.0)
    handle = recorder.ticker.call_each(recorder)
    await recorder.done
    handle.cancel()
    assert recorder.early == []
    for tick, deadline in zip(recorder.ticks, recorder.deadlines, strict=True):
        assert deadline == pytest.approx(start + tick * 1e-3)
    assert recorder.ticks[0] == 0 or recorder.ticker.skipped > 0


@pytest.mark.asyncio
async def test_a_tick_callback_that_raises_is_reported_and_called_again() -> None:
    loop = asyncio.get_running_loop()
    errors: list[dict[str, Any]] = []
    loop.set_exception_handler(lambda _loop, context: errors.append(context))
    calls: list[int] = []
    other = Recorder(Ticker(1000.0), 1000.0)
    group = other.group
    assert group is not None
    raised_in: list[int] = []

    def failing(tick: int) -> None:
        calls.append(tick)
        if len(calls) == 1:
            raised_in.append(group.wakeups)
            raise RuntimeError("the application's bug")

    handles = [Ticker(1000.0).call_each(failing), Ticker(1000.0).call_each(other)]
    await other.done
    for handle in handles:
        handle.cancel()
    assert [type(error["exception"]) for error in errors] == [RuntimeError]
    assert len(calls) >= 2  # called again after raising
    assert raised_in[0] in other.wakeups  # and the other callback of that wake-up still ran


@pytest.mark.asyncio
async def test_a_callback_may_cancel_itself_and_a_ticker_runs_one_callback_at_a_time() -> None:
    ticker = Ticker(1000.0)
    got: list[int] = []
    stopped: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def once(tick: int) -> None:
        got.append(tick)
        handle.cancel()
        stopped.set_result(None)

    handle = ticker.call_each(once)
    with pytest.raises(InvalidArgumentError, match="already"):
        ticker.call_each(once)
    await stopped
    assert handle.cancelled and handle.ticker is ticker
    await asyncio.sleep(0.005)
    assert len(got) == 1  # no call after its own cancel
    again = Recorder(ticker, 1000.0)
    second = ticker.call_each(again)  # free again once cancelled
    await again.done
    second.cancel()


@pytest.mark.parametrize("spin", [-1e-6, 2e-3, float("nan")])
def test_a_spin_window_is_within_one_period(spin: float) -> None:
    with pytest.raises(InvalidArgumentError, match="spin"):
        Ticker(1000.0, spin=spin)


@pytest.mark.asyncio
async def test_a_spinning_group_never_fires_early_and_spins_at_most_its_window() -> None:
    spin = 4e-4
    began = monotonic()
    recorder = Recorder(Ticker(1000.0, spin=spin), 1000.0, spin)
    handle = recorder.ticker.call_each(recorder)
    waiting = Ticker(1000.0, spin=spin)  # a task on the same group, woken by the same spin
    async for index in waiting:
        assert monotonic() >= waiting.deadline
        if index >= 3:
            break
    await recorder.done
    group = recorder.group
    assert group is not None and group.spin == spin
    handle.cancel()
    assert recorder.early == []
    assert 0.0 <= group.spun <= monotonic() - began
