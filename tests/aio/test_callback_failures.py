"""An application's bug must not stop tdtp serving its sessions, and a forgotten close must not keep an
event loop alive: callbacks that raise are reported through the loop's exception handler and every
session (the failing one included) goes on; loops with unclosed endpoints are collected with them."""

from __future__ import annotations

import asyncio
import gc
import os
from typing import Any

import pytest

from tdtp import (
    CloseCause,
    ConnectionConfig,
    DataReceived,
    PeerResumed,
    PeerSilent,
    connect,
    listen,
)
from tdtp.aio.loop_timers import loop_timers, tick_group
from tdtp.aio.relay import start_relay
from tdtp.aio.timer import monotonic

from eventually import eventually


def _record_errors(loop: asyncio.AbstractEventLoop) -> list[dict[str, Any]]:
    errors: list[dict[str, Any]] = []
    loop.set_exception_handler(lambda _loop, context: errors.append(context))
    return errors


@pytest.mark.asyncio
async def test_a_timer_callback_that_raises_does_not_strand_the_others() -> None:
    loop = asyncio.get_running_loop()
    errors = _record_errors(loop)
    timers = loop_timers(loop)
    fired: list[str] = []

    def failing() -> None:
        fired.append("failing")
        raise RuntimeError("a bug")

    first = timers.entry(failing)
    same_wakeup = timers.entry(lambda: fired.append("same wake-up"))
    later = timers.entry(lambda: fired.append("later"))
    now = monotonic()
    first.arm(now + 0.005)
    same_wakeup.arm(now + 0.005)
    later.arm(now + 0.030)
    try:
        await eventually(lambda: "later" in fired)
        assert fired == ["failing", "same wake-up", "later"]
        assert [type(error["exception"]) for error in errors] == [RuntimeError]
    finally:
        for entry in (first, same_wakeup, later):
            entry.close()


@pytest.mark.asyncio
async def test_a_raising_on_data_callback_is_reported_and_the_samples_keep_coming() -> None:
    loop = asyncio.get_running_loop()
    errors = _record_errors(loop)
    received: list[DataReceived] = []

    def on_data(sample: DataReceived) -> None:
        received.append(sample)
        if len(received) == 1:
            raise ValueError("the application's bug")

    async with listen(on_data=on_data) as server, connect("127.0.0.1", server.port) as master:
        for index in range(20):
            master.send(b"sample %d" % index)
            await asyncio.sleep(0.002)
        # Every sample sent was delivered, or counted lost or superseded: the failure stopped none.
        await eventually(lambda: len(received) >= 2)
        await eventually(
            lambda: (
                len(received) + master.stats.packets_lost + master.stats.samples_superseded
                >= master.stats.samples_offered
            )
        )
        assert [type(error["exception"]) for error in errors] == [ValueError]
        assert "on_data callback raised" in errors[0]["message"]
        (slave,) = server.endpoints
        assert not slave.is_closed


@pytest.mark.asyncio
async def test_a_raising_watchdog_callback_leaves_the_session_watched() -> None:
    # The slave's on_watchdog raises on the first PeerSilent: the slave must still report the
    # master back, and after a second outage close at idle_timeout like any other session.
    loop = asyncio.get_running_loop()
    errors = _record_errors(loop)
    config = ConnectionConfig(silence_timeout=0.05, idle_timeout=0.5)
    seen: list[PeerSilent | PeerResumed] = []

    def on_watchdog(event: PeerSilent | PeerResumed) -> None:
        seen.append(event)
        if len(seen) == 1:
            raise RuntimeError("the application's bug")

    async with listen(config=config, on_watchdog=on_watchdog) as server:
        relay = await start_relay(("127.0.0.1", 0), ("127.0.0.1", server.port), "delay 1ms")
        try:
            master = await connect(relay.address[0], relay.address[1], config=config)
            slave = await server.accept()
            relay.change("loss 100%")
            await eventually(lambda: len(seen) == 1)
            relay.change("delay 1ms")
            await eventually(lambda: len(seen) == 2)
            assert [type(event) for event in seen] == [PeerSilent, PeerResumed]
            relay.change("loss 100%")
            closed = await asyncio.wait_for(slave.wait_closed(), 10.0)
            assert closed.cause is CloseCause.IDLE_TIMEOUT
            assert [type(error["exception"]) for error in errors] == [RuntimeError]
            await master.close()
        finally:
            await relay.close()


def test_loops_left_with_unclosed_endpoints_are_collected() -> None:
    # An exception path or a forgotten close() leaves endpoints open when asyncio.run() returns:
    # the loop, the shared timer and tick group, the endpoints and their sockets must still go.
    async def forget_to_close() -> None:
        server = await listen("127.0.0.1", 0)
        master = await connect("127.0.0.1", server.port)
        master.send(b"x")
        tick_group(asyncio.get_running_loop(), 1000.0).join()
        await asyncio.sleep(0.01)

    def open_fds() -> int:
        return len(os.listdir("/proc/self/fd"))

    asyncio.run(forget_to_close())  # the first run may open lasting descriptors (the loop's own)
    gc.collect()
    before = open_fds()
    for _ in range(3):
        asyncio.run(forget_to_close())
    gc.collect()
    loops = [obj for obj in gc.get_objects() if isinstance(obj, asyncio.AbstractEventLoop)]
    endpoints = [obj for obj in gc.get_objects() if type(obj).__name__ == "Endpoint"]
    assert loops == [] and endpoints == []
    assert open_fds() <= before
