"""A restarted slave is known within about one RTT (PROTOCOL.md 5.7), in fake time: the new slave
answers the master's next session datagram with a RESET the master can verify, and nothing else can
end the master's session that way (forged, replayed, unkeyed RESETs to a keyed master)."""

from __future__ import annotations

import random

import pytest

from tdtp import CloseCause, Connection, ConnectionClosed, ConnectionConfig, Role, State
from tdtp.protection.derivation import reset_tag
from tdtp.protection.keys import PresharedKey
from tdtp.wire.control import RESET_ECHO_SIZE, RESET_SIZE, encode_reset
from tdtp.wire.header import PacketType, encode_header
from tdtp.wire.hold import HOLD_NO_ACK

from pair import SLAVE_ADDR, Pair

KEY = PresharedKey(bytes(range(32)))
OTHER_KEY = PresharedKey(bytes(range(1, 33)))
_RESET_HEADER = encode_header(int(PacketType.CONTROL), 0, 0, 0, HOLD_NO_ACK)


def _restart_slave(pair: Pair, keys: object = None, seed: int = 99) -> None:
    pair.slave.conn = Connection(role=Role.SLAVE, rng=random.Random(seed), keys=keys)  # type: ignore[arg-type]


def _closes(pair: Pair) -> list[ConnectionClosed]:
    return [e for e in pair.master.events if isinstance(e, ConnectionClosed)]


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
def test_a_restarted_slave_is_known_within_one_rtt(keyed: bool) -> None:
    pair = Pair(master_key=KEY if keyed else None, slave_keys=KEY if keyed else None)
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(1.0)
    restarted_at = pair.now
    _restart_slave(pair, KEY if keyed else None)
    pair.run_until(pair.now + 1.0, stop=lambda: bool(_closes(pair)))
    (closed,) = _closes(pair)
    assert closed.cause is CloseCause.PEER_RESTARTED
    assert "restarted" in closed.detail
    # The slave restarted at once: its RESETs are believed once it has been silent for the
    # watchdog's silence_timeout (0.1 s; before, any slave holding the key could end the session
    # by answering a copy of a datagram, PROTOCOL.md 5.7), its in-flight datagrams and one RTT
    # and sample interval later. A slave down longer than that is believed at its first RESET.
    last_heard = restarted_at + 0.010  # what the old slave had in flight
    assert pair.now - last_heard <= 0.1 + 0.021
    assert pair.master.conn.stats.drops.get("peer_alive", 0) > 0
    admission = pair.slave.conn.admission
    assert admission is not None
    stats = admission.stats
    assert stats.resets_sent >= 1
    assert stats.reset_bytes_out <= stats.reset_bytes_in


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
def test_a_slave_down_longer_than_the_watchdog_is_known_at_its_first_reset(keyed: bool) -> None:
    pair = Pair(master_key=KEY if keyed else None, slave_keys=KEY if keyed else None)
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(1.0)
    pair.slave.rate = 0.0
    pair.ms.drop = pair.sm.drop = lambda _: True  # the slave is gone (the network says so)
    pair.run_for(0.3)
    assert pair.master.conn.peer_silent
    _restart_slave(pair, KEY if keyed else None)  # back
    pair.ms.drop = pair.sm.drop = lambda _: False
    back_at = pair.now
    pair.run_until(pair.now + 1.0, stop=lambda: bool(_closes(pair)))
    (closed,) = _closes(pair)
    assert closed.cause is CloseCause.PEER_RESTARTED
    assert pair.now - back_at <= 0.021  # one RTT and one sample interval
    assert "peer_alive" not in pair.master.conn.stats.drops


def test_a_keyed_reset_needs_a_tag_under_the_masters_key() -> None:
    """A slave holding other keys only (or an unkeyed one) cannot end a keyed session."""
    pair = Pair(master_key=KEY, slave_keys=KEY)
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    _restart_slave(pair, [OTHER_KEY])
    pair.run_for(0.3)
    assert pair.master.conn.state is State.ESTABLISHED
    assert pair.master.conn.stats.drops.get("unmatched_reset", 0) > 0


def _sent_prefixes(pair: Pair) -> list[bytes]:
    return [d[:RESET_ECHO_SIZE] for d in pair.ms.wire]


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
def test_forged_and_replayed_resets_are_refused(keyed: bool) -> None:
    pair = Pair(master_key=KEY if keyed else None, slave_keys=KEY if keyed else None)
    pair.ms.keep_wire = True
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    rng = random.Random(7)
    master = pair.master.conn
    # Off-path: a guessed echo (random bytes; or the right header shape with a wrong payload).
    for _ in range(2000):
        echo = rng.randbytes(RESET_ECHO_SIZE)
        tags = (rng.randbytes(16),) if keyed else ()
        pair.inject(_RESET_HEADER + encode_reset(echo, tags), to_slave=False, source=SLAVE_ADDR)
    # On-path, keyed: a real echo without the key's tag.
    if keyed:
        echo = _sent_prefixes(pair)[-1]
        forged = _RESET_HEADER + encode_reset(echo, (reset_tag(OTHER_KEY.reset_key, echo),))
        pair.inject(forged, to_slave=False, source=SLAVE_ADDR)
    # Replayed: a RESET that answered a datagram of an earlier session of the same master.
    old = Pair(master_key=KEY if keyed else None, slave_keys=KEY if keyed else None, seed=5)
    old.ms.keep_wire = True
    old.open()
    old.start_samples(1000, 0)
    old.run_for(0.2)
    old_echo = old.ms.wire[-1][:RESET_ECHO_SIZE]
    tags = (reset_tag(KEY.reset_key, old_echo),) if keyed else ()
    pair.inject(_RESET_HEADER + encode_reset(old_echo, tags), to_slave=False, source=SLAVE_ADDR)
    pair.run_for(0.2)
    assert master.state is State.ESTABLISHED
    assert master.stats.drops["unmatched_reset"] >= 2001 + keyed
    # An echo that is too old (beyond the master's memory) is refused too.
    stale = _sent_prefixes(pair)[0]
    tags = (reset_tag(KEY.reset_key, stale),) if keyed else ()
    pair.inject(_RESET_HEADER + encode_reset(stale, tags), to_slave=False, source=SLAVE_ADDR)
    assert master.state is State.ESTABLISHED


def test_a_flood_at_a_restarted_slave_is_never_amplified_and_bounded() -> None:
    """Session datagrams of every size from many sources: each RESET is no larger than what it
    answers, datagrams too small to answer get nothing, and the RESET budget caps the rate."""
    config = ConnectionConfig()
    slave = Connection(config, role=Role.SLAVE, rng=random.Random(3), keys=[KEY, OTHER_KEY])
    rng = random.Random(4)
    sent_in = sent_out = 0
    for i in range(5000):
        size = rng.randrange(5, 200)
        data = bytes([rng.randrange(0, 0x80)]) + rng.randbytes(size - 1)  # DATA or ACK
        slave.receive_datagram(data, ("198.51.100.7", 1000 + i), now=0.5)
        for datagram, _addr in slave.datagrams_to_send(now=0.5):
            assert len(datagram) <= len(data)
            assert len(datagram) >= RESET_SIZE + 16
            sent_in += len(data)
            sent_out += len(datagram)
    admission = slave.admission
    assert admission is not None
    stats = admission.stats
    assert stats.resets_sent <= config.admission.resets_per_second
    assert stats.reset_bytes_out == sent_out <= sent_in
    assert slave.state is State.LISTENING
