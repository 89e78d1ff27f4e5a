"""The socket's send buffer: while the operating system cannot take datagrams, data is held in the
core (a newer sample supersedes it) instead of queueing in the event loop out of sight.

UDP on loopback never pushes back (the kernel frees each datagram as soon as it is delivered or
dropped), so the real-socket test runs the master's endpoint on a connected ``AF_UNIX`` datagram socket
whose reader stops reading: the kernel's queue fills after a few datagrams and the loop has to buffer,
exactly what a saturated uplink does to a UDP socket."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest

from tdtp import Connection, ConnectionConfig, Role, State, Ticker, connect, listen
from tdtp.aio.api import _DialerProtocol, _limit_write_buffer
from tdtp.aio.endpoint import Endpoint
from tdtp.aio.timer import monotonic

from eventually import eventually

MASTER = ("192.0.2.1", 1)
SLAVE = ("192.0.2.2", 2)


def _established_pair() -> tuple[Connection, Connection]:
    """A master and a slave connection opened in memory, on the real clock."""
    # Without send timestamps: every sample a DATA, as the reader below counts them.
    master = Connection(ConnectionConfig(timestamp_interval=0.0), role=Role.MASTER)
    slave = Connection(role=Role.SLAVE)
    now = monotonic()
    master.connect(SLAVE, now=now)
    for _ in range(3):  # OPEN, COOKIE, OPEN with the cookie, OPEN_ACK, the confirming KEEPALIVE
        for data, _ in master.datagrams_to_send(now=now):
            slave.receive_datagram(data, MASTER, now=now)
        for data, _ in slave.datagrams_to_send(now=now):
            master.receive_datagram(data, SLAVE, now=now)
    assert master.state is State.ESTABLISHED and slave.state is State.ESTABLISHED
    return master, slave


@pytest.mark.asyncio
async def test_a_full_send_buffer_supersedes_samples_instead_of_queueing_them(
    tmp_path: Path,
) -> None:
    reader = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    reader.bind(str(tmp_path / "slave.sock"))
    reader.setblocking(False)
    writer = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    writer.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)  # a few datagrams at most
    writer.connect(str(tmp_path / "slave.sock"))
    writer.setblocking(False)
    loop = asyncio.get_running_loop()
    transport, protocol = await loop.create_datagram_endpoint(_DialerProtocol, sock=writer)
    _limit_write_buffer(transport)
    conn, _ = _established_pair()
    endpoint = Endpoint(conn, transport, connected=True)
    protocol.endpoint = endpoint
    try:
        offered = 0
        largest_backlog = 0
        async for _ in Ticker(1000.0):
            endpoint.send(offered.to_bytes(4, "big") + bytes(96))
            offered += 1
            largest_backlog = max(largest_backlog, transport.get_write_buffer_size())
            if offered == 300:
                break
        stats = conn.stats
        # Nobody reads: the kernel queue filled, the socket pushed back, and the endpoint held the
        # data rather than let the loop queue ~290 datagrams (the issue saw 2,100 with uvloop).
        assert endpoint.write_paused
        assert stats.send_pauses >= 1
        assert stats.samples_blocked > 200
        # At most the datagram that hit the full buffer, besides the 22-byte KEEPALIVEs that still
        # go out while data is held (one per 33 ms of the 0.3 s).
        assert largest_backlog <= 2 * 105 + 10 * 22
        assert stats.sent.data_packets + stats.samples_superseded + 1 == offered  # 1 held
        # The reader catches up: the buffer drains and the newest sample (and only it) goes out.
        received: list[int] = []

        def drain() -> bool:
            while True:
                try:
                    data = reader.recv(2048)
                except BlockingIOError:
                    break
                if data[0] >> 6 == 0:  # DATA
                    received.append(int.from_bytes(data[5:9], "big"))
            return not endpoint.write_paused and bool(received) and received[-1] == offered - 1

        await eventually(drain)
        assert stats.sent.data_packets + stats.samples_superseded == offered
        assert received == sorted(received)
        assert len(received) == stats.sent.data_packets
    finally:
        await endpoint.close()
        transport.close()
        reader.close()


@pytest.mark.asyncio
async def test_a_server_socket_that_backs_up_holds_the_data_of_every_master() -> None:
    async with listen() as server:
        masters = [await connect("127.0.0.1", server.port) for _ in range(2)]
        slaves = [await server.accept() for _ in range(2)]
        assert server._protocol is not None
        server._protocol.pause_writing()  # what the loop calls when the shared socket is full
        for slave in slaves:
            assert slave.write_paused
            for index in range(5):
                slave.send(bytes([index]))
            assert slave.stats.sent.data_packets == 0
            assert slave.stats.samples_blocked == 4
        server._protocol.resume_writing()
        for slave, master in zip(slaves, masters, strict=True):
            assert not slave.write_paused
            await eventually(lambda m=master: m.stats.samples_delivered == 1)
            newest = master.latest()
            assert newest is not None and newest.payload == bytes([4])  # only the newest left
            await master.close()
