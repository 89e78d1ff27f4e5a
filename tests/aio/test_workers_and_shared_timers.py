"""Sessions at scale: SO_REUSEPORT servers sharing one port, one timer per loop for every endpoint,
and one wake-up per tick for every ticker of a rate."""

from __future__ import annotations

import asyncio
import math
import socket

import pytest

from tdtp import AddressError, ArgumentTypeError, Ticker
from tdtp.aio.api import connect, listen
from tdtp.aio.loop_timers import loop_timers, tick_group
from tdtp.aio.timer import monotonic as tdtp_monotonic

needs_reuseport = pytest.mark.skipif(
    not hasattr(socket, "SO_REUSEPORT"), reason="SO_REUSEPORT is not available here"
)


@needs_reuseport
@pytest.mark.asyncio
async def test_servers_sharing_a_port_take_every_master_between_them() -> None:
    first = await listen("127.0.0.1", 0, reuse_port=True)
    second = await listen("127.0.0.1", first.port, reuse_port=True)
    masters = [await connect("127.0.0.1", first.port) for _ in range(6)]
    try:
        for ep in masters:
            ep.send(b"hello")
        # Each master landed on one of the two (the kernel picks by its address), and a session
        # lives entirely in the server that took its OPEN.
        assert len(first.endpoints) + len(second.endpoints) == len(masters)
        for ep in masters:
            assert ep.established and not ep.is_closed
    finally:
        for ep in masters:
            await ep.close()
        await first.close()
        await second.close()


@needs_reuseport
@pytest.mark.asyncio
async def test_a_port_taken_without_reuse_port_stays_taken() -> None:
    async with listen("127.0.0.1", 0) as first:
        with pytest.raises(AddressError, match="in use"):
            await listen("127.0.0.1", first.port, reuse_port=True)


def test_reuse_port_must_be_a_bool() -> None:
    with pytest.raises(ArgumentTypeError, match="reuse_port"):
        listen("127.0.0.1", 0, reuse_port="yes")  # type: ignore[arg-type]


@pytest.mark.asyncio
async def test_endpoints_of_a_loop_share_one_timer() -> None:
    loop = asyncio.get_running_loop()
    async with listen("127.0.0.1", 0) as server:
        masters = [await connect("127.0.0.1", server.port) for _ in range(4)]
        timers = loop_timers(loop)
        # Four masters and their four slave endpoints: one timer, eight entries.
        assert timers.entries == 8
        for ep in masters:
            assert ep.timer_kind == timers.kind
        for ep in masters:
            await ep.close()
        await server.close()
        assert timers.entries == 0  # released with the last endpoint


@pytest.mark.asyncio
async def test_tickers_of_one_rate_wake_together() -> None:
    loop = asyncio.get_running_loop()
    ticks: list[list[int]] = [[], [], []]
    groups = set()

    async def run(record: list[int]) -> None:
        async for index in Ticker(500.0):
            groups.add(tick_group(loop, 500.0))
            record.append(index)
            if len(record) == 20:
                return

    await asyncio.gather(*(run(record) for record in ticks))
    assert len(groups) == 1  # one schedule for the three
    (group,) = groups
    assert group.members == 0  # each left it when its loop ended
    for record in ticks:
        assert record == sorted(record) and len(record) == 20  # (or skipped, and counted)
    # At most one wake-up per tick for all three, where a timer each would have taken three.
    assert group.wakeups <= max(max(record) for record in ticks) + 1


@pytest.mark.asyncio
async def test_a_ticker_says_when_its_tick_was_due() -> None:
    for ticker in (Ticker(500.0), Ticker(500.0, start=tdtp_monotonic())):
        assert math.isnan(ticker.deadline)
        previous = None
        async for index in ticker:
            # Never early, and on the schedule: one period after the tick before (or more, for
            # ticks skipped after a stall).
            assert tdtp_monotonic() >= ticker.deadline
            if previous is not None:
                assert ticker.deadline - previous[1] == pytest.approx(
                    (index - previous[0]) * ticker.period
                )
            previous = (index, ticker.deadline)
            if index >= 5:
                break
