"""The pcap writer: file layout, IP and UDP headers and their checksums, errors."""

from __future__ import annotations

import ipaddress
import struct
from pathlib import Path

import pytest

from tdtp.capture.pcap import LINKTYPE_RAW, CaptureError, PcapWriter

from capture_files import needs_tshark, read_pcap, tshark_fields, udp_payload

V4_A, V4_B = ("192.0.2.1", 40001), ("192.0.2.2", 47000)
V6_A, V6_B = ("2001:db8::1", 40001, 0, 0), ("2001:db8::2", 47000, 0, 0)


def _ones_complement_sum(data: bytes) -> int:
    """Independent of the writer: big-endian 16-bit words, end-around carry."""
    if len(data) % 2:
        data += b"\0"
    total = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return total


def _write(path: Path) -> None:
    with PcapWriter(path) as writer:
        writer.write_udp(V4_A, V4_B, b"\x2a\xf0\x48\xea\x1fhello", timestamp=1_700_000_000.25)
        writer.write_udp(V4_B, V4_A, b"odd", timestamp=1_700_000_000.5)
        writer.write_udp(V6_A, V6_B, b"over IPv6", timestamp=1_700_000_001.0)
        writer.write_udp(("fe80::1%lo", 1, 0, 1), V6_B, b"scoped", timestamp=1_700_000_001.0)
        writer.write_udp(("127.0.0.1", 5), ("::1", 6, 0, 0), b"mixed", timestamp=1_700_000_002.0)
        assert writer.packets == 5


def test_the_file_holds_raw_ip_packets_with_valid_checksums(tmp_path: Path) -> None:
    path = tmp_path / "x.pcap"
    _write(path)
    linktype, records = read_pcap(path)
    assert linktype == LINKTYPE_RAW
    assert [(r.seconds, r.micros) for r in records[:3]] == [
        (1_700_000_000, 250_000),
        (1_700_000_000, 500_000),
        (1_700_000_001, 0),
    ]
    assert [udp_payload(r.packet) for r in records] == [
        b"\x2a\xf0\x48\xea\x1fhello",
        b"odd",
        b"over IPv6",
        b"scoped",
        b"mixed",
    ]
    v4 = records[0].packet
    assert v4[0] == 0x45 and v4[9] == 17 and struct.unpack("!H", v4[2:4])[0] == len(v4)
    assert _ones_complement_sum(v4[:20]) == 0xFFFF  # the IPv4 header checksum verifies
    assert (v4[12:16], v4[16:20]) == (bytes([192, 0, 2, 1]), bytes([192, 0, 2, 2]))
    for record in records:
        packet = record.packet
        if packet[0] >> 4 == 4:
            src, dst, udp = packet[12:16], packet[16:20], packet[20:]
            pseudo = src + dst + struct.pack("!BBH", 0, 17, len(udp))
        else:
            src, dst, udp = packet[8:24], packet[24:40], packet[40:]
            pseudo = src + dst + struct.pack("!I3xB", len(udp), 17)
            assert packet[6] == 17 and struct.unpack("!H", packet[4:6])[0] == len(udp)
        assert struct.unpack("!H", udp[4:6])[0] == len(udp)
        assert _ones_complement_sum(pseudo + udp) == 0xFFFF  # the UDP checksum verifies
    mixed = records[4].packet
    assert mixed[0] >> 4 == 6  # one family per packet: the IPv4 end mapped into IPv6
    assert ipaddress.IPv6Address(mixed[8:24]).ipv4_mapped == ipaddress.IPv4Address("127.0.0.1")


@needs_tshark
def test_tshark_reads_addresses_ports_and_good_checksums(tmp_path: Path) -> None:
    path = tmp_path / "x.pcap"
    _write(path)
    rows = tshark_fields(
        path,
        ["ip.src", "ipv6.src", "udp.srcport", "udp.dstport", "udp.length", "udp.checksum.status"],
        "-o",
        "udp.check_checksum:TRUE",
        "-o",
        "ip.check_checksum:TRUE",
        home=tmp_path,
    )
    # checksum status: 0 bad, 1 good, 2 not verified
    assert rows[0] == ["192.0.2.1", "", "40001", "47000", str(8 + 10), "1"]
    assert rows[2][1:4] == ["2001:db8::1", "40001", "47000"]
    assert {row[5] for row in rows} == {"1"}
    ip_status = tshark_fields(
        path, ["ip.checksum.status"], "-o", "ip.check_checksum:TRUE", home=tmp_path
    )
    assert [row[0] for row in ip_status[:2]] == ["1", "1"]


def test_an_unwritable_path_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(CaptureError, match=r"cannot write the capture file .*writable directory"):
        PcapWriter(tmp_path / "no" / "such" / "dir" / "x.pcap")


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_disk_stops_the_capture_without_raising() -> None:
    writer = PcapWriter("/dev/full")  # every write fails with ENOSPC once it reaches the device
    for _ in range(200):  # past the file buffer
        writer.write_udp(V4_A, V4_B, bytes(100))
    writer.flush()
    assert writer.error is not None and "failed" in writer.error
    assert writer.closed
    writer.write_udp(V4_A, V4_B, b"ignored")  # and keeps quiet after
    writer.close()
