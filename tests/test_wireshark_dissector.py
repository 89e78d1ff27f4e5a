"""tools/wireshark/tdtp.lua under tshark, on captures tdtp writes: every field of every packet type
checked against tdtp's own codec, expert info for malformed packets, and the port registration."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tdtp import ConnectionConfig
from tdtp.capture.pcap import PcapWriter
from tdtp.config import AckMode
from tdtp.protection import PresharedKey
from tdtp.wire import (
    CloseBody,
    CookieBody,
    OpenAckBody,
    OpenBody,
    OpenFlags,
    PathChallengeBody,
    PathResponseBody,
    decode_control,
    decode_header,
    decode_hold,
    encode_header,
    encode_open,
    encode_path_challenge,
    encode_path_response,
)
from tdtp.wire.control import PROTOCOL_VERSION

from capture_files import needs_tshark, read_pcap, tshark_fields, udp_payload
from pair import MASTER_ADDR, SLAVE_ADDR, Pair

pytestmark = needs_tshark

KEY = PresharedKey(bytes(range(32)))
FIELDS = [
    "tdtp.type",
    "tdtp.seq",
    "tdtp.ack",
    "tdtp.sack",
    "tdtp.hold",
    "tdtp.hold_us",
    "tdtp.acked",
    "tdtp.absent",
    "tdtp.keyed",
    "tdtp.payload_len",
    "tdtp.code",
    "tdtp.version",
    "tdtp.flags",
    "tdtp.suite",
    "tdtp.max_payload",
    "tdtp.attempt",
    "tdtp.nonce",
    "tdtp.key_id",
    "tdtp.cookie",
    "tdtp.path_token",
    "tdtp.open_ack.pn",
    "tdtp.slave_nonce",
    "tdtp.reason",
    "tdtp.pn",
    "tdtp.sealed_len",
    "tdtp.tag",
    "tdtp.message.seq",
    "tdtp.message.ack",
    "tdtp.message_len",
    "tdtp.stamp",
]
HEURISTICS_FIRST = ("-o", "udp.try_heuristic_first:TRUE")
UNKEYED = (("192.0.2.1", 40001), ("192.0.2.2", 47000))  # 47000: HCrt's port in Wireshark
SEPARATE = (("192.0.2.3", 40003), ("192.0.2.4", 47002))
KEYED = (("192.0.2.5", 40005), ("2001:db8::6", 47003, 0, 0))
REFUSED = (("192.0.2.7", 40007), ("192.0.2.8", 47004))


def expected_fields(datagram: bytes, keyed: bool) -> dict[str, str]:
    """What the dissector must show for ``datagram``, from tdtp's codec (field: tshark text)."""
    out = dict.fromkeys(FIELDS, "")
    ptype, seq, ack, sack, hold = decode_header(datagram)
    out.update(
        {
            "tdtp.type": str(ptype),
            "tdtp.seq": str(seq),
            "tdtp.ack": str(ack),
            "tdtp.sack": f"0x{sack:02x}",
            "tdtp.hold": str(hold),
        }
    )
    decoded = decode_hold(hold)
    if decoded is not None:
        out["tdtp.hold_us"] = str(round(decoded * 1e6))
    if hold != 255:
        received = [ack] + [(ack - i) % 4096 for i in range(1, 7) if sack >> (i - 1) & 1]
        absent = [(ack - i) % 4096 for i in range(1, 7) if not sack >> (i - 1) & 1]
        out["tdtp.acked"] = ",".join(map(str, received))
        out["tdtp.absent"] = ",".join(map(str, absent))
    handshake = ptype == 2 and len(datagram) > 5 and datagram[5] in (1, 2, 5, 6, 7, 8, 9)
    if not handshake:
        out["tdtp.keyed"] = "1" if keyed else "0"
    if ptype == 2:
        out["tdtp.code"] = str(datagram[5])
    if keyed and not handshake:
        prefix = 6 if ptype == 2 else 5
        out["tdtp.pn"] = str(int.from_bytes(datagram[prefix : prefix + 2], "big"))
        out["tdtp.sealed_len"] = str(len(datagram) - prefix - 18)
        out["tdtp.tag"] = datagram[-16:].hex()
        return out
    if ptype == 0:
        out["tdtp.payload_len"] = str(len(datagram) - 5)
    if ptype != 2:
        return out
    if datagram[5] == 3:
        out["tdtp.nonce"] = datagram[6:22].hex()
        return out
    if datagram[5] == 10:  # MESSAGE: the master's nonce, number, next expected, the message
        out["tdtp.nonce"] = datagram[6:22].hex()
        out["tdtp.message.seq"] = str(int.from_bytes(datagram[22:24], "big"))
        out["tdtp.message.ack"] = str(int.from_bytes(datagram[24:26], "big"))
        out["tdtp.message_len"] = str(len(datagram) - 26)
        return out
    if datagram[5] in (15, 16):  # TIMESTAMP, TIMED_DATA: the sender's clock (and the sample)
        out["tdtp.stamp"] = str(int.from_bytes(datagram[6:10], "big"))
        if datagram[5] == 16:
            out["tdtp.payload_len"] = str(len(datagram) - 10)
        return out
    if datagram[5] == 11:  # MESSAGE_ACK: the master's nonce, next expected
        out["tdtp.nonce"] = datagram[6:22].hex()
        out["tdtp.message.ack"] = str(int.from_bytes(datagram[22:24], "big"))
        return out
    tag = b""
    body = decode_control(datagram[5:])
    if isinstance(body, OpenBody | OpenAckBody):
        out.update(
            {
                "tdtp.version": str(body.version),
                "tdtp.flags": f"0x{body.flags:02x}",
                "tdtp.suite": str(body.suite),
                "tdtp.max_payload": str(body.max_payload),
                "tdtp.nonce": body.nonce.hex(),
            }
        )
        if body.flags & OpenFlags.KEYED:
            tag = datagram[-16:]
    if isinstance(body, OpenBody):
        out.update(
            {
                "tdtp.attempt": str(body.attempt),
                "tdtp.key_id": body.key_id.hex(),
                "tdtp.cookie": body.cookie.hex(),
            }
        )
    elif isinstance(body, OpenAckBody):
        out["tdtp.open_ack.pn"] = str(body.packet_number)
        out["tdtp.slave_nonce"] = body.slave_nonce.hex()
    elif isinstance(body, CookieBody):
        out.update(
            {
                "tdtp.version": str(body.version),
                "tdtp.nonce": body.nonce.hex(),
                "tdtp.cookie": body.cookie.hex(),
            }
        )
    elif isinstance(body, CloseBody):
        out["tdtp.nonce"] = body.nonce.hex()
        out["tdtp.reason"] = str(body.reason)
    elif isinstance(body, PathChallengeBody):
        out["tdtp.path_token"] = body.token.hex()
    elif isinstance(body, PathResponseBody):
        out["tdtp.path_token"] = body.token.hex()
        out["tdtp.nonce"] = body.nonce.hex()
    if tag:
        out["tdtp.tag"] = tag.hex()
    return out


def _session(
    writer: PcapWriter,
    addresses: tuple[tuple[object, ...], tuple[object, ...]],
    *,
    config: ConnectionConfig | None = None,
    keyed: bool = False,
    refused: bool = False,
) -> Pair:
    pair = Pair(
        config,
        config,
        master_key=KEY if keyed or refused else None,
        slave_keys=[KEY] if keyed else None,
    )
    pair.capture, pair.addresses = writer, addresses
    pair.capture_epoch += writer.packets  # keep the sessions apart in time
    pair.open(timeout=0.3)
    if refused:
        return pair
    pair.start_samples(1000, 1000)
    pair.master.conn.send_control(b"mode 2", now=pair.now)  # a MESSAGE, answered by MESSAGE_ACK
    pair.run_for(0.03)
    pair.slave.conn.send_control(b"ready", now=pair.now)
    pair.master.conn.send_control(b"go", now=pair.now)
    pair.slave.rate = 0.0  # the reverse flow stops: stand-alone ACKs
    pair.run_for(0.03)
    pair.master.rate = 0.0
    pair.run_for(0.3)  # both idle: KEEPALIVEs
    pair.master.conn.close(now=pair.now)
    pair._flush(pair.master)
    return pair


def _build(path: Path) -> tuple[dict[int, bool], dict[int, str]]:
    """A capture with every packet type, keyed and not, and malformed packets. Returns which
    frames (1-based) are keyed sessions' and the expert message each malformed frame must show."""
    malformed: dict[int, str] = {}
    with PcapWriter(path) as writer:
        pair = _session(writer, UNKEYED)

        def inject(datagram: bytes, message: str, target: Pair = pair) -> None:
            target.inject(datagram, to_slave=True, source=MASTER_ADDR)
            malformed[writer.packets] = message

        inject(b"\x00\x01\x02", "Truncated")
        inject(encode_header(3, 1, 0, 0, 255) + b"x", "TYPE 3 is reserved")
        inject(encode_header(0, 1, 0, 0, 255), "DATA without payload")
        inject(encode_header(0, 1, 5, 1, 255) + b"x", "HOLD 255 (no acknowledgement) with ACK")
        # Path validation: a challenge to the master, its response to the slave.
        token = bytes(range(16, 32))
        challenge = encode_header(2, 0, 0, 0, 255) + encode_path_challenge(token)
        pair.inject(challenge, to_slave=False, source=SLAVE_ADDR)
        response = encode_path_response(token, pair.master.conn.master_nonce)
        pair.inject(encode_header(2, 0, 0, 0, 255) + response, to_slave=True, source=MASTER_ADDR)
        inject(encode_header(2, 1, 0, 0, 255) + b"\x0c", "Unknown control code")
        inject(encode_header(2, 1, 0, 0, 255) + b"\x0a\x00\x01\x00\x02", "Malformed control")
        inject(encode_header(2, 1, 0, 0, 255) + b"\x0b\x00", "Malformed control packet")
        inject(encode_header(2, 1, 0, 0, 255) + b"\x03\x00", "Malformed control packet")
        inject(encode_header(2, 0, 0, 0, 255) + b"\x07" + bytes(20), "Malformed control packet")
        open_body = OpenBody(PROTOCOL_VERSION, 0, 0, 0, 0, bytes(16), bytes(8), bytes(16))
        inject(encode_header(2, 1, 0, 0, 255) + encode_open(open_body), "max_payload 0")
        open_body = OpenBody(PROTOCOL_VERSION, 4, 0, 100, 0, bytes(16), bytes(8), bytes(16))
        inject(encode_header(2, 1, 0, 0, 255) + encode_open(open_body), "Inconsistent flags")
        separate = _session(
            writer, SEPARATE, config=ConnectionConfig(ack_mode=AckMode.SEPARATE, ack_size=12)
        )
        inject(encode_header(1, 1, 2, 3, 0) + b"\x01" * 7, "ACK padding is not zero", separate)
        first_keyed = writer.packets + 1
        # Stamps now and then (keyed TIMESTAMPs, TIMED_DATA), and plain keyed ACKs between them.
        keyed = _session(
            writer, KEYED, config=ConnectionConfig(timestamp_interval=0.05), keyed=True
        )
        inject(encode_header(0, 1, 0, 0, 255) + bytes(10), "Too short for packet number", keyed)
        last_keyed = writer.packets
        _session(writer, REFUSED, refused=True)
    keyed_frames = {
        frame: first_keyed <= frame <= last_keyed for frame in range(1, last_keyed + 99)
    }
    return keyed_frames, malformed


def test_every_packet_type_field_by_field(tmp_path: Path) -> None:
    path = tmp_path / "all.pcap"
    keyed_frames, malformed = _build(path)
    _, records = read_pcap(path)
    rows = tshark_fields(
        path, ["frame.protocols", "_ws.expert.message", *FIELDS], *HEURISTICS_FIRST, home=tmp_path
    )
    assert len(rows) == len(records) > 300
    codes_seen: set[str] = set()
    types_seen: set[tuple[str, bool]] = set()
    for frame, (record, row) in enumerate(zip(records, rows, strict=True), start=1):
        assert row[0].endswith(":tdtp"), (frame, row[0])
        datagram = udp_payload(record.packet)
        if frame in malformed:
            assert malformed[frame] in row[1], (frame, row[1])
            continue
        keyed = keyed_frames[frame]
        got = dict(zip(FIELDS, row[2:], strict=True))
        assert got == expected_fields(datagram, keyed), frame
        assert "Malformed" not in row[1] and "Inconsistent" not in row[1], (frame, row[1])
        types_seen.add((got["tdtp.type"], keyed))
        codes_seen.add(got["tdtp.code"])
    # Every packet type and control code appeared, keyed and not.
    assert {("0", False), ("1", False), ("2", False), ("0", True), ("1", True), ("2", True)} <= (
        types_seen
    )
    assert {"1", "2", "3", "4", "5", "6", "8", "9", "10", "11", "15", "16"} <= codes_seen


def test_the_port_preference_claims_a_port_another_dissector_owns(tmp_path: Path) -> None:
    path = tmp_path / "port.pcap"
    with PcapWriter(path) as writer:
        pair = Pair()
        pair.capture, pair.addresses = writer, UNKEYED
        pair.open()
        pair.start_samples(1000, 1000)
        pair.run_for(0.01)
    default = tshark_fields(path, ["frame.protocols"], home=tmp_path)
    assert any("hcrt" in row[0] for row in default)  # UDP 47000 is HCrt's by default
    for prefs in (("-o", "tdtp.ports:47000"), HEURISTICS_FIRST):
        rows = tshark_fields(path, ["frame.protocols"], *prefs, home=tmp_path)
        assert all(row[0].endswith(":tdtp") for row in rows), prefs
    # Without the handshake (a capture started mid-session) only the preference finds it.
    _, records = read_pcap(path)
    late = tmp_path / "late.pcap"
    with PcapWriter(late) as writer:
        for record in records[6:]:  # from the first DATA on
            packet = record.packet
            datagram = udp_payload(packet)
            to_slave = int.from_bytes(packet[22:24], "big") == 47000
            ends = UNKEYED if to_slave else UNKEYED[::-1]
            writer.write_udp(ends[0], ends[1], datagram, record.seconds)
    rows = tshark_fields(late, ["frame.protocols"], *HEURISTICS_FIRST, home=tmp_path)
    assert not any(row[0].endswith(":tdtp") for row in rows)
    rows = tshark_fields(late, ["frame.protocols"], "-o", "tdtp.ports:47000", home=tmp_path)
    assert all(row[0].endswith(":tdtp") for row in rows)


def test_a_demo_session_capture_decodes_field_by_field(tmp_path: Path) -> None:
    """`tdtp demo --pcap` on loopback: every frame of the master's socket, through tshark."""
    path = tmp_path / "demo.pcap"
    done = subprocess.run(
        [sys.executable, "-m", "tdtp", "demo", "--duration", "1", "--pcap", str(path), "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    _, records = read_pcap(path)
    assert summary["pcap"] == {"file": str(path), "packets": len(records), "error": None}
    rows = tshark_fields(
        path, ["frame.protocols", "_ws.expert.message", *FIELDS], *HEURISTICS_FIRST, home=tmp_path
    )
    assert len(rows) == len(records)
    kinds: set[str] = set()
    for frame, (record, row) in enumerate(zip(records, rows, strict=True), start=1):
        assert row[0].endswith(":tdtp"), (frame, row[0])
        assert row[1] == "", (frame, row[1])  # nothing malformed in a real session
        got = dict(zip(FIELDS, row[2:], strict=True))
        assert got == expected_fields(udp_payload(record.packet), keyed=False), frame
        kinds.add(got["tdtp.code"] or got["tdtp.type"])
    sent = summary["master_to_slave"]["packets_sent"]
    data_frames = sum(1 for row in rows if row[2] == "0")
    assert data_frames >= sent  # the master's DATA, plus the slave's it received
    assert {"0", "1", "6", "2"} <= kinds  # DATA, OPEN, COOKIE, OPEN_ACK at least


def test_the_rendezvous_messages_and_a_relayed_session_decode(tmp_path: Path) -> None:
    """REGISTER claims an endpoint's address pair with its relay (so the sessions it forwards are
    TDTP too); every rendezvous message decodes field by field, the SLAVE_DIALS flag included."""
    from tdtp.wire.control import OpenBody, OpenFlags, encode_open
    from tdtp.wire.rendezvous import (
        PROBE,
        PROBE_ACK,
        ReferralBody,
        RegisterBody,
        encode_probe,
        encode_referral,
        encode_register,
    )

    endpoint, relay = ("192.0.2.9", 40009), ("192.0.2.10", 7700)
    nonce, rid = bytes(range(16)), bytes(range(16, 32))
    register = encode_register(RegisterBody(1, nonce, rid, bytes(16), (("192.168.1.2", 40009),)))
    peer = ReferralBody(2, 0, nonce, bytes(16), 30, endpoint, ("203.0.113.2", 5000), False, ())
    opening = encode_header(2, 7, 0, 0, 255) + encode_open(
        OpenBody(
            PROTOCOL_VERSION, int(OpenFlags.SLAVE_DIALS), 0, 1200, 0, nonce, bytes(8), bytes(16)
        )
    )
    datagrams = [
        (endpoint, relay, register),
        (relay, endpoint, encode_referral(peer)),
        (endpoint, ("203.0.113.2", 5000), encode_probe(PROBE, b"t" * 16, b"m" * 16)),
        (("203.0.113.2", 5000), endpoint, encode_probe(PROBE_ACK, b"t" * 16, b"n" * 16)),
        (relay, endpoint, opening),  # a session forwarded by the relay
    ]
    path = tmp_path / "rendezvous.pcap"
    with PcapWriter(path) as writer:
        for number, (src, dst, datagram) in enumerate(datagrams):
            writer.write_udp(src, dst, datagram, 1.0 + number / 1000)
    fields = ["frame.protocols", "_ws.expert.message", "tdtp.code", "tdtp.rendezvous_id",
              "tdtp.referral.kind", "tdtp.probe.token", "tdtp.flags.slave_dials", "_ws.col.Info"]  # fmt: skip
    rows = tshark_fields(path, fields, *HEURISTICS_FIRST, home=tmp_path)
    assert [row[2] for row in rows] == ["21", "22", "23", "24", "1"]
    assert all(row[0].endswith(":tdtp") for row in rows[:2] + rows[4:]), rows
    assert rows[0][3] == rid.hex(":") or rows[0][3] == rid.hex()
    assert rows[1][4] == "2" and "PEER" in rows[1][7]
    assert "REGISTER listener" in rows[0][7]
    assert rows[4][6] in ("True", "1")
    assert not any("Malformed" in row[1] or "Reserved" in row[1] for row in rows), rows
