"""The asyncio endpoints over real UDP on loopback, on both event loops."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable

import pytest

from tdtp import CloseCause, ConnectionConfig, DataReceived
from tdtp.aio.api import ConnectError, connect, listen
from tdtp.aio.endpoint import Endpoint, EndpointClosedError
from tdtp.aio.ticker import Ticker

FAST_TIMEOUTS = ConnectionConfig(keepalive_interval=0.05, idle_timeout=0.5, open_timeout=0.5)


async def _eventually(condition: Callable[[], bool], within: float = 3.0) -> None:
    """Wait for ``condition`` on real sockets (a correctness timeout, not a timing goal)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + within
    while not condition():
        if loop.time() > deadline:
            raise AssertionError("condition not reached within the patience window")
        await asyncio.sleep(0.005)


async def _exchange(a: Endpoint, b: Endpoint, samples: int, rate: float = 1000.0) -> None:
    count = 0
    async for _ in Ticker(rate):
        a.send(b"m%05d" % count + bytes(94))
        b.send(b"s%05d" % count + bytes(94))
        count += 1
        if count == samples:
            break
    await _eventually(
        lambda: (
            b.stats.received.data_packets == a.stats.sent.data_packets
            and a.stats.received.data_packets == b.stats.sent.data_packets
        )
    )


@pytest.mark.asyncio
async def test_open_exchange_close() -> None:
    async with await listen("127.0.0.1", 0) as server:
        master = await connect("127.0.0.1", server.port)
        slave = await server.accept()
        assert slave.peer is not None and master.peer is not None
        await _exchange(master, slave, 200)
        # Nothing is lost on loopback, and nothing but data flows: the ACKs rode along.
        for ep in (master, slave):
            assert ep.stats.packets_lost == 0
            assert ep.stats.sent.ack_packets <= 2
        first = await slave.recv()
        assert first.payload.startswith(b"m")
        await master.close()
        closed = await asyncio.wait_for(slave.wait_closed(), 3.0)
        assert closed.cause is CloseCause.PEER_CLOSE
        received = [first] + [sample async for sample in slave.stream()]  # in order, to the close
        assert len(received) == master.stats.sent.data_packets
        assert [int(s.payload[1:6]) for s in received] == sorted(
            int(s.payload[1:6]) for s in received
        )
        with pytest.raises(EndpointClosedError):
            await slave.recv()


@pytest.mark.asyncio
async def test_ipv6() -> None:
    try:
        probe = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        probe.bind(("::1", 0))
        probe.close()
    except OSError:
        pytest.skip("no IPv6 loopback on this machine")
    async with await listen("::1", 0) as server, await connect("::1", server.port) as master:
        slave = await server.accept()
        assert master.peer is not None and master.peer[0] == "::1"
        await _exchange(master, slave, 100)
        assert slave.stats.packets_lost == master.stats.packets_lost == 0


@pytest.mark.asyncio
async def test_one_slave_serves_several_masters() -> None:
    async with await listen("127.0.0.1", 0) as server:
        masters = [await connect("127.0.0.1", server.port) for _ in range(3)]
        slaves = [await server.accept() for _ in range(3)]
        assert len({s.peer for s in slaves}) == 3 and len(server.endpoints) == 3
        # `>=`, not `==`: after a stall longer than max_catch_up periods (a loaded machine) the
        # ticker skips to the tick due now, and a loop waiting for tick 30 exactly once ran on,
        # sending forever, until CI was killed 14 minutes later.
        async for tick in Ticker(1000.0):
            for index, master in enumerate(masters):
                master.send(b"master-%d" % index)
            if tick >= 30:
                break
        # Everything each master sent arrives (on a loaded machine some samples are superseded
        # before they leave: latest-value semantics, not loss).
        await _eventually(
            lambda: (
                sum(s.stats.received.data_packets for s in slaves)
                == sum(m.stats.sent.data_packets for m in masters)
            )
        )
        # Each slave endpoint hears exactly one master: the server demultiplexes by address.
        senders = []
        for slave in slaves:
            count = slave.stats.received.data_packets
            assert count >= 1
            payloads = {(await slave.recv()).payload for _ in range(count)}
            assert len(payloads) == 1
            senders.append(payloads.pop())
        assert sorted(senders) == [b"master-0", b"master-1", b"master-2"]
        for master in masters:
            await master.close()
        await _eventually(lambda: not server.endpoints)
        assert server.stats.peers_accepted == 3


@pytest.mark.asyncio
async def test_max_peers_bounds_the_table_and_a_full_slave_says_so_at_once() -> None:
    async with await listen("127.0.0.1", 0, max_peers=1) as server:
        first = await connect("127.0.0.1", server.port)
        # Refused with an explicit REJECT BUSY after one cookie round trip, not after open_timeout.
        with pytest.raises(ConnectError, match=r"max_peers") as refused:
            await connect("127.0.0.1", server.port)
        assert "rejected" in str(refused.value)
        assert server.stats.peers_refused == 1
        assert len(server.endpoints) == 1
        await first.close()


class _BlackHole:
    """A transport that sends nothing: the endpoint behind it has vanished from the network."""

    def sendto(self, data: bytes, addr: object = None, /) -> None:
        pass


@pytest.mark.asyncio
async def test_peer_that_disappears_is_reported_within_the_idle_timeout() -> None:
    async with await listen("127.0.0.1", 0, config=FAST_TIMEOUTS) as server:
        master = await connect("127.0.0.1", server.port, config=FAST_TIMEOUTS)
        slave = await server.accept()
        await _exchange(master, slave, 50)
        slave._transport = _BlackHole()  # the slave host drops off the network
        slave._out = None  # (on the batched layer, its outbox too)
        closed = await asyncio.wait_for(master.wait_closed(), FAST_TIMEOUTS.idle_timeout + 2.0)
        assert closed.cause is CloseCause.IDLE_TIMEOUT
        assert master.is_closed


@pytest.mark.asyncio
async def test_garbage_is_dropped_and_counted_and_the_session_carries_on() -> None:
    async with await listen("127.0.0.1", 0) as server:
        master = await connect("127.0.0.1", server.port)
        slave = await server.accept()
        await _exchange(master, slave, 50)
        loop = asyncio.get_running_loop()
        stranger, _ = await loop.create_datagram_endpoint(
            asyncio.DatagramProtocol, remote_addr=("127.0.0.1", server.port)
        )
        stranger.sendto(b"\x00garbage from nowhere")
        master._transport.sendto(b"\xff\xff\xff\xff\xff junk from the master's own socket")
        await _eventually(
            lambda: (
                server.stats.datagrams_unattached == 1
                and slave.stats.drops.get("unknown_type") == 1
            )
        )
        stranger.close()
        await _exchange(master, slave, 50)
        assert slave.stats.packets_lost == master.stats.packets_lost == 0
        await master.close()


@pytest.mark.asyncio
async def test_connect_to_nobody_fails_with_a_clear_error() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        port = silent.getsockname()[1]
        with pytest.raises(ConnectError, match=f"127.0.0.1:{port}") as unanswered:
            await connect("127.0.0.1", port, config=FAST_TIMEOUTS)
    # What a user on another machine needs to hear: where the slave binds, firewalls, NAT.
    message = str(unanswered.value)
    assert "binds 127.0.0.1 unless given a host" in message
    assert f"UDP port {port}" in message and "behind NAT" in message


@pytest.mark.asyncio
async def test_callback_form_and_latest_value_send() -> None:
    got: list[DataReceived] = []
    async with (
        await listen("127.0.0.1", 0, on_data=got.append) as server,
        await connect("127.0.0.1", server.port) as master,
    ):
        await server.accept()
        for i in range(100):  # far faster than the pacer allows: most are superseded
            master.send(i.to_bytes(4, "big"))
        await _eventually(lambda: bool(got) and got[-1].payload == (99).to_bytes(4, "big"))
        stats = master.stats
        assert stats.samples_offered == 100
        assert stats.sent.data_packets + stats.samples_superseded == 100


@pytest.mark.asyncio
async def test_ticker_keeps_absolute_deadlines_and_skips_after_a_stall() -> None:
    import time

    ticker = Ticker(1000.0, max_catch_up=3)
    indexes: list[int] = []
    async for index in ticker:
        indexes.append(index)
        if len(indexes) == 5:
            time.sleep(0.02)  # block the loop for 20 periods
        if len(indexes) == 20:
            break
    assert indexes == sorted(indexes)
    assert ticker.skipped >= 10  # the stall's ticks were dropped, not fired in a burst
    assert indexes[-1] - indexes[0] == 19 + ticker.skipped
