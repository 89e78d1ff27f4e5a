"""pcap= on tdtp.connect and tdtp.listen: real sockets, both ends captured, what they hold."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from tdtp import ConnectionConfig
from tdtp.aio.api import connect, listen
from tdtp.capture.pcap import CaptureError, PcapWriter

from capture_files import read_pcap, udp_payload

EXCHANGE = 100


async def _run_session(
    master_pcap: Path, slave_pcap: Path, netem: str | None = None
) -> tuple[dict[str, int], dict[str, int]]:
    config = ConnectionConfig(keepalive_interval=0.05, idle_timeout=0.5)
    async with await listen("127.0.0.1", 0, config=config, pcap=slave_pcap) as server:
        master = await connect(
            "127.0.0.1", server.port, config=config, pcap=master_pcap, netem=netem, netem_seed=1
        )
        slave = await server.accept()
        for i in range(EXCHANGE):
            master.send(b"m%04d" % i)
            slave.send(b"s%04d" % i)
            await asyncio.sleep(0.002)
        await asyncio.sleep(0.1)  # a few KEEPALIVEs and the last ACKs
        await master.close()
        await asyncio.wait_for(slave.wait_closed(), 5.0)  # the CLOSE reached the server
        ms, ss = master.stats, slave.stats
        counts = (
            {"sent": ms.sent.datagrams, "in": ms.datagrams_in, "errors": master.send_errors},
            {"sent": ss.sent.datagrams, "in": ss.datagrams_in, "errors": slave.send_errors},
        )
        assert server.stats.admission.cookies_sent == 1
    return counts


@pytest.mark.asyncio
async def test_both_ends_capture_exactly_what_their_sockets_carried(tmp_path: Path) -> None:
    master_pcap, slave_pcap = tmp_path / "master.pcap", tmp_path / "slave.pcap"
    master, slave = await _run_session(master_pcap, slave_pcap)
    _, master_records = read_pcap(master_pcap)
    _, slave_records = read_pcap(slave_pcap)
    assert master["errors"] == slave["errors"] == 0
    # The master's socket: everything its connection sent and was handed.
    assert len(master_records) == master["sent"] + master["in"]
    # The server's socket: the session's traffic plus the COOKIE it sent before any session.
    assert len(slave_records) == slave["sent"] + slave["in"] + 2  # the first OPEN and its COOKIE
    # Loopback: one end's sent datagrams are the other's received ones, byte for byte.
    master_port = {master_records[0].packet[20:22]}  # the first record is the master's OPEN
    sent_by_master = [
        udp_payload(r.packet) for r in master_records if r.packet[20:22] in master_port
    ]
    received_by_slave = [
        udp_payload(r.packet) for r in slave_records if r.packet[20:22] in master_port
    ]
    assert sorted(sent_by_master) == sorted(received_by_slave)
    # Samples: DATA, and TIMED_DATA (code 16: the sender's clock, 4 bytes, before the sample).
    data = [p[5:] for p in sent_by_master if p[0] >> 6 == 0]
    data += [p[10:] for p in sent_by_master if p[0] >> 6 == 2 and p[5] == 16]
    assert len(data) == EXCHANGE and set(data) == {b"m%04d" % i for i in range(EXCHANGE)}


@pytest.mark.asyncio
async def test_the_capture_is_taken_below_netem(tmp_path: Path) -> None:
    """With impairment the file shows what really left the socket: emulated losses are absent."""
    master_pcap, slave_pcap = tmp_path / "master.pcap", tmp_path / "slave.pcap"
    await _run_session(master_pcap, slave_pcap, netem="loss 30%")
    _, master_records = read_pcap(master_pcap)
    _, slave_records = read_pcap(slave_pcap)
    master_port = master_records[0].packet[20:22]
    sent = [udp_payload(r.packet) for r in master_records if r.packet[20:22] == master_port]
    received = [udp_payload(r.packet) for r in slave_records if r.packet[20:22] == master_port]
    assert sorted(sent) == sorted(received)  # what left arrived; the emulated loss never left


@pytest.mark.asyncio
async def test_a_shared_writer_and_a_bad_path(tmp_path: Path) -> None:
    with pytest.raises(CaptureError, match="capture file"):
        await listen("127.0.0.1", 0, pcap=tmp_path / "missing" / "x.pcap")
    with PcapWriter(tmp_path / "both.pcap") as writer:
        async with (
            await listen("127.0.0.1", 0, pcap=writer) as server,
            await connect("127.0.0.1", server.port, pcap=writer) as master,
        ):
            await server.accept()
            master.send(b"one")
            await asyncio.sleep(0.05)
        assert not writer.closed  # the owner closes a shared writer
        assert writer.packets >= 8  # OPEN, COOKIE, OPEN, OPEN_ACK, KEEPALIVE each seen twice...
