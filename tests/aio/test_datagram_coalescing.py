"""Segmented sends (UDP_SEGMENT) and coalesced receives (UDP_GRO) in the compiled datagram engine.

On real loopback sockets; every check is on what the run recorded (the datagrams, in order and byte
for byte, and the engines' counters), never on a rate.
"""

from __future__ import annotations

import socket

import pytest
from datagram_recorder import Recorder

from tdtp.aio.datagram import DatagramLayer, datagram_build_info, open_datagram_endpoint
from tdtp.errors import ArgumentTypeError
from tdtp.session.events import Address

from eventually import eventually

pytestmark = [
    pytest.mark.asyncio,
    pytest.mark.skipif(not datagram_build_info().compiled, reason=datagram_build_info().reason),
]

SO_NO_CHECK = 11  # Linux: send UDP without checksums, which segmentation refuses (EINVAL)


async def _open(rec: Recorder, host: str = "127.0.0.1", **kwargs: object) -> DatagramLayer:
    return await open_datagram_endpoint(rec, local_addr=(host, 0), **kwargs)  # type: ignore[arg-type]


def _numbered(count: int, size: int, first: int = 0) -> list[bytes]:
    return [(first + i).to_bytes(2, "big") * (size // 2) + b"!" * (size % 2) for i in range(count)]


async def test_a_run_to_one_peer_leaves_in_one_call_and_arrives_datagram_by_datagram() -> None:
    recs = [Recorder(), Recorder()]
    async with (
        await _open(Recorder()) as tx,
        await _open(recs[0], timestamps=True, ecn=True) as r0,
        await _open(recs[1]) as r1,
    ):
        d0: Address = ("127.0.0.1", r0.sockname[1])
        d1: Address = ("127.0.0.1", r1.sockname[1])
        run = _numbered(40, 105)  # one run: equal lengths, one destination
        tail = [b"short"]  # shorter: ends the run as its last segment
        longer = _numbered(3, 200, first=100)  # longer than the run: a new one
        other = _numbered(5, 105, first=200)  # another destination: a new one
        back = _numbered(2, 105, first=300)
        items: list[tuple[bytes, Address | None]] = [
            *((d, d0) for d in run + tail + longer),
            *((d, d1) for d in other),
            *((d, d0) for d in back),
        ]
        assert tx.send_batch(items) == len(items)
        stats = tx.stats
        assert stats["send_calls"] == 1  # one sendmmsg for the whole list
        assert stats["datagrams_sent"] == len(items)
        assert stats["bytes_sent"] == sum(len(d) for d, _ in items)
        assert stats["segmenting"] == 1 and stats["segmentation_refused"] == 0
        assert stats["coalesced_sends"] == 4  # run + tail, the longer three, other, back
        await eventually(lambda: len(recs[0].datagrams) == 46 and len(recs[1].datagrams) == 5)
        assert recs[0].datagrams == run + tail + longer + back  # in order, byte for byte
        assert recs[1].datagrams == other
        assert {a[:2] for a in recs[0].sources} == {tx.sockname[:2]}
        rx = r0.stats
        assert rx["datagrams_received"] == 46 and rx["truncated"] == 0
        if rx["receive_coalescing"]:  # the kernel handed runs over whole: few buffers, few calls
            assert rx["coalesced_received"] >= 1
            assert len(recs[0].batches) <= 2


async def test_a_receiver_that_does_not_coalesce_gets_the_same_datagrams() -> None:
    rec = Recorder()
    async with await _open(Recorder()) as tx, await _open(rec, coalesce=False) as rx:
        assert rx.stats["receive_coalescing"] == 0
        dest: Address = ("127.0.0.1", rx.sockname[1])
        sent = _numbered(30, 100)
        assert tx.send_batch([(d, dest) for d in sent]) == 30
        assert tx.stats["coalesced_sends"] == 1
        await eventually(lambda: len(rec.datagrams) == 30)
        assert rec.datagrams == sent  # the kernel cut the run into datagrams
        assert rx.stats["coalesced_received"] == 0


async def test_a_sender_that_does_not_coalesce_sends_each_datagram_in_its_own_message() -> None:
    rec = Recorder()
    async with await _open(Recorder(), coalesce=False) as tx, await _open(rec) as rx:
        dest: Address = ("127.0.0.1", rx.sockname[1])
        sent = _numbered(20, 100)
        assert tx.send_batch([(d, dest) for d in sent]) == 20
        assert tx.stats["coalesced_sends"] == 0 and tx.stats["segmenting"] == 0
        assert tx.stats["send_calls"] == 1  # still one sendmmsg
        await eventually(lambda: len(rec.datagrams) == 20)
        assert rec.datagrams == sent


async def test_a_refused_segmented_send_goes_again_one_by_one_and_coalescing_stays_off() -> None:
    rec = Recorder()
    errors: list[OSError] = []
    async with await _open(Recorder(), on_error=errors.append) as tx, await _open(rec) as rx:
        # Without UDP checksums the kernel refuses to segment (EINVAL), as a route without
        # checksum offload (EIO) or a kernel without UDP_SEGMENT would.
        tx.socket.setsockopt(socket.SOL_SOCKET, SO_NO_CHECK, 1)
        dest: Address = ("127.0.0.1", rx.sockname[1])
        first = _numbered(10, 100)
        assert tx.send_batch([(d, dest) for d in first]) == 10
        stats = tx.stats
        assert stats["segmentation_refused"] == 1 and stats["segmenting"] == 0
        assert stats["send_errors"] == 0 and not errors  # not lost: sent again, not reported
        second = _numbered(10, 100, first=10)
        assert tx.send_batch([(d, dest) for d in second]) == 10
        assert tx.stats["segmentation_refused"] == 1  # tried once, then off
        assert tx.stats["datagrams_sent"] == 20 and tx.stats["coalesced_sends"] == 0
        await eventually(lambda: len(rec.datagrams) == 20)
        assert rec.datagrams == first + second


async def test_coalesced_datagrams_longer_than_buffer_size_are_dropped_and_counted() -> None:
    rec = Recorder()
    async with await _open(Recorder()) as tx, await _open(rec, buffer_size=64) as rx:
        dest: Address = ("127.0.0.1", rx.sockname[1])
        items: list[tuple[bytes, Address | None]] = [(d, dest) for d in _numbered(10, 100)]
        items.append((b"fits", dest))  # the run's shorter last segment
        assert tx.send_batch(items) == 11
        await eventually(lambda: rx.stats["truncated"] == 10)
        await eventually(lambda: rec.datagrams == [b"fits"])
        assert rx.stats["datagrams_received"] == 1


async def test_ipv6_runs_are_coalesced_too() -> None:
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as s:
            s.bind(("::1", 0))
    except OSError:
        pytest.skip("no IPv6 loopback")
    rec = Recorder()
    async with await _open(Recorder(), "::1") as tx, await _open(rec, "::1") as rx:
        dest: Address = ("::1", rx.sockname[1])
        sent = _numbered(64, 120)
        assert tx.send_batch([(d, dest) for d in sent]) == 64
        assert tx.stats["coalesced_sends"] == 1
        await eventually(lambda: len(rec.datagrams) == 64)
        assert rec.datagrams == sent


async def test_coalesce_must_be_a_bool() -> None:
    with pytest.raises(ArgumentTypeError):
        await _open(Recorder(), coalesce=1)


async def test_one_drain_of_coalesced_buffers_is_bounded() -> None:
    """A full batch of coalesced buffers holds up to 64 datagrams each: one turn of the reader
    ends after that batch instead of reading on for `rounds` more (other readers wait meanwhile)."""
    rec = Recorder()
    async with await _open(Recorder()) as tx, await _open(rec, batch=2) as rx:
        if not rx.stats["receive_coalescing"]:
            pytest.skip("this kernel does not coalesce received datagrams (UDP_GRO)")
        dest: Address = ("127.0.0.1", rx.sockname[1])
        sent = _numbered(256, 100)
        assert tx.send_batch([(d, dest) for d in sent]) == 256  # four runs of 64, queued now
        engine = rx._impl
        assert engine.drain() == 128  # two buffers of 64, then the turn ends (2 x 16 < 128)
        assert rx.stats["coalesced_received"] == 2
        await eventually(lambda: len(rec.datagrams) == 256)
        assert rec.datagrams == sent
