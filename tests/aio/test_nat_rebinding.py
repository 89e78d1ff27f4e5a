"""Path migration over real loopback sockets: the relay between master and slave gives the master a
new source port mid-session (a NAT rebinding); the session carries on both ways, keyed and unkeyed.
The test checks what the run recorded, never a wall-clock rate."""

from __future__ import annotations

import asyncio

import pytest

from tdtp import Endpoint, Ticker, connect, listen
from tdtp.aio.relay import start_relay
from tdtp.protection import PresharedKey

from eventually import eventually

KEY = PresharedKey(bytes(range(32)), name="operator")


async def _stream(ep: Endpoint, stop: asyncio.Event) -> None:
    async for _ in Ticker(1000.0):
        if stop.is_set() or ep.is_closed:
            return
        ep.send(b"sample" + bytes(94))


@pytest.mark.asyncio
@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
async def test_a_master_whose_source_port_changes_keeps_its_session(keyed: bool) -> None:
    keys = [KEY] if keyed else None
    async with listen(keys=keys) as server:
        relay = await start_relay(("127.0.0.1", 0), ("127.0.0.1", server.port), "delay 1ms")
        try:
            key = KEY if keyed else None
            async with connect(relay.address[0], relay.address[1], key=key) as master:
                slave = await server.accept()
                stop = asyncio.Event()
                streams = [
                    asyncio.create_task(_stream(master, stop)),
                    asyncio.create_task(_stream(slave, stop)),
                ]
                await eventually(lambda: slave.stats.samples_delivered >= 50)
                old_peer = slave.peer
                await relay.rebind()
                await eventually(lambda: slave.peer != old_peer)
                to_slave = slave.stats.samples_delivered
                to_master = master.stats.samples_delivered
                await eventually(
                    lambda: (
                        slave.stats.samples_delivered >= to_slave + 200
                        and master.stats.samples_delivered >= to_master + 200
                    )
                )
                stop.set()
                await asyncio.gather(*streams)
                stats = slave.stats
                assert stats.migrations == 1 and stats.paths_validated == 1
                assert stats.unvalidated_bytes_out <= 3 * stats.unvalidated_bytes_in
                assert server.stats.migration.migrations == 1
                # The datagrams from the new address found a session to claim them: no RESET.
                assert server.stats.admission.resets_sent == 0
                if keyed:
                    assert server.stats.migration.challenges_sent == 0
                else:
                    assert server.stats.migration.challenges_sent >= 1
                assert not slave.is_closed and not master.is_closed
                assert len(server.endpoints) == 1
        finally:
            await relay.close()
