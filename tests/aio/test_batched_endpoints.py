"""The endpoints and the server on the batched datagram layer (issue 23, round 2), on both loops.

Every test runs on three transports: the layer's compiled engine (the default where it is built),
its pure-Python engine (``TDTP_DATAGRAM_LAYER=pure``) and the loop's own transport
(``TDTP_DATAGRAM_LAYER=0``, the fallback). What they check is what the run itself recorded: every
datagram sent arrives, in order, at the session of its address; nothing forged is taken in.
"""

from __future__ import annotations

import asyncio
import errno
import math
import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from tdtp import ConnectionConfig, DataReceived
from tdtp.aio.api import connect, listen
from tdtp.aio.datagram import datagram_build_info
from tdtp.aio.datagram_transport import ENV, BatchedDatagramTransport, enabled
from tdtp.aio.endpoint import Endpoint, rx_time_of
from tdtp.aio.outbox import current_outbox, loop_outbox
from tdtp.aio.server import Server
from tdtp.aio.ticker import Ticker
from tdtp.aio.timer import monotonic
from tdtp.control.fixed import FixedConfig
from tests.eventually import eventually

UNLIMITED = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))
COMPILED = datagram_build_info().compiled

TRANSPORTS = [
    pytest.param(
        "compiled",
        marks=pytest.mark.skipif(not COMPILED, reason="the C datagram engine is not built"),
    ),
    "pure",
    "stock",
]


@pytest.fixture(params=TRANSPORTS)
def transport(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    kind: str = request.param
    monkeypatch.setenv(ENV, {"compiled": "1", "pure": "pure", "stock": "0"}[kind])
    yield kind


def _layer_stats(server: Server) -> dict[str, int] | None:
    transport = server._transport
    if isinstance(transport, BatchedDatagramTransport) and transport.layer is not None:
        return transport.layer.stats
    return None


async def _masters(server: Server, count: int) -> tuple[list[Endpoint], list[Endpoint]]:
    masters = [await connect("127.0.0.1", server.port, config=UNLIMITED) for _ in range(count)]
    slaves = [await server.accept() for _ in range(count)]
    return masters, slaves


@pytest.mark.asyncio
async def test_the_switch_picks_the_transport(transport: str) -> None:
    assert enabled() is (transport != "stock")
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        master, _ = await _masters(server, 1)
        batched = isinstance(server._transport, BatchedDatagramTransport)
        assert batched is (transport != "stock")
        assert isinstance(master[0]._transport, BatchedDatagramTransport) is batched
        if batched:
            assert server._transport.layer is not None  # type: ignore[union-attr]
            assert server._transport.layer.engine == transport  # type: ignore[union-attr]
        await master[0].close()


@pytest.mark.asyncio
async def test_a_burst_is_received_in_batches_in_order_by_address(transport: str) -> None:
    """Three masters send 40 samples each without yielding: the server's socket holds them all
    when it is next read, so the layer hands them up in batches, and each slave endpoint gets its
    own master's samples, every one, in order."""
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        masters, slaves = await _masters(server, 3)
        before = _layer_stats(server)
        for i in range(40):
            for index, master in enumerate(masters):
                master.send(b"%d:%03d" % (index, i) + bytes(90))
        sent = [m.stats.sent.data_packets for m in masters]
        await eventually(
            lambda: [s.stats.received.data_packets for s in slaves] == sent  # loopback: no loss
        )
        for slave in slaves:
            got = [(await slave.recv()).payload for _ in range(slave.unread)]
            origin = {payload.split(b":")[0] for payload in got}
            assert len(origin) == 1  # demultiplexed by address
            numbers = [int(payload[2:5]) for payload in got]
            assert numbers == sorted(numbers) and len(numbers) == len(set(numbers))
        after = _layer_stats(server)
        if before is not None and after is not None:
            received = after["datagrams_received"] - before["datagrams_received"]
            batches = after["batches_received"] - before["batches_received"]
            assert received >= sum(sent) and batches < received  # batches, not one each
        for master in masters:
            await master.close()


@pytest.mark.asyncio
async def test_replies_of_every_session_leave_in_one_flush(transport: str) -> None:
    """The slaves answer from on_data while the server handles a receive batch: on the layer,
    the answers of all sessions in it leave through the loop's outbox in one send_batch; every
    master gets every answer."""
    answers: list[DataReceived] = []

    def echo(sample: DataReceived) -> None:
        answers.append(sample)

    async with listen("127.0.0.1", 0, config=UNLIMITED, on_data=echo) as server:
        masters = [await connect("127.0.0.1", server.port, config=UNLIMITED) for _ in range(4)]
        await eventually(lambda: len(server.endpoints) == 4)
        slaves = server.endpoints
        for slave in slaves:
            slave.set_data_callback(lambda sample, ep=slave: ep.send(sample.payload))
        outbox = current_outbox(asyncio.get_running_loop())
        flushed = outbox.datagrams if outbox is not None else 0
        before = _layer_stats(server)
        for master in masters:  # no yield in between: one receive batch at the server
            master.send(b"ping" + bytes(96))
        await eventually(lambda: all(m.stats.received.data_packets == 1 for m in masters))
        for master in masters:
            assert (await master.recv()).payload == b"ping" + bytes(96)
        after = _layer_stats(server)
        if transport != "stock":
            assert outbox is not None and before is not None and after is not None
            assert outbox.datagrams - flushed >= 4  # the answers went through the outbox
            sent = after["datagrams_sent"] - before["datagrams_sent"]
            calls = after["send_calls"] - before["send_calls"]
            assert sent >= 4
            if transport == "compiled":
                assert calls < sent  # sendmmsg: several answers per system call
        for master in masters:
            await master.close()


@pytest.mark.asyncio
async def test_the_answer_to_a_lone_datagram_goes_to_the_socket_at_once(transport: str) -> None:
    """A receive batch of one datagram is not held: what the slave's on_data sends is handed to
    the socket during the callback, not queued for the end of the wake-up; a batch of several is
    held and answered through the outbox. Either way every answer arrives."""
    if transport == "stock":
        pytest.skip("the outbox exists on the batched layer only")
    seen: list[tuple[int, int, int]] = []  # (datagrams in the wake-up's batch, depth, direct)
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        masters, slaves = await _masters(server, 3)
        owner = loop_outbox(asyncio.get_running_loop())
        server_layer = server._transport.layer  # type: ignore[union-attr]
        assert server_layer is not None

        def echo(sample: DataReceived, ep: Endpoint) -> None:
            sent_before = server_layer.stats["datagrams_sent"]
            ep.send(sample.payload)
            left = server_layer.stats["datagrams_sent"] - sent_before
            seen.append((left, owner.depth, owner.direct))

        for slave in slaves:
            slave.set_data_callback(lambda sample, ep=slave: echo(sample, ep))
        received = server_layer.stats["datagrams_received"]
        masters[0].send(b"lone" + bytes(96))
        await eventually(lambda: masters[0].stats.received.data_packets == 1)
        if server_layer.stats["datagrams_received"] == received + 1:  # it came alone (no keep-
            # alive of a master landed in the same batch on a slow machine): answered at once
            assert seen == [(1, 0, 1)]  # sent during the callback, outside any held wake-up
        else:
            assert len(seen) == 1 and seen[0][0] in (0, 1)
        seen.clear()
        for master in masters:  # no yield in between: one receive batch of three at the server
            master.send(b"many" + bytes(96))
        await eventually(lambda: [m.stats.received.data_packets for m in masters] == [2, 1, 1])
        assert len(seen) == 3
        if all(depth for _, depth, _ in seen):  # the three came in one batch: held, sent at its end
            assert all(left == 0 and direct == 0 for left, _, direct in seen)
        for index, master in enumerate(masters):
            got = [(await master.recv()).payload[:4] for _ in range(master.unread)]
            assert got == ([b"lone"] if index == 0 else []) + [b"many"]
            await master.close()


@pytest.mark.asyncio
async def test_the_endpoint_names_its_sockets_under_capture_and_impairment(
    transport: str, tmp_path: Path
) -> None:
    """``Endpoint.sockets`` and ``datagram_layer_stats`` see through the pcap and netem wrappers to
    the socket's datagram layer, and its counters account for what the run sent."""
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        master = await connect(
            "127.0.0.1",
            server.port,
            config=UNLIMITED,
            pcap=str(tmp_path / "m.pcap"),
            netem="delay 1ms",
        )
        await server.accept()
        for _ in range(5):
            master.send(bytes(100))
            await asyncio.sleep(0)
        await eventually(lambda: master.stats.sent.data_packets == 5)
        stats = master.datagram_layer_stats
        if transport == "stock":
            assert master.sockets == "loop's transport" and stats is None
        else:
            assert master.sockets.startswith(f"datagram layer ({transport}")
            assert stats is not None
            await eventually(
                lambda: (
                    master.datagram_layer_stats is not None
                    and master.datagram_layer_stats["datagrams_sent"] >= master.stats.sent.datagrams
                )
            )
        await master.close()


@pytest.mark.asyncio
async def test_a_tick_group_wake_up_sends_every_session_in_one_flush(transport: str) -> None:
    """Slaves that send from one Ticker each share the tick group's wake-ups; on the layer what
    they send at one tick leaves through the outbox, and every sample sent arrives."""
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        masters, slaves = await _masters(server, 3)

        async def sender(ep: Endpoint) -> None:
            count = 0
            async for _ in Ticker(1000.0):
                ep.send(b"s%03d" % count + bytes(96))
                count += 1
                if count == 20:
                    return

        outbox = loop_outbox(asyncio.get_running_loop()) if transport != "stock" else None
        flushed = outbox.datagrams if outbox is not None else 0
        await asyncio.gather(*(sender(slave) for slave in slaves))
        await eventually(
            lambda: all(
                m.stats.received.data_packets == s.stats.sent.data_packets
                for m, s in zip(masters, slaves, strict=True)
            )
        )
        if outbox is not None:
            assert outbox.depth == 0
            assert outbox.datagrams - flushed >= sum(s.stats.sent.data_packets for s in slaves)
        for master in masters:
            await master.close()


@pytest.mark.asyncio
async def test_tick_callbacks_send_every_session_in_one_batch(transport: str) -> None:
    """Slaves on tick callbacks (Ticker.call_each): the group's wake-up calls them all with the
    outbox held, so on the compiled layer a tick's samples share system calls; every one arrives."""
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        masters, slaves = await _masters(server, 3)
        before = _layer_stats(server)
        finished: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        counts = [0] * len(slaves)
        handles = []

        def sender(i: int, ep: Endpoint) -> None:
            def on_tick(_: int) -> None:
                ep.send(b"s%03d" % counts[i] + bytes(96))
                counts[i] += 1
                if counts[i] == 20:
                    handles[i].cancel()
                    if all(c == 20 for c in counts) and not finished.done():
                        finished.set_result(None)

            return on_tick

        for i, slave in enumerate(slaves):
            handles.append(Ticker(1000.0).call_each(sender(i, slave)))
        await finished
        await eventually(
            lambda: all(
                m.stats.received.data_packets == s.stats.sent.data_packets == 20
                for m, s in zip(masters, slaves, strict=True)
            )
        )
        after = _layer_stats(server)
        if transport == "compiled":
            assert before is not None and after is not None
            sent = after["datagrams_sent"] - before["datagrams_sent"]
            assert sent >= 60
            assert after["send_calls"] - before["send_calls"] < sent
        for master in masters:
            await master.close()


@pytest.mark.asyncio
async def test_forged_and_off_path_datagrams_in_a_batch_are_dropped_and_counted(
    transport: str,
) -> None:
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        (master,), (slave,) = await _masters(server, 1)
        loop = asyncio.get_running_loop()
        stranger, _ = await loop.create_datagram_endpoint(
            asyncio.DatagramProtocol, remote_addr=("127.0.0.1", server.port)
        )
        unattached = server.stats.datagrams_unattached
        # One batch: the master's samples with junk from its own socket and a stranger's in between.
        for i in range(5):
            master.send(b"%03d" % i + bytes(97))
            stranger.sendto(b"\x00garbage from nowhere")
            master._transport.sendto(b"\xff\xff\xff\xff\xff junk from the master's own socket")
        await eventually(
            lambda: (
                server.stats.datagrams_unattached - unattached == 5
                and slave.stats.drops.get("unknown_type") == 5
                and slave.stats.received.data_packets == master.stats.sent.data_packets
            )
        )
        stranger.close()
        got = [(await slave.recv()).payload[:3] for _ in range(slave.unread)]
        assert got == sorted(got)
        await master.close()


@pytest.mark.asyncio
async def test_receive_times_and_ecn_marks_reach_the_core(transport: str) -> None:
    """On the layer the kernel's receive time (SO_TIMESTAMPNS) and the ECN field (IP_RECVTOS) are
    handed to the core: ``connection.last_rx_time`` on the loop's clock, ``stats.ecn_ce`` counting
    datagrams marked Congestion Experienced (sent here with TOS 3 on loopback)."""
    started = monotonic()
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        (master,), (slave,) = await _masters(server, 1)
        sock = master._transport.get_extra_info("socket")
        assert sock is not None
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_TOS, 0x03)  # ECN = CE
        for i in range(5):
            master.send(b"%03d" % i + bytes(97))
        await eventually(
            lambda: slave.stats.received.data_packets == master.stats.sent.data_packets
        )
        rx_time = slave.connection.last_rx_time
        if transport == "stock":
            assert rx_time is None and slave.stats.ecn_ce == 0  # the loop's transport has neither
        else:
            assert rx_time is not None
            # On the loop's clock, at or before the moment it was handled (1 s of slack for a
            # realtime clock being slewed meanwhile).
            assert started - 1.0 <= rx_time <= monotonic() + 1.0
            assert slave.stats.ecn_ce == 5
        await master.close()


def test_receive_times_convert_to_the_loop_clock() -> None:
    assert rx_time_of(-1, 10.0, 5_000_000_000) is None
    assert rx_time_of(4_000_000_000, 10.0, 5_000_000_000) == pytest.approx(9.0)


@pytest.mark.asyncio
async def test_an_oversized_datagram_in_a_flush_is_counted_and_the_rest_leave(
    transport: str,
) -> None:
    """EMSGSIZE in the middle of a send_batch: that datagram is lost and counted by the layer,
    nothing raises into the loop, the datagrams after it go out."""
    if transport == "stock":
        pytest.skip("the outbox exists on the batched layer only")
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        (master,), (slave,) = await _masters(server, 1)
        batched = master._transport
        assert isinstance(batched, BatchedDatagramTransport) and batched.outbox is not None
        layer = batched.layer
        assert layer is not None
        outbox = batched.outbox.owner
        outbox.hold()
        master.send(b"first" + bytes(95))
        batched.outbox.append(bytes(70_000))  # above the largest UDP datagram
        master.send(b"third" + bytes(95))
        outbox.release()
        assert layer.stats["too_big"] == 1
        await eventually(
            lambda: slave.stats.received.data_packets == master.stats.sent.data_packets
        )
        assert [(await slave.recv()).payload[:5] for _ in range(2)] == [b"first", b"third"]
        await master.close()


@pytest.mark.asyncio
async def test_kernel_errors_reach_the_endpoint_as_on_the_loops_transport(transport: str) -> None:
    """What the layer reports (ENOBUFS, EMSGSIZE, ECONNREFUSED once established) is what the
    loop's transport reports to ``error_received``: a lost datagram counted in ``send_errors``,
    never an exception into the loop, and the session goes on."""
    if transport == "stock":
        pytest.skip("the loop's transport reports its own errors")
    async with listen("127.0.0.1", 0, config=UNLIMITED) as server:
        (master,), (slave,) = await _masters(server, 1)
        batched = master._transport
        assert isinstance(batched, BatchedDatagramTransport)
        before = master.send_errors
        for code in (errno.ENOBUFS, errno.EMSGSIZE):
            batched._on_error(OSError(code, os.strerror(code)))
        batched._on_error(ConnectionRefusedError(errno.ECONNREFUSED, "refused"))
        assert master.send_errors == before + 3
        assert not master.is_closed
        master.send(b"after" + bytes(95))
        await eventually(
            lambda: slave.stats.received.data_packets == master.stats.sent.data_packets
        )
        await master.close()
