"""Path migration in fake time (docs/PROTOCOL.md 5.8): a NAT rebinding moves the master to a new source
address mid-session; the slave follows it (keyed: on the first authenticated datagram; unkeyed: after
a PATH_CHALLENGE the master answers with its nonce), sending at most three times what it received
from the new address until the address is validated. Forged keep-alives, challenges and responses
change nothing and are counted."""

from __future__ import annotations

import random

import pytest

from tdtp import PeerSilent, State
from tdtp.protection import PresharedKey
from tdtp.session.events import DataReceived
from tdtp.wire import (
    HEADER_SIZE,
    ControlCode,
    encode_header,
    encode_keepalive,
    encode_path_challenge,
    encode_path_response,
)

from pair import MASTER_ADDR, SLAVE_ADDR, Pair

KEY = PresharedKey(bytes(range(32)), name="operator")
NEW_ADDR = ("192.0.2.1", 51234)  # the same host behind a NAT that picked another port
VICTIM = ("203.0.113.9", 9999)
CONTROL_HEADER = encode_header(2, 0, 0, 0, 255)


def _stamps(received: list[DataReceived]) -> set[int]:
    return {int.from_bytes(event.payload[:4], "big") for event in received}


def _rebinding_run(keyed: bool) -> tuple[Pair, float, float]:
    """1 kHz both ways, the master's port changes at 1 s; the share of samples each way offered
    from 1.5 s after the change to the end (4 s) that arrived."""
    pair = Pair(master_key=KEY, slave_keys=[KEY]) if keyed else Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(1.0)
    pair.rebind_master(NEW_ADDR)
    pair.run_for(1.5)
    first = (pair.master.offered + 1, pair.slave.offered + 1)
    pair.run_for(1.5)
    last = (pair.master.offered - 20, pair.slave.offered - 20)  # the last ones may be in flight
    shares = []
    for receiver, (low, high) in (
        (pair.slave, (first[0], last[0])),
        (pair.master, (first[1], last[1])),
    ):
        wanted = set(range(low, high + 1))
        shares.append(len(wanted & _stamps(receiver.received)) / len(wanted))
    return pair, shares[0], shares[1]


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
def test_a_nat_rebinding_mid_session_loses_almost_nothing(keyed: bool) -> None:
    pair, to_slave, to_master = _rebinding_run(keyed)
    slave = pair.slave.conn
    assert slave.peer == NEW_ADDR and slave.state is State.ESTABLISHED
    assert to_slave >= 0.99 and to_master >= 0.99
    stats = slave.stats
    assert stats.migrations == 1 and stats.paths_validated == 1
    # Until validated, at most three times what came from the new address went to it.
    assert stats.unvalidated_bytes_out <= 3 * stats.unvalidated_bytes_in
    assert pair.challenges == (0 if keyed else pair.challenges)
    if not keyed:
        assert pair.challenges >= 1
        assert pair.migration is not None and pair.migration.stats.migrations == 1


def test_an_unkeyed_master_answers_a_challenge_only_for_its_slave_and_not_as_a_sign_of_life() -> (
    None
):
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.2)
    master = pair.master.conn
    before = master.stats.sent.control_packets
    token = bytes(range(16))
    pair.inject(CONTROL_HEADER + encode_path_challenge(token), to_slave=False, source=SLAVE_ADDR)
    assert master.stats.sent.control_packets == before + 1  # the PATH_RESPONSE
    # A second one at once is paced (at most one per 5 ms): a forged flood buys little.
    pair.inject(CONTROL_HEADER + encode_path_challenge(token), to_slave=False, source=SLAVE_ADDR)
    assert master.stats.drops.get("rate_limited") == 1
    # From anyone but the slave: dropped like any stranger's datagram.
    pair.inject(CONTROL_HEADER + encode_path_challenge(token), to_slave=False, source=VICTIM)
    assert master.stats.drops.get("wrong_address") == 1


def test_a_keyed_master_ignores_path_challenges() -> None:
    pair = Pair(master_key=KEY, slave_keys=[KEY])
    pair.open()
    pair.run_for(0.1)
    challenge = CONTROL_HEADER + encode_path_challenge(bytes(16))
    pair.inject(challenge, to_slave=False, source=SLAVE_ADDR)
    assert pair.master.conn.stats.drops.get("unexpected_control") == 1


def test_forged_keepalives_from_the_masters_address_do_not_hide_a_dead_master() -> None:
    """Unkeyed: a blind attacker who knows the master's address but not its nonce."""
    pair = Pair()
    pair.open()
    pair.run_for(0.2)
    pair.ms.drop = lambda _: True  # the master dies
    forged = CONTROL_HEADER + encode_keepalive(bytes(16))
    end = pair.now + 0.5
    while pair.now < end:
        pair.inject(forged, to_slave=True, source=MASTER_ADDR)  # 100 Hz of forgeries
        pair.run_for(0.01)
    slave = pair.slave.conn
    assert any(isinstance(event, PeerSilent) for event in pair.slave.events)
    assert slave.stats.drops.get("nonce_mismatch", 0) >= 49


def test_forged_path_responses_move_nothing() -> None:
    pair = Pair()
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    pair.rebind_master(NEW_ADDR)
    migration = pair.migration
    assert migration is not None
    pair.ms.drop = lambda _: True  # keep the session quiet: no real response
    pair.run_for(0.05)
    slave = pair.slave.conn
    nonce = slave.master_nonce
    # A token minted for another address, one never minted, the right token with a wrong nonce.
    token_for_victim = migration._tokens.mint(VICTIM, b"tdtp path challenge", pair.now)
    for token, nonce_sent, source in (
        (token_for_victim, nonce, NEW_ADDR),
        (bytes(16), nonce, VICTIM),
        (token_for_victim, bytes(16), VICTIM),
    ):
        response = CONTROL_HEADER + encode_path_response(token, nonce_sent)
        assert migration.on_unattached(response, source, pair.now, [slave]) is None
    assert migration.stats.drops == {"bad_token": 2, "no_session": 1}
    assert slave.peer == MASTER_ADDR and slave.stats.migrations == 0


def test_a_replayed_keyed_datagram_from_a_spoofed_address_buys_at_most_three_times_its_size() -> (
    None
):
    """An on-path attacker who sees a datagram the slave has not (the master's path is cut) sends it
    first, from a victim's address: the session follows (it authenticates), but sends the victim
    at most three times the datagram's bytes, and comes back when the master is heard again."""
    pair = Pair(master_key=KEY, slave_keys=[KEY])
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(0.5)
    pair.rebind_master(MASTER_ADDR)  # installs the slave's front; the master keeps its address
    pair.ms.keep_wire = True
    pair.ms.drop = lambda _: True  # the attacker sits on the path and holds everything
    pair.run_for(0.02)
    captured = [d for d in pair.ms.wire if d[0] >> 6 == 0][-1]
    pair.ms.keep_wire = False
    migration = pair.migration
    assert migration is not None
    slave = pair.slave.conn
    assert migration.on_unattached(captured, VICTIM, pair.now, [slave]) is slave
    assert slave.peer == VICTIM
    pair._flush(pair.slave)  # what the slave sends now goes to the victim (lost there)
    pair.run_for(0.05)
    to_victim = slave.stats.unvalidated_bytes_out
    assert to_victim <= 3 * len(captured)  # the rest is held (counted)
    assert slave.stats.path_limited > 0
    pair.ms.drop = lambda _: False  # the attacker lets the master through again
    pair.run_for(1.0)
    stats = slave.stats
    assert stats.unvalidated_bytes_out <= 3 * stats.unvalidated_bytes_in
    assert slave.peer == MASTER_ADDR  # followed the real master back
    assert stats.migrations == 2 and stats.paths_validated == 1
    # A replay of the same datagram now moves nothing (its packet number is old).
    assert migration.on_unattached(captured, VICTIM, pair.now + 0.01, [slave]) is None


def test_a_flood_from_unknown_addresses_is_answered_with_fewer_bytes_and_bounded_trials() -> None:
    unkeyed, keyed = Pair(), Pair(master_key=KEY, slave_keys=[KEY])
    rng = random.Random(5)
    for pair in (unkeyed, keyed):
        pair.open()
        pair.run_for(0.2)
        pair.rebind_master(MASTER_ADDR)
        pair.ms.drop = lambda _: True  # the master is quiet: every session is a candidate
        pair.run_for(0.3)  # (unkeyed: once silent longer than a live master ever is)
        migration = pair.migration
        assert migration is not None
        flood = 20_000
        for index in range(flood):
            size = rng.randrange(HEADER_SIZE, 200)
            data = bytes([rng.randrange(256) & 0x3F | 0x40]) + rng.randbytes(size - 1)
            source = (f"198.51.100.{index % 250}", 1024 + index)
            migration.on_unattached(data, source, pair.now + index * 1e-6, [pair.slave.conn])
        stats = migration.stats
        assert stats.migrations == 0 and pair.slave.conn.peer == MASTER_ADDR
        assert stats.bytes_out <= stats.bytes_in
        if pair is keyed:
            # 20,000 datagrams in 20 ms: the trial budget (2,000/s, a burst of 200) bounds the work.
            assert stats.trials <= 200 + 0.02 * 2000 + 1
            assert stats.drops["trial_budget"] >= flood - stats.trials
            assert stats.challenges_sent == 0
        else:
            assert stats.trials == 0
            # A challenge may go out on the session's behalf at most 10 times a second, in bursts
            # of 3 (PROTOCOL.md 5.8): 20,000 datagrams in 20 ms draw 3, not one each.
            assert 0 < stats.challenges_sent <= 3 + 0.02 * 10
            drops = stats.drops
            assert drops["challenge_budget"] + drops["too_small"] == flood - stats.challenges_sent


def test_a_challenge_is_never_larger_than_what_triggered_it() -> None:
    pair = Pair()
    pair.open()
    pair.run_for(0.2)
    pair.rebind_master(MASTER_ADDR)
    pair.ms.drop = lambda _: True
    pair.run_for(0.3)  # silent longer than a live master ever is (no RTT sample: 0.233 s)
    migration = pair.migration
    assert migration is not None
    small = CONTROL_HEADER + bytes([ControlCode.KEEPALIVE]) + bytes(15)  # 21 bytes
    assert migration.on_unattached(small, VICTIM, pair.now, [pair.slave.conn]) is None
    assert migration.stats.drops == {"too_small": 1}
    keepalive = CONTROL_HEADER + encode_keepalive(bytes(16))  # 22 bytes
    challenge = migration.on_unattached(keepalive, VICTIM, pair.now, [pair.slave.conn])
    assert isinstance(challenge, bytes) and len(challenge) <= len(keepalive)
