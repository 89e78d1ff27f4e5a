"""The rendezvous core in fake time (docs/PROTOCOL.md 5.12): the relay's cookies, pairing, bounds and
budgets, and the client's hole punching and path choice. What a third party without the rendezvous
name can do (nothing: not join, not hijack, not end), and that no unvalidated address ever gets more
bytes than it sent."""

from __future__ import annotations

import random

import pytest

from tdtp.errors import InvalidArgumentError
from tdtp.protection import PresharedKey
from tdtp.rendezvous.client import PathKind, RendezvousClient
from tdtp.rendezvous.relay import RelayCore
from tdtp.rendezvous.settings import RelayConfig, Rendezvous, meeting
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.rendezvous import (
    PROBE,
    PROBE_SIZE,
    REGISTER_MIN_SIZE,
    ReferralKind,
    RegisterBody,
    RegisterFlags,
    decode_referral,
    decode_register,
    encode_probe,
    encode_register,
)

RELAY = ("203.0.113.10", 7700)
A = ("203.0.113.1", 40000)
B = ("203.0.113.2", 50000)
MALLORY = ("198.51.100.66", 6666)
SETTINGS = Rendezvous(*RELAY, name="robot-7")
MEET = meeting(None, "robot-7")


def _register(
    relay: RelayCore, addr: tuple[str, int], rid: bytes, nonce: bytes, now: float, *,
    listener: bool = False, leave: bool = False,
) -> list[tuple[bytes, tuple[str, int]]]:  # fmt: skip
    """A full registration: REGISTER, the cookie, REGISTER with it. What the last one drew."""
    flags = (RegisterFlags.LISTENER if listener else 0) | (RegisterFlags.LEAVE if leave else 0)
    first = encode_register(RegisterBody(int(flags), nonce, rid, bytes(16), ()))
    (cookie_reply, to), *_ = relay.receive(first, addr, now)
    assert to == addr
    cookie = decode_referral(cookie_reply).cookie
    again = encode_register(RegisterBody(int(flags), nonce, rid, cookie, ()))
    return relay.receive(again, addr, now)


def _kinds(out: list[tuple[bytes, tuple[str, int]]]) -> list[tuple[int, tuple[str, int]]]:
    return [(decode_referral(d).kind, to) for d, to in out]


def test_a_register_without_a_cookie_draws_a_smaller_cookie_and_leaves_no_state() -> None:
    relay = RelayCore(rng=random.Random(1))
    datagram = encode_register(RegisterBody(0, b"n" * 16, MEET.rendezvous_id, bytes(16), ()))
    assert len(datagram) == REGISTER_MIN_SIZE
    ((reply, to),) = relay.receive(datagram, A, 0.0)
    assert to == A and len(reply) < len(datagram)
    assert decode_referral(reply).kind == ReferralKind.COOKIE
    assert relay.stats.registrations == 0 and relay.routes == {}


def test_two_sides_of_one_id_are_told_each_other_and_routed() -> None:
    relay = RelayCore(rng=random.Random(1))
    assert _kinds(_register(relay, A, MEET.rendezvous_id, b"a" * 16, 0.0, listener=True)) == [
        (ReferralKind.WAITING, A)
    ]
    out = _register(relay, B, MEET.rendezvous_id, b"b" * 16, 0.1)
    assert _kinds(out) == [(ReferralKind.PEER, B), (ReferralKind.PEER, A)]
    to_b, to_a = (decode_referral(d) for d, _ in out)
    assert (to_b.peer, to_b.reflexive, to_b.peer_listens) == (A, B, True)
    assert (to_a.peer, to_a.nonce) == (B, b"a" * 16)  # A's own nonce: it can tell it is real
    assert relay.routes[A].dest == B and relay.routes[B].dest == A
    assert relay.stats.rendezvous_paired == 1


def test_a_third_party_without_the_name_cannot_join_hijack_or_end_a_rendezvous() -> None:
    relay = RelayCore(rng=random.Random(1))
    _register(relay, A, MEET.rendezvous_id, b"a" * 16, 0.0, listener=True)
    _register(relay, B, MEET.rendezvous_id, b"b" * 16, 0.0)
    guess = meeting(None, "robot-8").rendezvous_id
    # Join or hijack under a guessed name (either side): a rendezvous of its own, nothing else.
    for listener in (False, True):
        out = _register(relay, MALLORY, guess, b"m" * 16, 0.1, listener=listener)
        assert all(to == MALLORY for _, to in out)
    assert relay.routes[A].dest == B and relay.routes[B].dest == A
    # End it, or take A's place, forging A's address: without A's cookie only A hears the answer.
    for flags in (RegisterFlags.LEAVE, RegisterFlags.LISTENER):
        forged = encode_register(
            RegisterBody(int(flags), b"m" * 16, MEET.rendezvous_id, b"\x01" * 16, ())
        )
        out = relay.receive(forged, A, 0.2)
        assert _kinds(out) == [(ReferralKind.COOKIE, A)]  # to A, not to the forger
    # Leave from its own address with a valid cookie, naming the real id it does not know: no.
    _register(relay, MALLORY, guess, b"m" * 16, 0.3, leave=True)
    assert relay.routes[A].dest == B and relay.routes[B].dest == A
    # A datagram to relay from an unregistered address is never forwarded.
    assert relay.receive(b"\x00" * 40, MALLORY, 0.4)[0][1] == MALLORY  # "unknown source"
    assert relay.stats.forwarded == 0


def test_an_unvalidated_address_never_gets_more_bytes_than_it_sent() -> None:
    relay = RelayCore(RelayConfig(replies_per_second=1000.0), rng=random.Random(2))
    _register(relay, A, MEET.rendezvous_id, b"a" * 16, 0.0)
    rng = random.Random(3)
    for i in range(5000):
        size = rng.randrange(1, 200)
        data = bytes(rng.randrange(256) for _ in range(size))
        if i % 3 == 0:  # REGISTERs too, valid-looking, without a cookie
            data = encode_register(
                RegisterBody(0, rng.randbytes(16), rng.randbytes(16), bytes(16), ())
            )
        addr = (f"198.51.100.{rng.randrange(256)}", rng.randrange(1, 65536))
        for reply, to in relay.receive(data, addr, i * 0.0002):
            assert to == addr and len(reply) <= len(data)
    stats = relay.stats
    assert 0 < stats.unvalidated_bytes_out <= stats.unvalidated_bytes_in
    assert stats.registrations == 1  # none of them holds a registration


def test_the_tables_are_bounded_and_expire() -> None:
    relay = RelayCore(RelayConfig(max_registrations=4, lifetime=10.0), rng=random.Random(1))
    for i in range(4):
        _register(relay, (f"203.0.113.{i + 1}", 4000), bytes([i]) * 16, b"x" * 16, 0.0)
    out = _register(relay, ("203.0.113.9", 4000), b"\x09" * 16, b"y" * 16, 1.0)
    referral = decode_referral(out[0][0])
    assert referral.kind == ReferralKind.REFUSED and referral.reason == 22
    relay.handle_timer(11.0)  # nobody refreshed: all expire
    assert relay.stats.registrations == 0 and relay.stats.expired == 4
    assert _kinds(_register(relay, ("203.0.113.9", 4000), b"\x09" * 16, b"y" * 16, 11.0)) == [
        (ReferralKind.WAITING, ("203.0.113.9", 4000))
    ]


def test_the_same_side_from_a_new_address_takes_over_a_nat_rebinding() -> None:
    relay = RelayCore(rng=random.Random(1))
    _register(relay, A, MEET.rendezvous_id, b"a" * 16, 0.0, listener=True)
    _register(relay, B, MEET.rendezvous_id, b"b" * 16, 0.0)
    moved = ("203.0.113.1", 40001)
    out = _register(relay, moved, MEET.rendezvous_id, b"a" * 16, 1.0, listener=True)
    assert _kinds(out) == [(ReferralKind.PEER, moved), (ReferralKind.PEER, B)]
    assert relay.routes[B].dest == moved and A not in relay.routes
    assert relay.stats.replaced == 1


def test_register_and_referral_codecs_refuse_what_is_not_theirs() -> None:
    with pytest.raises(MalformedPacketError):
        decode_register(b"\x80\x00\x00\x00\xff\x15\x03" + bytes(60))  # version 3
    with pytest.raises(MalformedPacketError):
        decode_referral(b"\x80\x00\x00\x00\xff\x16\x04\x09\x00" + bytes(16))  # kind 9
    body = RegisterBody(1, b"n" * 16, b"i" * 16, b"c" * 16, (("192.168.1.2", 7), ("::1", 8)))
    assert decode_register(encode_register(body)) == body


def test_a_keyed_pair_meets_under_its_key_and_an_unkeyed_one_needs_a_name() -> None:
    key = PresharedKey(bytes(range(32)))
    other = PresharedKey(bytes(range(1, 33)))
    assert meeting(key, None) != meeting(other, None)
    assert meeting(key, None).rendezvous_id != meeting(None, "x").rendezvous_id
    assert meeting(key, None).probe_key != meeting(key, None).rendezvous_id
    with pytest.raises(InvalidArgumentError, match="needs a name"):
        meeting(None, None)


# ---------------------------------------------------------------------- the client


def _client(listener: bool, **kw: float) -> RendezvousClient:
    settings = Rendezvous(*RELAY, name="robot-7", **kw)  # type: ignore[arg-type]
    client = RendezvousClient(
        settings, MEET, listener=listener, relay=RELAY, local=(), rng=random.Random(int(listener))
    )
    client.start(0.0)
    return client


def _meet(dialer: RendezvousClient, listener: RendezvousClient, now: float) -> None:
    """Run both through a real RelayCore until each knows the other."""
    relay = RelayCore(rng=random.Random(9))
    where = {id(dialer): B, id(listener): A}
    for _ in range(4):
        for client in (listener, dialer):
            client.handle_timer(now)
            for data, to in client.datagrams_to_send(now):
                if to == RELAY:
                    for reply, back in relay.receive(data, where[id(client)], now):
                        target = dialer if back == B else listener
                        target.receive(reply, RELAY, now)
    assert dialer.peer == A and listener.peer == B


def _exchange(
    one: RendezvousClient, other: RendezvousClient, now: float, *, cut: bool = False
) -> None:
    """Deliver the probes between the pair (their WAN addresses are A and B), unless cut."""
    where = {id(one): B, id(other): A}
    for sender, receiver in ((one, other), (other, one)):
        for data, to in sender.datagrams_to_send(now):
            if to == RELAY or cut:
                continue
            if to == where[id(receiver)]:
                receiver.receive(data, where[id(sender)], now)


def test_a_probe_without_the_probe_key_is_not_answered_and_cannot_validate_a_path() -> None:
    listener = _client(True)
    relay_knows = meeting(None, "robot-7").rendezvous_id  # all the relay learns
    forged = encode_probe(PROBE, b"t" * 16, relay_knows)
    assert len(forged) == PROBE_SIZE
    listener.receive(forged, MALLORY, 0.0)
    assert listener.datagrams_to_send(0.0) == [] or all(
        to == RELAY for _, to in listener.datagrams_to_send(0.0)
    )
    assert listener.stats.drops == {"unauthenticated": 1}
    assert (MALLORY[0], MALLORY[1]) not in listener.accepted


def test_the_dialer_opens_direct_when_a_probe_returns_else_on_the_relay_in_time() -> None:
    dialer, listener = _client(False), _client(True)
    _meet(dialer, listener, 0.0)
    assert dialer.choice(0.0) is None  # still punching
    now = 0.0
    while dialer.choice(now) is None:  # the holes are open: a round trip validates
        now += 0.01
        dialer.handle_timer(now)
        listener.handle_timer(now)
        _exchange(dialer, listener, now)
    assert dialer.choice(now) == A and now < SETTINGS.direct_wait
    # Another pair whose probes never arrive (a symmetric NAT): the relay after direct_wait.
    dialer, listener = _client(False), _client(True)
    _meet(dialer, listener, 0.0)
    now = 0.0
    while dialer.choice(now) is None:
        now += 0.01
        dialer.handle_timer(now)
        listener.handle_timer(now)
        _exchange(dialer, listener, now, cut=True)
    assert dialer.choice(now) == RELAY
    assert SETTINGS.direct_wait <= now < SETTINGS.direct_wait + 0.02


def test_a_dead_direct_path_goes_back_to_the_relay_within_a_second_and_returns() -> None:
    dialer, listener = _client(False), _client(True)
    _meet(dialer, listener, 0.0)
    now = 0.0
    while dialer.direct is None or listener.direct is None:
        now += 0.01
        for c in (dialer, listener):
            c.handle_timer(now)
        _exchange(dialer, listener, now)
    dialer.in_session(A, now)
    listener.in_session(B, now)
    assert dialer.path_kind() is listener.path_kind() is PathKind.DIRECT
    cut_at = now
    while dialer.path_kind() is PathKind.DIRECT or listener.path_kind() is PathKind.DIRECT:
        now += 0.01
        for c in (dialer, listener):
            c.handle_timer(now)
        _exchange(dialer, listener, now, cut=True)
    assert now - cut_at < 1.0
    changes = [(e.kind, e.addr) for e in dialer.events]
    assert changes[-1] == (PathKind.RELAYED, RELAY)
    healed_at = now
    while dialer.path_kind() is PathKind.RELAYED or listener.path_kind() is PathKind.RELAYED:
        now += 0.01
        for c in (dialer, listener):
            c.handle_timer(now)
        _exchange(dialer, listener, now)
    assert now - healed_at <= SETTINGS.retry_interval + 0.05
    assert dialer.events[-1].kind is PathKind.DIRECT and dialer.stats.direct_lost == 1


def test_replayed_probes_draw_a_bounded_number_of_answers() -> None:
    """An on-path attacker replaying an authentic PROBE from spoofed sources: at most 200 answers
    a second (a burst of 20), each the PROBE's size."""
    dialer, listener = _client(False), _client(True)
    _meet(dialer, listener, 0.0)
    dialer.handle_timer(0.05)
    probe = next(d for d, to in dialer.datagrams_to_send(0.05) if to == A)  # one to replay
    answered = 0
    for i in range(2000):
        listener.receive(probe, (f"198.51.100.{i % 250}", 1000 + i), 1.0 + i * 0.0005)
        answered += len([d for d, to in listener.datagrams_to_send(1.0) if to != RELAY])
    assert answered <= 20 + 200 * 1.0 + 1
    assert listener.stats.drops["rate_limited"] == 2000 - answered
