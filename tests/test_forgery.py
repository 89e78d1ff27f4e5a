"""Issue 31's forgeries in fake time: each costs no more than the forged datagrams (PROTOCOL.md 5.5,
5.7, 5.8, 5.9, 5.10; SECURITY.md). Every attack here ended a session, silenced a stream, delivered
forged control messages or moved a session to a victim in version 3; each drop is counted.

The slave's front for datagrams from addresses no session holds (path migration, then a RESET for
what no session can own) is driven as a server drives it (``_Front``)."""

from __future__ import annotations

import random
import struct

import pytest

from tdtp import CloseCause, Connection, ConnectionClosed, ConnectionConfig, Role, State
from tdtp.admission import Admission
from tdtp.admission.slots import EvictionNotices
from tdtp.protection.keys import PresharedKey, as_key_ring
from tdtp.session.events import ControlReceived
from tdtp.wire import ControlCode, PacketType, encode_header, encode_path_response
from tdtp.wire.hold import HOLD_NO_ACK

from pair import MASTER_ADDR, SLAVE_ADDR, Pair

KEY = PresharedKey(bytes(range(32)), name="operator")
STRANGER = ("198.51.100.7", 666)
VICTIM = ("203.0.113.9", 9999)
_CONTROL_HEADER = encode_header(int(PacketType.CONTROL), 0, 0, 0, HOLD_NO_ACK)
Address = tuple[str, int]


class _Front:
    """A slave server's front door in fake time: its admission (with the keys) and path migration,
    answering what no session can own with a RESET, as tdtp.aio.server does."""

    def __init__(self, pair: Pair, keyed: bool) -> None:
        self.admission = Admission(
            ConnectionConfig(), as_key_ring([KEY]) if keyed else None, rng=random.Random(7)
        )
        pair.migration = self.admission.paths
        self.pair = pair
        self.resets = 0

    def unattached(self, data: bytes, source: Address) -> bytes | None:
        """What the server sends back to ``source`` (a PATH_CHALLENGE or a RESET), if anything."""
        pair = self.pair
        paths = self.admission.paths
        outcome = paths.on_unattached(data, source, pair.now, [pair.slave.conn])
        if isinstance(outcome, bytes):
            return outcome
        if outcome is None and paths.unclaimed:
            reset = self.admission.reset(data, pair.now)
            self.resets += reset is not None
            return reset
        pair._flush(pair.slave)  # it moved: what it sends now goes to its new address
        return None


def _closes(pair: Pair) -> list[ConnectionClosed]:
    return [event for event in pair.master.events if isinstance(event, ConnectionClosed)]


def _newest_data(pair: Pair, back: int = 1) -> bytes:
    """A DATA, or a TIMED_DATA (a sample with its sender's clock: at 100 Hz every sample is one)."""
    return [
        d
        for d in pair.ms.wire
        if d[0] >> 6 == PacketType.DATA or (d[0] >> 6 == PacketType.CONTROL and d[5] == 16)
    ][-back]


# ---------------------------------------------------------------------- RESET is no oracle


def test_a_datagram_replayed_to_its_own_slave_draws_no_reset() -> None:
    """Keyed, the master at 100 Hz (its session is quiet between samples). A copy of its newest
    datagram from a fresh address authenticates under the session's keys at a packet number
    already accepted: it belongs to the live session, so the slave neither moves nor answers it
    (``replayed``), where version 3 signed a RESET that ended the session."""
    pair = Pair(master_key=KEY, slave_keys=[KEY])
    pair.ms.keep_wire = True
    front = _Front(pair, keyed=True)
    pair.open()
    pair.start_samples(100, 0)
    pair.run_for(0.1)
    for _ in range(40):
        pair.run_for(0.0071)  # at various phases of the 10 ms period
        # A copy of a datagram the slave has (the newest may still be on its way: a copy that
        # overtakes it moves the session, under the 3x limit, and back: test_path_migration).
        answer = front.unattached(_newest_data(pair, back=2), STRANGER)
        if answer is not None:
            pair.inject(answer, to_slave=False, source=SLAVE_ADDR)
    assert front.resets == 0
    assert front.admission.paths.stats.drops.get("replayed", 0) > 0
    assert pair.master.conn.state is State.ESTABLISHED and not _closes(pair)
    assert pair.slave.conn.peer == MASTER_ADDR


@pytest.mark.parametrize("master_rate", [1000, 100, 0])
def test_a_second_slave_holding_the_key_cannot_end_the_session(master_rate: int) -> None:
    """A second slave with the same key has no session for the master, so it signs a RESET for any
    copy of the master's datagrams. The master takes a RESET only from a slave it has not heard
    for its silence_timeout (PROTOCOL.md 5.7): its own slave keeps talking, so every relayed RESET
    is dropped (``peer_alive``) and no session ends."""
    pair = Pair(master_key=KEY, slave_keys=[KEY])
    pair.ms.keep_wire = True
    pair.open()
    pair.start_samples(master_rate, 0)  # the slave sends no samples: keep-alives and ACKs only
    second = Connection(role=Role.SLAVE, rng=random.Random(9), keys=[KEY])
    relayed = 0
    for step in range(100):
        pair.run_for(0.0073)
        copy = [d for d in pair.ms.wire if len(d) >= 40][-1]  # a DATA or KEEPALIVE of the master
        second.receive_datagram(copy, (f"198.51.100.{step}", 1000 + step), now=pair.now)
        for reset, _ in second.datagrams_to_send(now=pair.now):
            pair.inject(reset, to_slave=False, source=SLAVE_ADDR)
            relayed += 1
    assert relayed == 100
    assert pair.master.conn.state is State.ESTABLISHED and not _closes(pair)
    assert pair.master.conn.stats.drops["peer_alive"] == 100


# ---------------------------------------------------------------------- unkeyed, off path


def _forged_message(seq: int, ack: int, data: bytes, nonce: bytes) -> bytes:
    """A MESSAGE as an off-path attacker builds it: every field but the master's nonce is guessable."""
    return (
        _CONTROL_HEADER
        + bytes((ControlCode.MESSAGE,))
        + nonce
        + struct.pack(">HH", seq, ack)
        + data
    )


def test_a_sweep_of_forged_messages_delivers_none_and_every_real_one_arrives() -> None:
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.2)
    for index in range(20):
        pair.master.conn.send_control(b"real %d" % index, now=pair.now)
    rng = random.Random(31)
    forged = 0
    for seq in range(65536):
        ack = rng.randrange(65536)
        for guess in (ack, ack ^ 0x8000):  # one of the two acknowledges nothing new
            pair.inject(
                _forged_message(seq, guess, b"FORGED", rng.randbytes(16)),
                to_slave=True,
                source=MASTER_ADDR,
            )
            forged += 1
        if seq % 4096 == 4095:
            pair.run_for(0.01)
    pair.master.conn.send_control(b"E-STOP", now=pair.now)
    pair.run_for(0.5)
    delivered = [e.payload for e in pair.slave.events if isinstance(e, ControlReceived)]
    assert b"FORGED" not in delivered
    assert delivered == [b"real %d" % index for index in range(20)] + [b"E-STOP"]
    slave = pair.slave.conn.stats
    assert slave.drops["nonce_mismatch"] == forged
    assert slave.control_dropped == {"nonce_mismatch": forged}


def test_forged_data_far_ahead_leaves_both_streams_flowing() -> None:
    """20 forged DATA a second from the master's address, each numbered 63 above the master's
    newest (the best an attacker can guess): dropped as ``far_ahead``; the slave never
    acknowledges a number the master did not send, so the master keeps the slave's stream."""
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    master_before, slave_before = len(pair.master.received), len(pair.slave.received)
    drops_before = dict(pair.slave.conn.stats.drops)
    started, forged = pair.now, 0
    while pair.now < started + 3.0:
        ahead = (pair.master.conn._recovery.sent.next_seq - 1 + 63) & 0xFFF
        pair.inject(
            encode_header(0, ahead, 0, 0, HOLD_NO_ACK) + bytes(100),
            to_slave=True,
            source=MASTER_ADDR,
        )
        forged += 1
        pair.run_for(0.05)
    elapsed = pair.now - started
    assert (len(pair.master.received) - master_before) / elapsed >= 990  # the reverse stream
    assert (len(pair.slave.received) - slave_before) / elapsed >= 990
    drops = pair.slave.conn.stats.drops
    assert {
        k: v - drops_before.get(k, 0) for k, v in drops.items() if v != drops_before.get(k)
    } == {"far_ahead": forged}
    assert pair.master.conn.stats.optimistic_acks == 0


def test_a_loss_burst_of_the_real_flow_is_not_far_ahead() -> None:
    """A real jump comes after a silence as long as the burst: taken at once."""
    lost = set(range(500, 560))  # 60 samples in a row lost at 1 kHz
    pair = Pair()
    pair.ms.drop = lambda index: index in lost
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(1.5)
    assert "far_ahead" not in pair.slave.conn.stats.drops
    # (the window holds a few back while the burst's losses are unreported: superseded, not late)
    assert len(pair.slave.received) >= pair.master.offered - 60 - 40


def test_forged_data_cannot_silence_a_master_that_sends_no_data() -> None:
    """The master sends no samples; forged DATA from its address move the slave's receive window
    to numbers it never sent. The slave's acknowledgements then name packets never sent: ignored
    (``optimistic_acks``), and the slave's samples they ride on still delivered."""
    pair = Pair()
    pair.open()
    pair.start_samples(0, 1000)
    pair.run_for(0.3)
    rng = random.Random(4)
    for _ in range(4):
        pair.inject(
            encode_header(0, rng.randrange(4096), 0, 0, HOLD_NO_ACK) + b"x",
            to_slave=True,
            source=MASTER_ADDR,
        )
    before = len(pair.master.received)
    pair.run_for(1.0)
    assert len(pair.master.received) - before >= 990
    assert pair.master.conn.stats.optimistic_acks > 0


def test_a_forged_number_cannot_prime_the_reorder_wait() -> None:
    """A forgery numbered just ahead of the flow (within what the jump check lets through) opens
    a gap the real samples then fill in order: their "displacement" would set the reorder wait
    to its maximum after every loss. The real sample with the forgery's number then arrives as a
    duplicate, which unmasks it, and the wait stays zero."""
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.3)
    for _ in range(20):
        ahead = (pair.master.conn._recovery.sent.next_seq - 1 + 20) & 0xFFF
        pair.inject(
            encode_header(0, ahead, 0, 0, HOLD_NO_ACK) + bytes(100),
            to_slave=True,
            source=MASTER_ADDR,
        )
        pair.run_for(0.1)
        assert pair.slave.conn.stats.reorder_wait == 0.0


# ---------------------------------------------------------------------- unkeyed, on path


class _Attacker:
    """On path: it saw the master's nonce (in its first KEEPALIVE) and sees what the slave sends
    to the victim; it sends as the victim."""

    def __init__(self, pair: Pair, front: _Front) -> None:
        self.pair, self.front = pair, front
        keepalive = next(d for d in pair.ms.wire if len(d) == 22 and d[5] == ControlCode.KEEPALIVE)
        self.keepalive = keepalive
        self.nonce = keepalive[6:22]
        self.sent_as_victim = 0
        self.to_victim = 0
        original = pair._send

        def send(data: bytes, *, to_slave: bool, src: Address, dst: Address) -> None:
            if dst == VICTIM:
                self.to_victim += len(data)
            original(data, to_slave=to_slave, src=src, dst=dst)

        pair._send = send  # type: ignore[method-assign]

    def round(self) -> None:
        self.sent_as_victim += len(self.keepalive)
        answer = self.front.unattached(self.keepalive, VICTIM)
        if answer is None or answer[5] != ControlCode.PATH_CHALLENGE:
            return
        self.to_victim += len(answer)
        response = _CONTROL_HEADER + encode_path_response(answer[6:22], self.nonce)
        self.sent_as_victim += len(response)
        self.front.unattached(response, VICTIM)


@pytest.mark.parametrize("keepalive_lost", [False, True], ids=["talking", "a-keepalive-lost"])
def test_an_on_path_attacker_cannot_move_a_quiet_master_to_a_victim(keepalive_lost: bool) -> None:
    """The master sends no samples (acknowledgements and keep-alives only), the slave 1 kHz. Every
    20 ms the attacker sends the master's KEEPALIVE from a victim's address and answers any
    PATH_CHALLENGE with the nonce. A master still heard at its address is never quiet enough to
    move (PROTOCOL.md 5.8); one whose keep-alive was lost may move, but the victim is held to
    three times what was sent as it, and the session goes back when the master speaks."""
    pair = Pair()
    pair.ms.keep_wire = True
    front = _Front(pair, keyed=False)
    pair.open()
    pair.start_samples(0, 1000)
    pair.run_for(0.5)
    attacker = _Attacker(pair, front)
    before, started = len(pair.master.received), pair.now
    for round_ in range(50):
        if keepalive_lost and round_ % 10 == 0:
            pair.ms.drop = lambda _: True  # the master's datagrams are lost for 120 ms
            pair.run_for(0.12)
            pair.ms.drop = lambda _: False
        attacker.round()
        pair.run_for(0.02)
    elapsed = pair.now - started
    assert attacker.to_victim <= 3 * attacker.sent_as_victim
    assert pair.slave.conn.peer == MASTER_ADDR
    share = (len(pair.master.received) - before) / (elapsed * 1000)
    assert share >= (0.6 if keepalive_lost else 0.99)  # (lost: 120 ms of every 320 go nowhere)
    stats = pair.slave.conn.stats
    if keepalive_lost:
        assert stats.migrations > 0 and stats.paths_validated == 0
        assert front.admission.paths.stats.moved_back > 0
    else:
        assert stats.migrations == 0
        assert front.admission.paths.stats.drops["no_quiet_session"] == 50


def test_a_real_rebinding_is_proven_once_the_old_address_stays_silent() -> None:
    """Unkeyed NAT rebinding: the session follows the master's PATH_RESPONSE under the 3x limit,
    which lifts once the old address has been silent for silence_timeout."""
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    pair.rebind_master(("192.0.2.1", 51234))
    pair.run_for(1.0)
    stats = pair.slave.conn.stats
    assert pair.slave.conn.peer == ("192.0.2.1", 51234)
    assert stats.migrations == 1 and stats.paths_validated == 1
    assert stats.unvalidated_bytes_out <= 3 * stats.unvalidated_bytes_in


def test_path_challenges_per_session_are_bounded() -> None:
    """Junk of 22 bytes or more from unknown addresses while the unkeyed master is gone: each drew
    a PATH_CHALLENGE in version 3; now at most 10 a second per session (bursts of 3)."""
    pair = Pair()
    front = _Front(pair, keyed=False)
    pair.open()
    pair.run_for(0.2)
    pair.ms.drop = lambda _: True
    pair.run_for(0.3)
    rng = random.Random(8)
    challenges = 0
    for index in range(10_000):  # 10,000 a second for one second
        junk = bytes([rng.randrange(0x80)]) + rng.randbytes(40)
        answer = front.unattached(junk, (f"198.51.100.{index % 250}", 2000 + index))
        challenges += answer is not None
        pair.now += 0.0001
    assert 0 < challenges <= 3 + 10
    assert front.admission.paths.stats.drops["challenge_budget"] > 9_000


# ---------------------------------------------------------------------- takeover


class _ServerAfterTakeover:
    """An exclusive server's front door once a takeover has ended the master's session (in fake
    time, standing in for the slave connection): the displaced master's datagrams get the CLOSE
    TAKEN_OVER again (the notices a server keeps, tdtp.admission.slots), anything else from an
    unknown address a RESET, as tdtp.aio.server does."""

    def __init__(self, close: bytes, now: float) -> None:
        config = ConnectionConfig()
        self.notices = EvictionNotices(4, config.idle_timeout, config.silence_timeout)
        self.notices.add(MASTER_ADDR, close, now)
        self.admission = Admission(config, as_key_ring([KEY]), rng=random.Random(3))
        self.peer = None
        self.state = State.LISTENING
        self.repeated = 0
        self._out: list[tuple[bytes, Address]] = []

    def receive_datagram(self, data: bytes, addr: Address, *, now: float) -> None:
        if self.notices.holds(addr, now):
            close = self.notices.answer(addr, len(data), now)
            if close is not None:
                self.repeated += 1
                self._out.append((close, addr))
            return
        reset = self.admission.reset(data, now)
        if reset is not None:
            self._out.append((reset, addr))

    def datagrams_to_send(self, *, now: float) -> list[tuple[bytes, Address]]:
        out, self._out = self._out, []
        return out

    def get_timer(self) -> None:
        return None

    def handle_timer(self, *, now: float) -> None:
        pass

    def next_event(self) -> None:
        return None


@pytest.mark.parametrize("race", ["reset_first", "close_lost"])
def test_a_displaced_master_always_ends_taken_over(race: str) -> None:
    """Keyed, exclusive: another master took control. The displaced master's datagrams still in
    flight reach a server that holds no session for it any more: a RESET from its front may
    overtake the CLOSE (reset_first: on the batched datagram layer a RESET left at once while the
    CLOSE waited for the end of the wake-up), or the CLOSE may be lost (close_lost). The master
    ends ``taken_over`` either way: a RESET is not believed from a slave heard a moment ago
    (``peer_alive``), and the server answers the master's next datagrams with the same CLOSE."""
    pair = Pair(master_key=KEY, slave_keys=[KEY])
    pair.ms.keep_wire = True
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    closes_to_lose = 1 if race == "close_lost" else 0

    def lose_the_close(datagram: bytes) -> bool:
        nonlocal closes_to_lose
        if closes_to_lose and len(datagram) > 5 and datagram[5] == ControlCode.CLOSE:
            closes_to_lose -= 1
            return True
        return False

    pair.sm.drop_datagram = lose_the_close
    pair.slave.rate = 0.0
    close = pair.slave.conn.close(now=pair.now, taken_over=True)
    assert close is not None
    pair._flush(pair.slave)  # the CLOSE leaves (or is lost)
    server = _ServerAfterTakeover(close, pair.now)
    pair.slave.conn = server  # type: ignore[assignment]  # the session is forgotten
    if race == "reset_first":
        # Another datagram of the master, from an address the server holds nothing for: its
        # RESET reaches the master before the CLOSE does.
        copy = Admission(ConnectionConfig(), as_key_ring([KEY]), rng=random.Random(4))
        reset = copy.reset(_newest_data(pair), pair.now)
        assert reset is not None
        pair.inject(reset, to_slave=False, source=SLAVE_ADDR)
    pair.run_for(1.0)
    (closed,) = _closes(pair)
    assert closed.cause is CloseCause.PEER_CLOSE and closed.detail == "taken_over"
    if race == "reset_first":
        assert pair.master.conn.stats.drops["peer_alive"] == 1
        assert server.repeated == 0
    else:
        assert server.repeated >= 1  # the CLOSE again, not a RESET
        assert server.admission.stats.resets_sent == 0
