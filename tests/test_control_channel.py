"""The reliable control channel in fake time (docs/PROTOCOL.md 5.10): exactly once, in order, through
loss, reordering, duplication, outages and the 16-bit wrap; bounded against a peer that never
acknowledges; attacks dropped and counted; samples never held up."""

from __future__ import annotations

import pytest

from tdtp import (
    ConnectionConfig,
    ControlChannelFailedError,
    ControlExpired,
    ControlQueueFullError,
    ControlReceived,
    EmptyPayloadError,
    InvalidArgumentError,
    PayloadTooLargeError,
    PayloadTypeError,
)
from tdtp.protection import PresharedKey
from tdtp.session.control_channel import FIRST_MESSAGE_BASE, expand_message_number
from tdtp.wire import (
    HOLD_NO_ACK,
    ControlCode,
    PacketType,
    encode_header,
    encode_message,
    encode_message_ack,
)

from pair import MASTER_ADDR, Direction, Endpoint, Pair

KEY = PresharedKey(bytes(range(32)), "station-1")


def _is_message(datagram: bytes) -> bool:
    return datagram[0] >> 6 == PacketType.CONTROL and datagram[5] == ControlCode.MESSAGE


def _is_control_channel(datagram: bytes) -> bool:
    return datagram[0] >> 6 == PacketType.CONTROL and datagram[5] in (
        ControlCode.MESSAGE,
        ControlCode.MESSAGE_ACK,
    )


def _messages(endpoint: Endpoint) -> list[ControlReceived]:
    return [event for event in endpoint.events if isinstance(event, ControlReceived)]


def _expired(endpoint: Endpoint) -> list[ControlExpired]:
    return [event for event in endpoint.events if isinstance(event, ControlExpired)]


def _opened(pair: Pair, rate: float = 1000.0, size: int = 100) -> Pair:
    pair.open()
    assert pair.established
    pair.start_samples(rate, rate, size=size)
    pair.run_for(0.1)
    return pair


def _send_every(pair: Pair, count: int, interval: float, *, both: bool = True) -> None:
    for k in range(count):
        pair.master.conn.send_control(f"m{k}".encode(), now=pair.now)
        if both:
            pair.slave.conn.send_control(f"s{k}".encode(), now=pair.now)
        pair.run_for(interval)


def _check_in_order(receiver: Endpoint, sender: Endpoint, prefix: str, count: int) -> None:
    messages = _messages(receiver)
    assert [m.index for m in messages] == list(range(count))
    assert [m.payload for m in messages] == [f"{prefix}{k}".encode() for k in range(count)]
    sent, got = sender.conn.stats, receiver.conn.stats
    assert sent.control_sent == sent.control_acked == got.control_delivered == count
    assert sender.conn.control_unacked == 0


def test_messages_arrive_once_and_in_order_through_loss_and_reordering() -> None:
    # 5 % loss each way, and one datagram in 7 held back 15 ms (reordered past later ones).
    ms = Direction(drop=lambda i: i % 20 == 7, extra_delay=lambda i: 0.015 * (i % 7 == 3))
    sm = Direction(drop=lambda i: i % 20 == 13, extra_delay=lambda i: 0.015 * (i % 7 == 5))
    pair = _opened(Pair(ms=ms, sm=sm))
    _send_every(pair, 200, 0.05)
    pair.drain(3.0)
    _check_in_order(pair.slave, pair.master, "m", 200)
    _check_in_order(pair.master, pair.slave, "s", 200)
    assert pair.master.conn.stats.control_retransmits > 0  # losses were repaired
    assert not _expired(pair.master) and not _expired(pair.slave)


def test_lost_messages_are_retransmitted_on_the_session_loss_delay() -> None:
    """Every first transmission of a MESSAGE is lost: each is delivered by its retransmission,
    about one loss delay (srtt + reorder allowance + the peer's ACK delay) later."""
    seen: set[bytes] = set()

    def first_copy(datagram: bytes) -> bool:
        if not _is_message(datagram):
            return False
        key = datagram[6:8]  # the message number
        if key in seen:
            return False
        seen.add(key)
        return True

    pair = _opened(Pair(ms=Direction(drop_datagram=first_copy)))
    loss_delay = pair.master.conn._recovery.loss_delay
    sent_at = pair.now
    pair.master.conn.send_control(b"stop", now=pair.now)
    pair.run_for(1.0)
    (message,) = _messages(pair.slave)
    assert message.payload == b"stop"
    assert loss_delay <= message.received_at - sent_at <= loss_delay + 0.05
    assert pair.master.conn.stats.control_retransmits == 1


def test_samples_keep_flowing_while_a_message_is_outstanding() -> None:
    """No head-of-line blocking: while every MESSAGE is lost for a second, samples arrive as before."""
    blackout = [True]
    pair = _opened(Pair(ms=Direction(drop_datagram=lambda d: blackout[0] and _is_message(d))))
    pair.master.conn.send_control(b"mode 2", now=pair.now)
    before = pair.slave.conn.stats.samples_delivered
    pair.run_for(1.0)
    assert not _messages(pair.slave)
    assert pair.master.conn.control_unacked == 1
    assert pair.slave.conn.stats.samples_delivered - before >= 950  # ~1000 samples in that second
    blackout[0] = False
    pair.run_for(1.5)
    assert [m.payload for m in _messages(pair.slave)] == [b"mode 2"]


def test_duplicates_are_delivered_once_and_acknowledged_again() -> None:
    pair = _opened(Pair())
    pair.ms.keep_wire = True
    pair.master.conn.send_control(b"gripper close", now=pair.now)
    pair.run_for(0.1)
    copies = [d for d in pair.ms.wire if _is_message(d)]
    assert len(copies) == 1
    for _ in range(3):
        pair.inject(copies[0], to_slave=True, source=MASTER_ADDR)
    pair.run_for(0.1)
    assert [m.payload for m in _messages(pair.slave)] == [b"gripper close"]
    stats = pair.slave.conn.stats
    assert stats.control_dropped == {"duplicate": 3} and stats.drops["duplicate"] >= 3
    assert stats.control_delivered == 1


def test_the_16_bit_wrap_is_crossed_in_order() -> None:
    """The first message number is 0xF000 | ISN: every session crosses the wrap within 4096
    messages. 6000 messages each way, as fast as the window allows."""
    config = ConnectionConfig(control_max_rate=100_000.0)
    pair = _opened(Pair(config, config, ms=Direction(drop=lambda i: i % 50 == 9)), rate=100.0)
    first = pair.master.conn._channel._first
    assert first >> 12 == FIRST_MESSAGE_BASE >> 12
    total = 6000
    queued = {"master": 0, "slave": 0}
    while min(queued.values()) < total:
        for name, endpoint in (("master", pair.master), ("slave", pair.slave)):
            try:
                while queued[name] < total:
                    endpoint.conn.send_control(queued[name].to_bytes(4, "big"), now=pair.now)
                    queued[name] += 1
            except ControlQueueFullError:
                pass
        pair.run_for(0.02)
    pair.drain(3.0)
    for receiver in (pair.slave, pair.master):
        messages = _messages(receiver)
        assert [int.from_bytes(m.payload, "big") for m in messages] == list(range(total))
        assert [m.index for m in messages] == list(range(total))
    assert pair.master.conn._channel._next > 0x10000  # past the wrap


def test_expand_message_number_is_nearest() -> None:
    assert expand_message_number(0x0002, 0xFFFE) == 0x10002
    assert expand_message_number(0xFFFE, 0x10002) == 0xFFFE
    assert expand_message_number(0x1234, 0x31234) == 0x31234


def test_a_peer_that_never_acknowledges_cannot_grow_our_buffers() -> None:
    """Every MESSAGE_ACK and MESSAGE from the slave is lost: the master holds at most
    control_window messages, refuses more with ControlQueueFullError, probes at a backed-off pace
    within the rate cap, and gives up at control_timeout with one ControlExpired."""
    config = ConnectionConfig(control_window=8, control_timeout=5.0)
    pair = _opened(Pair(config, config, sm=Direction(drop_datagram=_is_control_channel)))
    master = pair.master.conn
    for k in range(8):
        master.send_control(bytes([k]), now=pair.now)
    with pytest.raises(ControlQueueFullError, match="control_window"):
        master.send_control(b"one more", now=pair.now)
    assert master.control_unacked == 8
    pair.run_for(4.9)
    stats = master.stats
    # 8 first transmissions, one round of retransmissions at the first timeout, then one probe per
    # backed-off interval (doubling up to 1 s): far below the 200/s cap.
    assert stats.control_transmissions <= 8 + 8 + 12
    assert not _expired(pair.master)
    pair.run_for(0.2)
    (expired,) = _expired(pair.master)
    assert expired.first_index == 0
    assert expired.payloads == tuple(bytes([k]) for k in range(8))
    assert "5 s" in expired.detail
    assert stats.control_given_up == 8 and master.control_unacked == 0
    with pytest.raises(ControlChannelFailedError, match="not acknowledged"):
        master.send_control(b"after", now=pair.now)
    # The slave delivered each message once, however often it came (its ACKs were what was lost).
    assert [m.payload for m in _messages(pair.slave)] == [bytes([k]) for k in range(8)]
    # Samples went on throughout.
    assert pair.slave.conn.stats.samples_delivered > 4000


def test_the_rate_cap_paces_messages() -> None:
    config = ConnectionConfig(control_max_rate=50.0)
    pair = _opened(Pair(config, config))
    start = pair.now
    for k in range(40):
        pair.master.conn.send_control(bytes([k]), now=pair.now)
    pair.run_for(2.0)
    messages = _messages(pair.slave)
    assert len(messages) == 40
    # A burst of 8, then 50 a second: the 40th leaves about (40 - 8) / 50 = 0.64 s after the first.
    assert 0.6 <= messages[-1].received_at - start <= 0.7


def test_an_application_that_does_not_read_holds_the_peer_back() -> None:
    """Unread messages count against the receive bound: past it MESSAGEs are dropped unacknowledged
    (control_backlog) and retransmitted once the application reads."""
    config = ConnectionConfig(control_window=4)
    pair = _opened(Pair(config, config))
    slave = pair.slave.conn
    slave.control_held(4)  # a driver's application has 4 unread messages
    for k in range(3):
        pair.master.conn.send_control(bytes([k]), now=pair.now)
    pair.run_for(0.5)
    assert not _messages(pair.slave)
    assert slave.stats.control_dropped.get("control_backlog", 0) >= 3
    slave.control_held(0)
    pair.run_for(2.0)
    assert [m.payload for m in _messages(pair.slave)] == [b"\x00", b"\x01", b"\x02"]


def test_a_ten_second_outage_is_ridden_out() -> None:
    """Both directions dead for 10 s while messages are sent: all arrive after it, in order, none
    given up (control_timeout 20 s), and the probes during it stay few."""
    dead = [False]
    pair = _opened(Pair(ms=Direction(drop=lambda _: dead[0]), sm=Direction(drop=lambda _: dead[0])))
    _send_every(pair, 5, 0.05)
    dead[0] = True
    before = pair.master.conn.stats.control_transmissions
    for k in range(5, 25):
        pair.master.conn.send_control(f"m{k}".encode(), now=pair.now)
        pair.slave.conn.send_control(f"s{k}".encode(), now=pair.now)
        pair.run_for(0.5)
    during = pair.master.conn.stats.control_transmissions - before
    assert during <= 40  # the first copies, then one probe per backed-off second
    dead[0] = False
    pair.drain(5.0)
    _check_in_order(pair.slave, pair.master, "m", 25)
    _check_in_order(pair.master, pair.slave, "s", 25)
    assert not _expired(pair.master) and not _expired(pair.slave)


def test_keyed_replays_are_refused_and_messages_arrive_once() -> None:
    pair = Pair(master_key=KEY, slave_keys=[KEY], ms=Direction(drop=lambda i: i % 25 == 4))
    pair.ms.keep_wire = True
    _opened(pair)
    _send_every(pair, 30, 0.03, both=False)
    pair.drain(1.0)
    _check_in_order(pair.slave, pair.master, "m", 30)
    replayed_before = pair.slave.conn.stats.drops.get("replayed", 0)
    recorded = [d for d in pair.ms.wire if _is_message(d)]
    assert recorded
    for datagram in recorded:
        pair.inject(datagram, to_slave=True, source=MASTER_ADDR)
    assert pair.slave.conn.stats.drops["replayed"] - replayed_before == len(recorded)
    assert len(_messages(pair.slave)) == 30
    # A forged MESSAGE (a packet number never used, any tag) does not authenticate.
    last = recorded[-1]
    number = (int.from_bytes(last[6:8], "big") + 100) & 0xFFFF
    forged = last[:6] + number.to_bytes(2, "big") + last[8:]
    pair.inject(forged, to_slave=True, source=MASTER_ADDR)
    assert pair.slave.conn.stats.drops.get("unauthenticated", 0) >= 1
    assert len(_messages(pair.slave)) == 30


def _unkeyed_message(seq: int, ack: int, data: bytes, nonce: bytes) -> bytes:
    header = encode_header(PacketType.CONTROL, 0, 0, 0, HOLD_NO_ACK)
    return header + encode_message(nonce, seq, ack, data)


@pytest.mark.parametrize(
    ("name", "reason"),
    [
        ("empty", "bad_control"),
        ("oversized", "oversized"),
        ("optimistic", "optimistic_ack"),
        ("far_ahead", "control_window"),
        ("short_ack", "bad_control"),
        ("optimistic_ack_alone", "optimistic_ack"),
        ("another_nonce", "nonce_mismatch"),
        ("ack_with_another_nonce", "nonce_mismatch"),
    ],
)
def test_malformed_and_forged_messages_are_dropped_and_counted(name: str, reason: str) -> None:
    pair = _opened(Pair())
    slave = pair.slave.conn
    expected = slave._channel._expected  # the next message number the slave expects
    ours = slave._channel._acked_below  # the slave's own next number: nothing sent yet
    header = encode_header(PacketType.CONTROL, 0, 0, 0, HOLD_NO_ACK)
    nonce = slave.master_nonce
    other = bytes(16)
    datagram = {
        "empty": header + encode_message(nonce, expected, ours, b"")[:21],
        "oversized": _unkeyed_message(expected, ours, bytes(257), nonce),
        "optimistic": _unkeyed_message(expected, ours + 5, b"x", nonce),
        "far_ahead": _unkeyed_message(expected + 64, ours, b"x", nonce),
        "short_ack": header + encode_message_ack(nonce, ours)[:18],
        "optimistic_ack_alone": header + encode_message_ack(nonce, ours + 1),
        # What an off-path attacker sends: it does not know the master's nonce (PROTOCOL.md 5.10).
        "another_nonce": _unkeyed_message(expected, ours, b"x", other),
        "ack_with_another_nonce": header + encode_message_ack(other, ours),
    }[name]
    before = dict(slave.stats.drops)
    pair.inject(datagram, to_slave=True, source=MASTER_ADDR)
    assert slave.stats.drops.get(reason, 0) == before.get(reason, 0) + 1
    assert slave.stats.control_dropped == {reason: 1}
    assert not _messages(pair.slave)
    # The channel still works afterwards.
    pair.master.conn.send_control(b"ok", now=pair.now)
    pair.run_for(0.2)
    assert [m.payload for m in _messages(pair.slave)] == [b"ok"]


def test_a_forged_message_in_the_window_from_another_address_is_refused() -> None:
    pair = _opened(Pair())
    expected = pair.slave.conn._channel._expected
    forged = _unkeyed_message(expected, 0, b"evil", pair.slave.conn.master_nonce)
    pair.inject(forged, to_slave=True, source=("203.0.113.9", 1))
    assert pair.slave.conn.stats.drops["wrong_address"] == 1
    assert not _messages(pair.slave)


def test_misuse_raises_specific_errors() -> None:
    pair = Pair()
    with pytest.raises(Exception, match="wait for the ConnectionEstablished"):
        pair.master.conn.send_control(b"x", now=0.0)
    _opened(pair)
    conn = pair.master.conn
    with pytest.raises(EmptyPayloadError):
        conn.send_control(b"", now=pair.now)
    with pytest.raises(PayloadTooLargeError, match="control_max_message"):
        conn.send_control(bytes(257), now=pair.now)
    with pytest.raises(PayloadTypeError, match="encode"):
        conn.send_control("text", now=pair.now)  # type: ignore[arg-type]
    conn.send_control(bytearray(b"ok"), now=pair.now)
    conn.close(now=pair.now)
    with pytest.raises(Exception, match="closed"):
        conn.send_control(b"x", now=pair.now)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("control_max_message", 0),
        ("control_max_message", 5000),
        ("control_window", 0),
        ("control_window", 40000),
        ("control_max_rate", 0.0),
        ("control_max_rate", float("inf")),
        ("control_timeout", -1.0),
        ("control_timeout", float("nan")),
    ],
)
def test_config_is_validated(field: str, value: float) -> None:
    with pytest.raises(InvalidArgumentError, match=field):
        ConnectionConfig(**{field: value})  # type: ignore[arg-type]


def test_a_large_control_message_fits_a_small_max_payload() -> None:
    """The receive size check admits a full control message even where samples are tiny."""
    config = ConnectionConfig(max_payload=16, control_max_message=1000)
    pair = _opened(Pair(config, config), size=16)
    pair.master.conn.send_control(bytes(1000), now=pair.now)
    pair.run_for(0.2)
    assert [len(m.payload) for m in _messages(pair.slave)] == [1000]


def test_random_control_input_never_raises_and_never_delivers_twice() -> None:
    """Thousands of random MESSAGE and MESSAGE_ACK datagrams from the master's address (numbers
    near the expected ones, random lengths; unkeyed, so the ones that fit are taken as the master's):
    every one is taken in or dropped and counted, never raised, and the messages delivered stay
    consecutive."""
    import random

    rng = random.Random(21)
    pair = _opened(Pair())
    slave = pair.slave.conn
    channel = slave._channel
    header = encode_header(PacketType.CONTROL, 0, 0, 0, HOLD_NO_ACK)
    for _ in range(3000):
        code = rng.choice((ControlCode.MESSAGE, ControlCode.MESSAGE_ACK))
        seq = (channel._expected + rng.randrange(-70, 70)) & 0xFFFF
        ack = (channel._acked_below + rng.randrange(-3, 3)) & 0xFFFF
        body = bytes([code]) + seq.to_bytes(2, "big") + ack.to_bytes(2, "big")
        body += rng.randbytes(rng.randrange(0, 300))
        if rng.random() < 0.3:
            body = body[: rng.randrange(0, len(body) + 1)]
        before = slave.stats.datagrams_in
        pair.inject(header + body, to_slave=True, source=MASTER_ADDR)
        assert slave.stats.datagrams_in == before + 1
    stats = slave.stats
    assert stats.datagrams_in == stats.received.datagrams + stats.dropped
    indices = [m.index for m in _messages(pair.slave)]
    assert indices == list(range(len(indices)))
    assert stats.control_delivered == len(indices)
