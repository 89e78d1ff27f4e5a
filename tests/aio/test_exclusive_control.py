"""Exclusive control (docs/PROTOCOL.md 5.9) over real loopback sockets: at most one master commands an
exclusive slave; a second one is refused with REJECT IN_USE (and told why), takes over once the first
has been silent for ``takeover_after`` watchdog periods, or at once when keyed with TAKEOVER."""

from __future__ import annotations

import asyncio

import pytest

from tdtp import (
    CloseCause,
    ConnectError,
    ConnectionConfig,
    Endpoint,
    InvalidArgumentError,
    connect,
    listen,
)
from tdtp.aio.relay import start_relay
from tdtp.protection import PresharedKey

from eventually import eventually

KEY = PresharedKey(bytes(range(32)), name="operator")
SECOND = PresharedKey(bytes(range(1, 33)), name="relief")
FAST = ConnectionConfig(silence_timeout=0.05, open_timeout=2.0)


@pytest.mark.asyncio
async def test_a_second_master_is_refused_while_the_first_commands() -> None:
    async with listen(exclusive=True) as server, connect("127.0.0.1", server.port) as first:
        await server.accept()
        with pytest.raises(ConnectError, match="exclusive and another master commands it"):
            await connect("127.0.0.1", server.port)
        assert server.stats.peers_in_use == 1 and server.stats.takeovers == 0
        assert not first.is_closed


@pytest.mark.asyncio
async def test_a_silent_master_is_replaced_after_its_takeover_period() -> None:
    async with listen(config=FAST, exclusive=True, takeover_after=2) as server:
        relay = await start_relay(("127.0.0.1", 0), ("127.0.0.1", server.port), "delay 1ms")
        try:
            first = await connect(*relay.address, config=FAST)
            held = await server.accept()
            relay.change("loss 100%")  # the first master goes silent
            await held.wait_silent()
            await eventually(lambda: held.connection.quiet_for(_now()) >= 0.1)
            async with connect("127.0.0.1", server.port, config=FAST) as second:
                taken = await server.accept()
                assert taken.peer != held.peer and not second.is_closed
                closed = await held.wait_closed()
                assert closed.cause is CloseCause.TAKEN_OVER
                assert server.stats.takeovers == 1
            await first.close()
        finally:
            await relay.close()


@pytest.mark.asyncio
async def test_a_keyed_master_takes_over_at_once_with_the_flag() -> None:
    async with (
        listen(keys=[KEY, SECOND], exclusive=True) as server,
        connect("127.0.0.1", server.port, key=KEY) as first,
    ):
        held = await server.accept()
        # Without the flag: refused while the first one is alive.
        with pytest.raises(ConnectError, match="exclusive"):
            await connect("127.0.0.1", server.port, key=SECOND)
        config = ConnectionConfig(takeover=True)
        async with connect("127.0.0.1", server.port, key=SECOND, config=config) as second:
            taken = await server.accept()
            assert taken.connection.key == SECOND
            assert (await held.wait_closed()).cause is CloseCause.TAKEN_OVER
            # The master that lost control hears it: CLOSE with the reason taken_over.
            lost = await first.wait_closed()
            assert lost.cause is CloseCause.PEER_CLOSE and lost.detail == "taken_over"
            assert not second.is_closed


@pytest.mark.asyncio
async def test_a_displaced_master_sending_at_1khz_always_ends_taken_over() -> None:
    """The displaced master's samples still in flight reach a server that no longer holds its
    session: in version 3 their RESET usually overtook the CLOSE (4 of 6 runs of the CLI), and
    the master ended peer_restarted. Now it ends taken_over every time (PROTOCOL.md 5.7, 5.9)."""
    for _ in range(3):
        async with listen(keys=[KEY, SECOND], exclusive=True) as server:
            first = await connect("127.0.0.1", server.port, key=KEY)
            held = await server.accept()
            sending = asyncio.create_task(_send_at_1khz(first))
            await asyncio.sleep(0.05)
            config = ConnectionConfig(takeover=True)
            async with connect("127.0.0.1", server.port, key=SECOND, config=config):
                await server.accept()
                assert (await held.wait_closed()).cause is CloseCause.TAKEN_OVER
                lost = await asyncio.wait_for(first.wait_closed(), 5.0)
            await sending
            assert lost.cause is CloseCause.PEER_CLOSE and lost.detail == "taken_over"
            await first.close()


async def _send_at_1khz(endpoint: Endpoint) -> None:
    """Samples every millisecond until the session ends (at most 5 s)."""
    for _ in range(5000):
        if endpoint.is_closed:
            return
        endpoint.send(bytes(100))
        await asyncio.sleep(0.001)


@pytest.mark.asyncio
async def test_an_unkeyed_takeover_flag_buys_nothing() -> None:
    async with listen(exclusive=True) as server, connect("127.0.0.1", server.port):
        await server.accept()
        with pytest.raises(ConnectError, match="exclusive"):
            await connect("127.0.0.1", server.port, config=ConnectionConfig(takeover=True))


@pytest.mark.parametrize("bad", [0, 1001, 2.5, True, "3"])
def test_takeover_after_is_validated(bad: object) -> None:
    with pytest.raises(InvalidArgumentError, match="takeover_after"):
        listen(exclusive=True, takeover_after=bad)  # type: ignore[arg-type]


def _now() -> float:
    from tdtp import monotonic

    return monotonic()
