"""The watchdog and outages on real sockets, through the impairing relay switched to ``loss 100%``
and back (``tc qdisc change``). Nothing here asserts a count or a delay from the wall clock: each step
waits for the event the run itself reports."""

from __future__ import annotations

import asyncio

import pytest

from tdtp import (
    CloseCause,
    ConnectionConfig,
    Endpoint,
    EndpointClosedError,
    PeerResumed,
    PeerSilent,
    Ticker,
    connect,
    listen,
)
from tdtp.aio.relay import start_relay

from eventually import eventually


async def _stream(ep: Endpoint, stop: asyncio.Event) -> None:
    async for _ in Ticker(1000.0):
        if stop.is_set() or ep.is_closed:
            return
        ep.send(b"sample" + bytes(94))


@pytest.mark.asyncio
async def test_the_slave_learns_its_master_is_silent_and_back_and_the_session_survives() -> None:
    slave_events: list[PeerSilent | PeerResumed] = []
    async with listen(on_watchdog=slave_events.append) as server:
        relay = await start_relay(("127.0.0.1", 0), ("127.0.0.1", server.port), "delay 1ms")
        try:
            async with connect(relay.address[0], relay.address[1]) as master:
                slave = await server.accept()
                stop = asyncio.Event()
                streams = [
                    asyncio.create_task(_stream(master, stop)),
                    asyncio.create_task(_stream(slave, stop)),
                ]
                await eventually(lambda: slave.stats.samples_delivered >= 50)
                # A loaded machine can starve the master for a watchdog period before the outage:
                # judge only what the outage itself brings (events and silences from here on).
                await eventually(lambda: not slave.peer_silent)
                assert await slave.wait_resumed() is None  # not silent: returns at once
                before = len(slave_events)
                silences_before = slave.stats.peer_silences

                relay.change("loss 100%")  # the link goes down both ways
                silent = await asyncio.wait_for(slave.wait_silent(), 10.0)
                assert slave.peer_silent
                await eventually(lambda: master.peer_silent)
                assert [type(e) for e in slave_events[before:]] == [PeerSilent]
                assert slave_events[before] is silent
                assert silent.detected_at - silent.since >= 0.1  # never before silence_timeout

                delivered = slave.stats.samples_delivered
                relay.change("delay 1ms")  # and comes back
                resumed = await asyncio.wait_for(slave.wait_resumed(), 10.0)
                assert resumed is not None and resumed.silent_for >= 0.1
                assert [type(e) for e in slave_events[before : before + 2]] == [
                    PeerSilent,
                    PeerResumed,
                ]
                await eventually(lambda: slave.stats.samples_delivered > delivered + 50)
                assert not slave.is_closed and not master.is_closed
                assert slave.stats.peer_silences >= silences_before + 1
                assert slave.stats.longest_silence >= resumed.silent_for
                stop.set()
                await asyncio.gather(*streams)
        finally:
            await relay.close()


@pytest.mark.asyncio
async def test_an_outage_longer_than_idle_timeout_ends_the_session_with_its_cause() -> None:
    config = ConnectionConfig(silence_timeout=0.05, idle_timeout=0.5)
    async with listen(config=config) as server:
        relay = await start_relay(("127.0.0.1", 0), ("127.0.0.1", server.port), "delay 1ms")
        try:
            master = await connect(relay.address[0], relay.address[1], config=config)
            slave = await server.accept()
            watch = asyncio.create_task(slave.wait_silent())
            relay.change("loss 100%")
            await asyncio.wait_for(watch, 10.0)
            closed = await asyncio.wait_for(slave.wait_closed(), 10.0)
            assert closed.cause is CloseCause.IDLE_TIMEOUT
            with pytest.raises(EndpointClosedError, match="idle_timeout"):
                await slave.wait_resumed()
            with pytest.raises(EndpointClosedError, match=r"idle_timeout.*0\.5 s"):
                slave.send(b"too late")
            await asyncio.wait_for(master.wait_closed(), 10.0)
            with pytest.raises(EndpointClosedError) as raised:
                await master.wait_silent()
            assert raised.value.event.cause is CloseCause.IDLE_TIMEOUT
            await master.close()
        finally:
            await relay.close()
