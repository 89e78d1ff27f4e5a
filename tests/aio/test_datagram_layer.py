"""The batched datagram layer (tdtp.aio.datagram) on real loopback sockets, both engines.

Every check is on what the run recorded (datagrams, callbacks, counters), never on a rate: the
burst tests send everything before the loop gets a turn, so it is all queued when the reader runs.
"""

from __future__ import annotations

import asyncio
import math
import os
import socket
import subprocess
import sys
import time

import pytest
from datagram_recorder import Recorder

from tdtp.aio.datagram import (
    DatagramLayer,
    datagram_build_info,
    open_datagram_endpoint,
)
from tdtp.errors import (
    ArgumentTypeError,
    DatagramEngineUnavailableError,
    DatagramLayerClosedError,
    InvalidArgumentError,
    TdtpError,
)
from tdtp.session.events import Address

from eventually import eventually

ENGINES = [
    "pure",
    pytest.param(
        "compiled",
        marks=pytest.mark.skipif(
            not datagram_build_info().compiled, reason=datagram_build_info().reason
        ),
    ),
]


def _has_ipv6() -> bool:
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s:
            s.bind(("::1", 0))
    except OSError:
        return False
    return True


async def _open(
    rec: Recorder, engine: str, host: str = "127.0.0.1", **kwargs: object
) -> DatagramLayer:
    return await open_datagram_endpoint(
        rec,
        local_addr=(host, 0),
        on_error=rec.errors.append,
        engine=engine,  # type: ignore[arg-type]
        **kwargs,  # type: ignore[arg-type]
    )


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("host", ["127.0.0.1", "::1"])
async def test_round_trip_both_families(engine: str, host: str) -> None:
    if host == "::1" and not _has_ipv6():
        pytest.skip("no IPv6 loopback")
    a_rec, b_rec = Recorder(), Recorder()
    async with await _open(a_rec, engine, host) as a, await _open(b_rec, engine, host) as b:
        assert a.engine == engine
        b_addr = b.sockname
        assert a.sendto(b"ping", (host, b_addr[1]))
        await eventually(lambda: len(b_rec.datagrams) == 1)
        (datas, addrs, stamps, classes) = b_rec.batches[0]
        assert datas == [b"ping"] and stamps is None and classes is None
        assert addrs[0][:2] == a.sockname[:2]
        assert b.sendto(bytearray(b"pong"), addrs[0])
        await eventually(lambda: len(a_rec.datagrams) == 1)
        assert a_rec.datagrams == [b"pong"]
        assert a.stats["datagrams_sent"] == 1 and a.stats["datagrams_received"] == 1
    assert a.is_closed and b.is_closed
    with pytest.raises(DatagramLayerClosedError):
        a.sendto(b"late", ("127.0.0.1", 9))


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
async def test_a_queued_burst_arrives_in_at_most_ceil_n_over_batch_callbacks(engine: str) -> None:
    rec = Recorder()
    batch, n = 8, 50
    async with await _open(rec, engine, batch=batch) as rx:
        port = rx.sockname[1]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for i in range(n):  # before the loop runs again: all queued when the reader wakes
                tx.sendto(i.to_bytes(2, "big") * 50, ("127.0.0.1", port))
        await eventually(lambda: len(rec.datagrams) == n)
        assert len(rec.batches) <= math.ceil(n / batch)
        assert all(len(b[0]) <= batch for b in rec.batches)
        assert [int.from_bytes(d[:2], "big") for d in rec.datagrams] == list(range(n))
        stats = rx.stats
        assert stats["datagrams_received"] == n and stats["batches_received"] == len(rec.batches)


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
async def test_send_batch_sends_every_datagram_to_its_own_address(engine: str) -> None:
    recs = [Recorder(), Recorder()]
    async with (
        await _open(Recorder(), engine, batch=4) as tx,
        await _open(recs[0], engine) as r0,
        await _open(recs[1], engine) as r1,
    ):
        ports = [r0.sockname[1], r1.sockname[1]]
        items: list[tuple[bytes, Address | None]] = [
            (bytes([i]) * 10, ("127.0.0.1", ports[i % 2])) for i in range(11)
        ]
        assert tx.send_batch(items) == 11
        await eventually(lambda: len(recs[0].datagrams) + len(recs[1].datagrams) == 11)
        assert recs[0].datagrams == [bytes([i]) * 10 for i in range(0, 11, 2)]
        assert recs[1].datagrams == [bytes([i]) * 10 for i in range(1, 11, 2)]
        if engine == "compiled":
            assert tx.stats["send_calls"] == math.ceil(11 / 4)  # one sendmmsg per batch


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
async def test_many_peers_interleaved_keep_their_addresses_both_ways(engine: str) -> None:
    # A server's socket: many peers, one datagram each in turn, several rounds. Every datagram
    # is reported from its own sender's address and every answer reaches its own peer (the
    # compiled engine remembers peers' addresses in bounded tables: more peers than a table's
    # slots must still be right, only slower).
    rec = Recorder()
    peers = 300
    rounds = 3
    async with await _open(rec, engine, batch=64) as server:
        port = server.sockname[1]
        sockets = []
        try:
            for _ in range(peers):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                sockets.append(s)
                s.bind(("127.0.0.1", 0))
                s.setblocking(False)
            sent = 0
            for r in range(rounds):
                for i, s in enumerate(sockets):
                    s.sendto(f"{r}:{i}".encode(), ("127.0.0.1", port))
                    sent += 1
                    if sent % 50 == 0:  # a chunk at a time: well within the receive buffer
                        await eventually(lambda n=sent: len(rec.datagrams) == n)
            senders = [s.getsockname() for s in sockets]
            got = [(d, a) for batch in rec.batches for d, a in zip(batch[0], batch[1], strict=True)]
            assert len(got) == peers * rounds
            for data, addr in got:
                index = int(data.split(b":")[1])
                assert tuple(addr[:2]) == senders[index]
            # Answers to each peer's address as reported, interleaved, in one call.
            assert server.send_batch([(data, addr) for data, addr in got]) == peers * rounds
            for i, s in enumerate(sockets):
                for r in range(rounds):
                    await eventually(lambda s=s: _readable(s))
                    assert s.recv(64) == f"{r}:{i}".encode()
        finally:
            for s in sockets:
                s.close()


def _readable(s: socket.socket) -> bool:
    try:
        s.recv(64, socket.MSG_PEEK)
    except BlockingIOError:
        return False
    return True


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
async def test_kernel_timestamps_when_asked(engine: str) -> None:
    rec = Recorder()
    async with await _open(rec, engine, timestamps=True) as rx:
        before = time.time_ns()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for i in range(5):
                tx.sendto(bytes([i]), ("127.0.0.1", rx.sockname[1]))
        await eventually(lambda: len(rec.datagrams) == 5)
        after = time.time_ns()
        stamps = [s for b in rec.batches for s in (b[2] or [])]
        assert len(stamps) == 5
        assert stamps == sorted(stamps)  # one sender, one queue: in order
        assert all(before - 1_000_000 <= s <= after for s in stamps)  # CLOCK_REALTIME


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("host", ["127.0.0.1", "::1"])
async def test_ecn_bits_round_trip(engine: str, host: str) -> None:
    if host == "::1" and not _has_ipv6():
        pytest.skip("no IPv6 loopback")
    rec = Recorder()
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    async with await _open(rec, engine, host, ecn=True) as rx:
        with socket.socket(family, socket.SOCK_DGRAM) as tx:
            for mark in (0b01, 0b10, 0b11):  # ECT(1), ECT(0), CE
                if family == socket.AF_INET:
                    tx.setsockopt(socket.IPPROTO_IP, socket.IP_TOS, mark)
                else:
                    tx.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_TCLASS, mark)
                tx.sendto(b"x", (host, rx.sockname[1]))
        await eventually(lambda: len(rec.datagrams) == 3)
        classes = [c for b in rec.batches for c in (b[3] or [])]
        assert [c & 3 for c in classes] == [0b01, 0b10, 0b11]


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
async def test_port_unreachable_is_reported_and_counted_never_raised(engine: str) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gone:
        gone.bind(("127.0.0.1", 0))
        port = gone.getsockname()[1]
    rec = Recorder()
    layer = await open_datagram_endpoint(
        rec,
        remote_addr=("127.0.0.1", port),
        on_error=rec.errors.append,
        engine=engine,  # type: ignore[arg-type]
    )
    async with layer:
        layer.sendto(b"anyone?")  # the ICMP error comes back on the connected socket
        await eventually(lambda: layer.stats["port_unreachable"] >= 1)
        assert any(isinstance(e, ConnectionRefusedError) for e in rec.errors)
        assert rec.datagrams == []
        # The socket is still read after the error (uvloop drops a descriptor on EPOLLERR; the
        # layer registers it again): a datagram from the peer, once it is there, arrives.
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as peer:
            peer.bind(("127.0.0.1", port))
            peer.sendto(b"here now", layer.sockname)
            await eventually(lambda: rec.datagrams == [b"here now"])


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
async def test_oversized_datagrams_are_lost_and_counted(engine: str) -> None:
    rec = Recorder()
    async with await _open(rec, engine, buffer_size=64) as layer:
        dest = ("127.0.0.1", layer.sockname[1])
        assert not layer.sendto(b"x" * 70_000, dest)  # EMSGSIZE: no exception
        assert layer.stats["too_big"] == 1 and layer.stats["send_errors"] == 1
        assert any(e.errno is not None for e in rec.errors)
        layer.sendto(b"y" * 100, dest)  # longer than the receive buffer: dropped, counted
        layer.sendto(b"z" * 10, dest)
        await eventually(lambda: len(rec.datagrams) == 1)
        assert rec.datagrams == [b"z" * 10]
        assert layer.stats["truncated"] == 1


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
async def test_a_full_send_buffer_holds_a_bounded_number_and_resumes(engine: str) -> None:
    events: list[str] = []
    rec = Recorder()
    async with await _open(
        rec,
        engine,
        max_pending=3,
        on_pause=lambda: events.append("pause"),
        on_resume=lambda: events.append("resume"),
    ) as layer:
        dest: Address = ("127.0.0.1", layer.sockname[1])
        # What the engine does on EAGAIN, driven directly (loopback UDP never pushes back).
        layer._blocked([(b"a", dest), (b"b", dest)])
        assert layer.write_paused and events == ["pause"]
        assert not layer.sendto(b"c", dest)  # paused: held, no system call
        assert layer.send_batch([(b"d", dest), (b"e", dest)]) == 0
        assert layer.pending == 3 and layer.stats["pending_dropped"] == 2
        await eventually(lambda: events == ["pause", "resume"])
        await eventually(lambda: len(rec.datagrams) == 3)
        assert sorted(rec.datagrams) == [b"a", b"b", b"c"]
        assert not layer.write_paused


@pytest.mark.asyncio
async def test_parameters_are_validated_before_anything_is_bound() -> None:
    rec = Recorder()
    for kwargs, error in (
        ({"batch": 0}, InvalidArgumentError),
        ({"batch": 5000}, InvalidArgumentError),
        ({"buffer_size": 10}, InvalidArgumentError),
        ({"batch": 1024, "buffer_size": 65536}, InvalidArgumentError),
        ({"timestamps": 1}, ArgumentTypeError),
        ({"engine": "fast"}, InvalidArgumentError),
        ({"max_pending": -1}, InvalidArgumentError),
    ):
        with pytest.raises(error):
            await open_datagram_endpoint(rec, local_addr=("127.0.0.1", 0), **kwargs)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgumentError):
        await open_datagram_endpoint(rec)
    with pytest.raises(TdtpError):
        await open_datagram_endpoint(rec, local_addr=("no-such-host.invalid", 0))
    if not datagram_build_info().compiled:
        with pytest.raises(DatagramEngineUnavailableError):
            await open_datagram_endpoint(rec, local_addr=("127.0.0.1", 0), engine="compiled")


@pytest.mark.asyncio
@pytest.mark.parametrize("engine", ENGINES)
async def test_misuse_raises_tdtp_errors(engine: str) -> None:
    async with await _open(Recorder(), engine) as layer:
        with pytest.raises(InvalidArgumentError):
            layer.sendto(b"x", ("localhost", 1))  # names are resolved by the caller
        with pytest.raises(ArgumentTypeError):
            layer.sendto("text", ("127.0.0.1", 1))  # type: ignore[arg-type]
        with pytest.raises(ArgumentTypeError):
            layer.send_batch([b"x"])  # type: ignore[list-item]


def test_the_pure_switch_selects_the_pure_engine() -> None:
    code = (
        "import asyncio\n"
        "from tdtp.aio.datagram import datagram_build_info, open_datagram_endpoint\n"
        "got = []\n"
        "async def main():\n"
        "    a = await open_datagram_endpoint(lambda d, *_: got.extend(d), local_addr=('127.0.0.1', 0))\n"
        "    a.sendto(b'hi', a.sockname)\n"
        "    while not got: await asyncio.sleep(0.005)\n"
        "    print(datagram_build_info().engine, a.engine, got)\n"
        "    a.close()\n"
        "asyncio.run(main())\n"
    )
    env = {**os.environ, "TDTP_PURE_PYTHON": "1"}
    out = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    )
    assert out.stdout.split() == ["pure", "pure", "[b'hi']"]


@pytest.mark.asyncio
async def test_the_opt_in_switch_runs_connect_and_listen_on_the_layer(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import tdtp
    from tdtp.aio.datagram_transport import BatchedDatagramTransport

    monkeypatch.setenv("TDTP_DATAGRAM_LAYER", "1")
    got: list[tdtp.DataReceived] = []
    async with (
        tdtp.listen("127.0.0.1", 0, on_data=got.append) as server,
        tdtp.connect("127.0.0.1", server.port) as ep,
    ):
        assert isinstance(server._transport, BatchedDatagramTransport)
        assert isinstance(ep._transport, BatchedDatagramTransport)
        for i in range(10):
            ep.send(bytes([i]) * 20)
            await asyncio.sleep(0.001)
        await eventually(lambda: len(got) >= 1 and got[-1].payload == bytes([9]) * 20)
        layer = server._transport._layer
        assert layer is not None and layer.stats["datagrams_received"] >= len(got)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as gone:
        gone.bind(("127.0.0.1", 0))
        port = gone.getsockname()[1]
    with pytest.raises(tdtp.PortUnreachableError):
        await tdtp.connect("127.0.0.1", port)
