"""tools/wireshark/tdtp.lua on multipath sessions (PROTOCOL.md 5.11): the second path's address pair
is found by its MP_CHALLENGE, and every multipath field reads as tdtp's codec says."""

from __future__ import annotations

from pathlib import Path

import pytest

from tdtp import ConnectionConfig, MultipathConfig
from tdtp.capture.pcap import PcapWriter
from tdtp.wire import (
    MpAbandonBody,
    MpChallengeBody,
    MpReportBody,
    MpResponseBody,
    decode_control,
)

from capture_files import needs_tshark, read_pcap, tshark_fields, udp_payload
from multipath_pair import SLAVE_ADDR, MultipathPair, PathLink, master_addr
from pair import Direction

pytestmark = needs_tshark

KEY = bytes(range(32))
FIELDS = [
    "tdtp.code",
    "tdtp.keyed",
    "tdtp.flags.multipath",
    "tdtp.nonce",
    "tdtp.mp.path",
    "tdtp.mp.token",
    "tdtp.mp.echo",
    "tdtp.mp.seq",
    "tdtp.mp.received",
    "tdtp.mp.first",
    "tdtp.mp.lag",
    "tdtp.reason",
    "tdtp.pn",
]


def _capture(path: Path, *, keyed: bool) -> None:
    cfg = ConnectionConfig(multipath=MultipathConfig())
    links = [PathLink(Direction(delay=0.005), Direction(delay=0.005)) for _ in range(2)]
    pair = MultipathPair(
        links, cfg, cfg, master_key=KEY if keyed else None, slave_keys=KEY if keyed else None
    )
    with PcapWriter(path) as writer:
        original = pair._send

        def recorded(
            data: bytes, to_slave: bool, local: int, src: tuple[str, int], dst: tuple[str, int]
        ) -> None:
            source, target = (master_addr(local), SLAVE_ADDR)
            if not to_slave:
                source, target = target, source
            writer.write_udp(source, target, data, 1_700_000_000.0 + pair.now)
            original(data, to_slave, local, src, dst)

        pair._send = recorded  # type: ignore[method-assign]
        pair.open()
        pair.start_samples(1000, 1000)
        pair.run_for(0.1)
        paths = pair.master.conn.multipath
        assert paths is not None
        paths.close_path(1, pair.now)  # an MP_ABANDON
        pair.run_for(0.02)


@pytest.mark.parametrize("keyed", [False, True])
def test_multipath_packets_field_by_field(tmp_path: Path, keyed: bool) -> None:
    path = tmp_path / "multipath.pcap"
    _capture(path, keyed=keyed)
    _, records = read_pcap(path)
    rows = tshark_fields(
        path,
        ["frame.protocols", "_ws.expert.message", *FIELDS],
        "-o",
        "udp.try_heuristic_first:TRUE",
        home=tmp_path,
    )
    assert len(rows) == len(records) > 200
    codes: set[int] = set()
    for frame, (record, row) in enumerate(zip(records, rows, strict=True), start=1):
        assert row[0].endswith(":tdtp"), (frame, row[0])  # path 1's pair too
        assert "Malformed" not in row[1], (frame, row[1])
        got = dict(zip(FIELDS, row[2:], strict=True))
        datagram = udp_payload(record.packet)
        if datagram[0] >> 6 != 2:
            assert got["tdtp.keyed"] == ("1" if keyed else "0"), frame
            continue
        code = datagram[5]
        codes.add(code)
        if code == 1:
            assert got["tdtp.flags.multipath"] == "1"
        if code not in (17, 18, 19, 20):
            continue
        if code in (17, 18):
            assert got["tdtp.nonce"] == datagram[6:22].hex()
        if keyed:
            prefix = 22 if code in (17, 18) else 6
            assert got["tdtp.pn"] == str(int.from_bytes(datagram[prefix : prefix + 2], "big"))
            continue
        body = decode_control(datagram[5:])
        if isinstance(body, MpChallengeBody):
            assert (got["tdtp.mp.path"], got["tdtp.mp.token"]) == (
                str(body.path_id),
                body.token.hex(),
            )
        elif isinstance(body, MpResponseBody):
            assert got["tdtp.mp.echo"] == body.echo.hex()
            assert got["tdtp.mp.token"] == body.token.hex()
        elif isinstance(body, MpReportBody):
            assert got["tdtp.mp.path"] == str(body.path_id)
            assert got["tdtp.mp.seq"] == str(body.seq)
            assert (got["tdtp.mp.received"], got["tdtp.mp.first"]) == (
                str(body.received),
                str(body.first),
            )
            assert got["tdtp.mp.lag"] == str(body.lag)
        elif isinstance(body, MpAbandonBody):
            assert (got["tdtp.mp.path"], got["tdtp.reason"]) == (str(body.path_id), "19")
    assert {17, 18, 19, 20} <= codes
