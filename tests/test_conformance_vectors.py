"""tdtp against its own conformance vectors (tests/vectors/tdtp-v4-*.json, tests/vectors/README.md).

The files are data for any implementation; this is tdtp's runner. It reads the committed files (it
never regenerates them) and checks every vector, so a change of behaviour that the vectors pin fails
here until the vectors are regenerated on purpose (tools/vectors/generate.py) and the diff reviewed.
"""

from __future__ import annotations

import hmac
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tdtp.protection.derivation import (
    TrafficSecret,
    derive_key_id,
    derive_open_secret,
    derive_session_secrets,
)
from tdtp.protection.keys import PresharedKey
from tdtp.protection.packet_protection import Direction, PacketOpener, PacketSealer
from tdtp.rendezvous.relay import RelayCore
from tdtp.rendezvous.settings import meeting
from tdtp.session.receive_window import ReceiveWindow
from tdtp.session.recovery import loss_delay_of
from tdtp.session.rtt import RttEstimator
from tdtp.session.sent_log import LostPacket, SentPacketLog
from tdtp.session.stats import DropReason
from tdtp.wire import (
    CipherSuite,
    ControlCode,
    decode_control,
    decode_header,
    decode_hold,
    encode_header,
    encode_hold,
    expand_seq,
)
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.rendezvous import (
    PROBE,
    REGISTER,
    ReferralKind,
    decode_probe,
    decode_referral,
    decode_register,
)

VECTORS = Path(__file__).resolve().parent / "vectors"
sys.path.insert(0, str(VECTORS))

from tdtp_adapter import ScriptRunner, ServerRunner  # noqa: E402

FORMAT_VERSION = 1
SUITES = (
    "header",
    "hold",
    "seqnum",
    "control",
    "receiver",
    "sender",
    "keyed",
    "endpoint",
    "server",
    "rendezvous",
)


def _load(suite: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads(
        (VECTORS / f"tdtp-v4-{suite}.json").read_text(encoding="utf-8")
    )
    return data


def _approx(value: float | None) -> object:
    return None if value is None else pytest.approx(value, rel=1e-9, abs=1e-12)


def test_every_file_is_a_known_format_version_and_suite() -> None:
    files = sorted(path.name for path in VECTORS.glob("tdtp-v4-*.json"))
    assert files == sorted(f"tdtp-v4-{suite}.json" for suite in SUITES)
    for suite in SUITES:
        data = _load(suite)
        assert data["format"] == "tdtp-conformance-vectors"
        assert data["format_version"] == FORMAT_VERSION
        assert data["protocol_version"] == 4
        assert data["suite"] == suite
        assert data["description"]


# ---------------------------------------------------------------------------- stateless suites


def check_header(data: dict[str, Any]) -> int:
    for vector in data["valid"]:
        raw = bytes.fromhex(vector["hex"])
        fields = (vector["type"], vector["seq"], vector["ack"], vector["sack"], vector["hold"])
        assert tuple(decode_header(raw)) == fields, vector["name"]
        assert tuple(decode_header(raw + b"trailing payload")) == fields
        assert encode_header(*fields) == raw, vector["name"]
    for vector in data["invalid"]:
        with pytest.raises(MalformedPacketError) as caught:
            decode_header(bytes.fromhex(vector["hex"]))
        assert caught.value.reason == vector["error"]
    return len(data["valid"]) + len(data["invalid"])


def check_hold(data: dict[str, Any]) -> int:
    assert [vector["code"] for vector in data["decode"]] == list(range(256))
    for vector in data["decode"]:
        decoded = decode_hold(vector["code"])
        if vector["hold_ns"] is None:
            assert decoded is None
        else:
            assert decoded is not None and round(decoded * 1e9) == vector["hold_ns"]
    for vector in data["encode"]:
        assert encode_hold(vector["hold_ns"] / 1e9) == vector["code"], vector
    return len(data["decode"]) + len(data["encode"])


def check_seqnum(data: dict[str, Any]) -> int:
    for vector in data["expand"]:
        assert expand_seq(vector["truncated"], vector["expected"]) == vector["full"], vector
    for vector in data["ack_expand"]:
        log = SentPacketLog(vector["first_seq"], reorder_threshold=3, max_tracked=100_000)
        lost: list[LostPacket] = []
        for i in range(vector["packets_sent"]):
            log.on_sent(i * 0.001, 10, lost)
        if vector["largest_acked"] is not None:
            log.on_ack(vector["largest_acked"], 0, None, 1.0)
        full = log.expand_ack(vector["ack"], None, 1.0, 0.1)
        assert full == vector["full"], vector["name"]
        assert (full is None) == vector["optimistic"]
    return len(data["expand"]) + len(data["ack_expand"])


def check_control(data: dict[str, Any]) -> int:
    for vector in data["valid"]:
        body = bytes.fromhex(vector["body_hex"])
        assert vector["datagram_hex"].endswith(vector["body_hex"])
        decoded = decode_control(body)
        assert ControlCode(body[0]).name == vector["code"]
        fields = {
            name: [tag.hex() for tag in value]
            if isinstance(value, tuple)
            else value.hex()
            if isinstance(value, bytes)
            else int(value)
            for name, value in decoded._asdict().items()
            if name != "code"
        }
        assert fields == vector["fields"], vector["name"]
    for vector in data["invalid"]:
        with pytest.raises(MalformedPacketError) as caught:
            decode_control(bytes.fromhex(vector["body_hex"]))
        assert caught.value.reason == vector["error"], vector["name"]
    return len(data["valid"]) + len(data["invalid"])


# ---------------------------------------------------------------------------- receiver and sender


def check_receiver(data: dict[str, Any]) -> int:
    checked = 0
    for case in data["cases"]:
        window = ReceiveWindow(case["initial_seq"])
        for event in case["events"]:
            kind = event.get("event")
            if kind in ("piggyback", "ack_delay"):
                due = (
                    window.has_data if kind == "piggyback" else window.unreported_since is not None
                )
                acks = []
                if due:
                    acks = [[window.highest, window.sack_below(window.highest)]]
                    window.mark_reported()
                assert acks == event["acks"], (case["name"], event)
            else:
                arrival, full, gap = window.on_data(event["seq"], event.get("at", 0.0))
                assert (arrival.value, full, gap) == (event["kind"], event["full"], event["gap"])
                acks = [[held.ack, held.sack] for held in window.take_held()]
                if window.coverage_exhausted():
                    acks.append([window.highest, window.sack_below(window.highest)])
                    window.mark_reported()
                assert acks == event["acks"], (case["name"], event)
            checked += 1
    return checked


def check_sender(data: dict[str, Any]) -> int:
    checked = 0
    for case in data["cases"]:
        log = SentPacketLog(
            case["first_seq"], reorder_threshold=case["reorder_threshold"], max_tracked=16384
        )
        rtt = RttEstimator(case["initial_rtt"])
        lost: list[LostPacket] = []
        for packet in case["sent"]:
            assert log.on_sent(packet["at"], 100, lost) == packet["seq"]

        ack_delay = case["ack_delay"]
        # PROTOCOL.md 5.4: computed at the start and after each RTT sample, kept in between.
        delay = loss_delay_of(rtt, log.reorder_window_scale, ack_delay)
        for event in case["events"]:
            expect = event["expect"]
            at = event["at"]
            lost = []
            if event.get("event") == "timer":
                log.detect_losses(at, delay, lost)
            else:
                hold = decode_hold(event["hold"])
                full = log.expand_ack(event["ack"], hold, at, rtt.srtt)
                assert (full is None) == expect["optimistic"], case["name"]
                if full is None:
                    checked += 1
                    continue
                assert full == expect["ack_full"]
                outcome = log.on_ack(full, event["sack"], hold, at)
                if outcome.rtt_sample is not None:
                    rtt.on_sample(outcome.rtt_sample)
                    delay = loss_delay_of(rtt, log.reorder_window_scale, ack_delay)
                log.detect_losses(at, delay, lost)
                assert outcome.newly_acked == expect["newly_acked"], case["name"]
                assert outcome.rtt_sample == _approx(expect["rtt_sample"])
                assert outcome.spurious == expect["spurious"]
                assert rtt.srtt == _approx(expect["srtt"])
                assert rtt.rttvar == _approx(expect["rttvar"])
                assert log.largest_acked == expect["largest_acked"]
            assert [packet.seq for packet in lost] == expect["lost"], (case["name"], at)
            assert log.unknown == expect["unknown_total"]
            assert delay == _approx(expect["loss_delay"]), (case["name"], at)
            assert log.loss_deadline(delay) == _approx(expect["loss_timer"])
            checked += 1
    return checked


# ---------------------------------------------------------------------------- keyed


def check_keyed(data: dict[str, Any]) -> int:
    from tdtp.protection.derivation import derive_reset_key, reset_tag
    from tdtp.wire import decode_reset

    for vector in data["reset_tags"]:
        key = derive_reset_key(bytes.fromhex(vector["psk"]))
        echo = bytes.fromhex(vector["echo"])
        assert reset_tag(key, echo).hex() == vector["tag"]
        datagram = bytes.fromhex(vector["datagram"])
        assert decode_reset(datagram[5:]).tags == (bytes.fromhex(vector["tag"]),)
    for vector in data["derivations"]:
        psk = bytes.fromhex(vector["psk"])
        suite = CipherSuite(vector["suite"])
        master, slave = bytes.fromhex(vector["master_nonce"]), bytes.fromhex(vector["slave_nonce"])
        assert derive_key_id(psk).hex() == vector["key_id"]
        assert derive_reset_key(psk).hex() == vector["reset_key"]
        open_secret = derive_open_secret(psk, master, suite)
        assert (open_secret.key.hex(), open_secret.iv.hex()) == (
            vector["open_key"],
            vector["open_iv"],
        )
        session = derive_session_secrets(psk, master, slave, suite)
        assert [
            session.master_to_slave.key.hex(),
            session.master_to_slave.iv.hex(),
            session.slave_to_master.key.hex(),
            session.slave_to_master.iv.hex(),
        ] == [vector["m2s_key"], vector["m2s_iv"], vector["s2m_key"], vector["s2m_iv"]]
    for vector in data["handshake_tags"]:
        psk, suite = bytes.fromhex(vector["psk"]), CipherSuite(vector["suite"])
        datagram = bytes.fromhex(vector["datagram_without_tag"])
        nonce = datagram[13:29]  # the master's nonce sits at the same offset in both
        if vector["message"] == "OPEN":
            secret = derive_open_secret(psk, nonce, suite)
        else:
            slave_nonce = datagram[29:45]
            secret = derive_session_secrets(psk, nonce, slave_nonce, suite).slave_to_master
        tagger = Direction(suite, secret)
        tag = bytes.fromhex(vector["tag"])
        assert tagger.tag(vector["nonce_counter"], datagram) == tag
        assert tagger.verify(vector["nonce_counter"], datagram, tag)
    for vector in data["seal"]:
        secret = TrafficSecret(bytes.fromhex(vector["key"]), bytes.fromhex(vector["iv"]))
        suite = CipherSuite(vector["suite"])
        sealer = PacketSealer(suite, secret, encrypt=vector["encrypt"])
        sealer.next_number = vector["packet_number"]
        prefix, body = bytes.fromhex(vector["prefix"]), bytes.fromhex(vector["body"])
        datagram = bytes.fromhex(vector["datagram"])
        assert sealer.seal(prefix, body) == datagram
        opener = PacketOpener(suite, secret, encrypt=vector["encrypt"])
        opener.window.highest = vector["packet_number"] - 1
        assert opener.open(datagram, len(prefix)) == body
    opening = data["opening"]
    secret = TrafficSecret(bytes.fromhex(opening["key"]), bytes.fromhex(opening["iv"]))
    opener = PacketOpener(CipherSuite(opening["suite"]), secret, encrypt=opening["encrypt"])
    for step in opening["steps"]:
        body = opener.open(bytes.fromhex(step["datagram"]), opening["prefix_size"])
        if step["verdict"] == "accepted":
            assert body is not None and body.hex() == step["body"], step["name"]
        else:
            assert body is None and opener.failure == step["verdict"], step["name"]
        assert opener.window.highest == step["highest"], step["name"]
    return (
        len(data["derivations"])
        + len(data["handshake_tags"])
        + len(data["seal"])
        + len(opening["steps"])
    )


# ---------------------------------------------------------------------------- endpoint scripts


def _check_scripts(data: dict[str, Any], runner: type[ScriptRunner] | type[ServerRunner]) -> int:
    checked = 0
    for script in data["scripts"]:
        run = runner(script)
        for number, step in enumerate(script["steps"]):
            inputs = {k: v for k, v in step.items() if k != "expect"}
            got = run.step(inputs)
            assert got == step["expect"], f"{script['name']}, step {number} at {step['at']}"
            checked += 1
    return checked


def check_endpoint(data: dict[str, Any]) -> int:
    return _check_scripts(data, ScriptRunner)


def check_server(data: dict[str, Any]) -> int:
    return _check_scripts(data, ServerRunner)


def test_the_endpoint_scripts_cover_every_drop_reason() -> None:
    covered = {
        step["expect"]["drop"]
        for script in _load("endpoint")["scripts"]
        for step in script["steps"]
        if step["expect"]["drop"] is not None
    }
    assert covered == {reason.value for reason in DropReason}


def check_rendezvous(data: dict[str, Any]) -> int:
    checked = 0
    for vector in data["names"]:
        key = None if vector["psk_hex"] is None else PresharedKey(bytes.fromhex(vector["psk_hex"]))
        met = meeting(key, vector["rendezvous_name"])
        assert met.rendezvous_id.hex() == vector["rendezvous_id_hex"], vector["name"]
        assert met.probe_key.hex() == vector["probe_key_hex"], vector["name"]
        checked += 1
    probe_key = meeting(None, "robot-7").probe_key
    for vector in data["probes"]:
        body = decode_probe(bytes.fromhex(vector["datagram_hex"]))
        tag = b"P" if body.code == PROBE else b"A"
        mac = hmac.digest(probe_key, tag + bytes([vector["side"]]) + body.token, "sha256")[:16]
        assert (body.token.hex(), body.mac) == (vector["token_hex"], mac), vector["name"]
        checked += 1
    for vector in data["valid"]:
        raw = bytes.fromhex(vector["datagram_hex"])
        body = decode_register(raw) if raw[5] == REGISTER else decode_referral(raw)
        fields = vector["fields"]
        for name, raw_value in body._asdict().items():
            value = raw_value
            if isinstance(raw_value, bytes):
                value = raw_value.hex()
            elif isinstance(raw_value, tuple):
                value = [list(item) if isinstance(item, tuple) else item for item in raw_value]
            assert value == fields[name], (vector["name"], name)
        checked += 1
    relay = RelayCore()
    for number, vector in enumerate(data["relay_answers"]):
        answers = relay.receive(
            bytes.fromhex(vector["datagram_hex"]), ("198.51.100.9", number), 0.0
        )
        if vector["answer_kind"] is None:
            assert answers == [], vector["name"]
        else:
            ((reply, _),) = answers
            assert ReferralKind(decode_referral(reply).kind).name == vector["answer_kind"]
            assert len(reply) == vector["answer_size"], vector["name"]
        checked += 1
    return checked


CHECKS: dict[str, Callable[[dict[str, Any]], int]] = {
    "header": check_header,
    "hold": check_hold,
    "seqnum": check_seqnum,
    "control": check_control,
    "receiver": check_receiver,
    "sender": check_sender,
    "keyed": check_keyed,
    "endpoint": check_endpoint,
    "server": check_server,
    "rendezvous": check_rendezvous,
}


@pytest.mark.parametrize("suite", SUITES)
def test_vectors(suite: str) -> None:
    assert CHECKS[suite](_load(suite)) >= 8  # every file holds a real set, not a token one
