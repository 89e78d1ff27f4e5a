"""The relay's core, sans-IO (docs/PROTOCOL.md 5.12): registrations, pairing, and what it forwards.

Two endpoints that cannot reach each other (NATs, firewalls) both dial out to one relay and register
under the same rendezvous id, one as the dialer and one as the listener. The relay

* validates every registrant's address with a stateless cookie first (a REGISTER without a valid
  one is answered with a 41-byte COOKIE referral, smaller than any REGISTER, within a per-source
  rate and a global reply budget), so a forged source can neither register nor be made a target;
* once both sides of an id are registered, tells each the other's reflexive address (as the relay
  sees it) and local addresses (REFERRAL PEER), so they can punch holes towards each other;
* forwards every other datagram from a registered address, whole and unread, to its pair's
  address: a keyed session's datagrams are sealed end to end, so the relay can neither read, forge
  nor replay them (the receiver's replay window refuses a copy);
* answers a datagram from an address that holds no registration, if it is large enough, with a
  25-byte "unknown source" referral (a registrant whose NAT mapping changed registers again at
  once), within the same reply budget.

An unvalidated address never gets more bytes than it sent (:attr:`RelayStats.unvalidated_bytes_out`
<= :attr:`RelayStats.unvalidated_bytes_in`). Knowing the rendezvous id is what lets a registrant
join, replace or leave a rendezvous: a third party without it can do none of these. Tables are
bounded (:class:`~tdtp.rendezvous.settings.RelayConfig`).

:attr:`RelayCore.routes` is the forwarding table the driver reads for every datagram (source
address -> :class:`Route`); everything else goes through :meth:`RelayCore.receive`.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from typing import Final

from tdtp.admission.cookie import CookieJar
from tdtp.admission.rate_limit import SourceRateLimiter, TokenBucket
from tdtp.rendezvous.settings import RelayConfig
from tdtp.wire.address import Address
from tdtp.wire.control import CloseReason
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.rendezvous import (
    COOKIE_REFERRAL_SIZE,
    COOKIE_SIZE,
    NONCE_SIZE,
    REGISTER,
    UNKNOWN_REFERRAL_SIZE,
    Candidate,
    ReferralBody,
    ReferralKind,
    RegisterFlags,
    decode_register,
    encode_referral,
    rendezvous_code,
)

_NO_COOKIE: Final = bytes(COOKIE_SIZE)
_NO_NONCE: Final = bytes(NONCE_SIZE)
_DIALER, _LISTENER = 0, 1


class Route:
    """Where a registered address's datagrams go, and how many it sent this second."""

    __slots__ = ("dest", "dropped", "forwarded", "sent")

    def __init__(self, dest: Address) -> None:
        self.dest = dest
        self.sent = 0
        """Datagrams forwarded in the current second (reset by :meth:`RelayCore.handle_timer`)."""
        self.forwarded = 0
        """Datagrams forwarded before the current second."""
        self.dropped = 0
        """Datagrams over the forward rate."""


@dataclass(slots=True, eq=False)
class Registration:
    addr: Address
    rendezvous_id: bytes
    side: int
    nonce: bytes
    candidates: tuple[Candidate, ...]
    expires: float


@dataclass(slots=True)
class RelayStats:
    """What a relay did: registrations, answers, forwarding, drops by reason."""

    registrations: int = 0
    """Registrations held now."""
    rendezvous_paired: int = 0
    """Times two sides of an id met (REFERRAL PEER to both)."""
    registers: int = 0
    cookies_sent: int = 0
    replaced: int = 0
    """Registrations taken over by a validated REGISTER from another address (same id and side)."""
    expired: int = 0
    left: int = 0
    refused: int = 0
    unknown_sent: int = 0
    forwarded: int = 0
    """Datagrams forwarded whole (updated once a second and when read through :meth:`RelayCore.stats`)."""
    forward_dropped: int = 0
    """Datagrams from a registered address over its forward rate."""
    unvalidated_bytes_in: int = 0
    """Bytes of the datagrams from addresses not (yet) validated that the relay answered."""
    unvalidated_bytes_out: int = 0
    """Bytes of those answers: at most :attr:`unvalidated_bytes_in`, by construction."""
    drops: dict[str, int] = field(default_factory=dict)

    def count_drop(self, reason: str) -> None:
        self.drops[reason] = self.drops.get(reason, 0) + 1


class RelayCore:
    """Registrations and forwarding routes for one relay socket."""

    def __init__(
        self, config: RelayConfig | None = None, *, rng: random.Random | None = None
    ) -> None:
        self.config = config = config if config is not None else RelayConfig()
        rng = rng if rng is not None else random.SystemRandom()
        self._cookies = CookieJar(rng.randbytes(32), config.cookie_lifetime)
        self._per_source = SourceRateLimiter(
            config.registers_per_source, config.register_burst, config.max_sources
        )
        self._replies = TokenBucket(config.replies_per_second, config.replies_per_second)
        self._by_addr: dict[Address, Registration] = {}
        self._by_id: dict[bytes, list[Registration | None]] = {}
        self.routes: dict[Address, Route] = {}
        """Source address -> where its datagrams go (paired registrations only)."""
        self.forward_rate = config.forward_rate
        self._retired = 0  # datagrams forwarded by routes since removed
        self._stats = RelayStats()

    @property
    def stats(self) -> RelayStats:
        stats = self._stats
        stats.registrations = len(self._by_addr)
        stats.forwarded = self._retired + sum(r.forwarded + r.sent for r in self.routes.values())
        return stats

    def receive(self, data: bytes, addr: Address, now: float) -> list[tuple[bytes, Address]]:
        """A datagram the fast path did not forward: a REGISTER, or anything from an address
        without a route. Returns what to send."""
        stats = self._stats
        if rendezvous_code(data) == REGISTER:
            return self._on_register(data, addr, now)
        if addr in self._by_addr:
            stats.count_drop("rendezvous message" if rendezvous_code(data) else "unpaired")
            return []
        if rendezvous_code(data) or len(data) < UNKNOWN_REFERRAL_SIZE:
            stats.count_drop("unknown source")
            return []
        if not self._replies.take(now):
            stats.count_drop("reply budget")
            return []
        reply = encode_referral(
            ReferralBody(ReferralKind.UNKNOWN, 0, _NO_NONCE, _NO_COOKIE, 0, None, None, False, ())
        )
        stats.unknown_sent += 1
        stats.unvalidated_bytes_in += len(data)
        stats.unvalidated_bytes_out += len(reply)
        return [(reply, addr)]

    def handle_timer(self, now: float) -> None:
        """Once a second: registrations that were not refreshed expire, forward budgets refill."""
        for route in self.routes.values():
            route.forwarded += route.sent
            self._stats.forward_dropped += route.dropped
            route.sent = route.dropped = 0
        for registration in [r for r in self._by_addr.values() if r.expires <= now]:
            self._stats.expired += 1
            self._remove(registration)

    # ------------------------------------------------------------------ registrations

    def _on_register(self, data: bytes, addr: Address, now: float) -> list[tuple[bytes, Address]]:
        stats = self._stats
        stats.registers += 1
        try:
            body = decode_register(data)
        except MalformedPacketError:
            stats.count_drop("bad_control")
            return []
        if not self._per_source.allow(addr, now):
            stats.count_drop("rate_limited")
            return []
        if body.cookie == _NO_COOKIE or not self._cookies.check(body.cookie, addr, body.nonce, now):
            if not self._replies.take(now):
                stats.count_drop("reply budget")
                return []
            cookie = self._cookies.mint(addr, body.nonce, now)
            reply = self._referral(ReferralKind.COOKIE, body.nonce, cookie=cookie)
            assert len(reply) == COOKIE_REFERRAL_SIZE <= len(data)
            stats.cookies_sent += 1
            stats.unvalidated_bytes_in += len(data)
            stats.unvalidated_bytes_out += len(reply)
            return [(reply, addr)]
        # The registrant receives at ``addr``: answers to it are no longer reflections.
        side = _LISTENER if body.flags & RegisterFlags.LISTENER else _DIALER
        held = self._by_addr.get(addr)
        if body.flags & RegisterFlags.LEAVE:
            if held is not None and held.rendezvous_id == body.rendezvous_id:
                stats.left += 1
                self._remove(held)
            return [(self._referral(ReferralKind.LEFT, body.nonce), addr)]
        if held is not None and (held.rendezvous_id, held.side) != (body.rendezvous_id, side):
            self._remove(held)  # the same socket meets under another id now
            held = None
        slots = self._by_id.get(body.rendezvous_id)
        if held is None:
            if len(self._by_addr) >= self.config.max_registrations:
                self.handle_timer(now)  # room from the expired ones, if any
            if len(self._by_addr) >= self.config.max_registrations:
                stats.refused += 1
                reason = int(CloseReason.RENDEZVOUS_FULL)
                return [(self._referral(ReferralKind.REFUSED, body.nonce, reason=reason), addr)]
            if slots is not None and (previous := slots[side]) is not None:
                stats.replaced += 1  # the same side again from a new address (a NAT rebinding)
                self._remove(previous)
                slots = self._by_id.get(body.rendezvous_id)
            held = Registration(addr, body.rendezvous_id, side, body.nonce, (), 0.0)
            self._by_addr[addr] = held
            if slots is None:
                slots = self._by_id[body.rendezvous_id] = [None, None]
            slots[side] = held
        held.nonce = body.nonce
        held.candidates = body.candidates
        held.expires = now + self.config.lifetime
        assert slots is not None
        other = slots[1 - side]
        if other is None:
            return [(self._referral(ReferralKind.WAITING, body.nonce, reflexive=addr), addr)]
        out = [(self._peer_referral(held, other), addr)]
        if addr not in self.routes:
            self._pair(held, other)
            stats.rendezvous_paired += 1
            out.append((self._peer_referral(other, held), other.addr))
        return out

    def _pair(self, one: Registration, other: Registration) -> None:
        self.routes[one.addr] = Route(other.addr)
        self.routes[other.addr] = Route(one.addr)

    def _remove(self, registration: Registration) -> None:
        addr = registration.addr
        del self._by_addr[addr]
        slots = self._by_id[registration.rendezvous_id]
        slots[registration.side] = None
        other = slots[1 - registration.side]
        for gone in (addr, other.addr if other is not None else None):
            route = self.routes.pop(gone, None) if gone is not None else None
            if route is not None:
                self._retired += route.forwarded + route.sent
        if other is None:
            del self._by_id[registration.rendezvous_id]

    def _referral(
        self,
        kind: ReferralKind,
        nonce: bytes,
        *,
        cookie: bytes = _NO_COOKIE,
        reason: int = 0,
        reflexive: Address | None = None,
    ) -> bytes:
        lifetime = int(self.config.lifetime) if reflexive is not None else 0
        where = None if reflexive is None else (str(reflexive[0]), int(reflexive[1]))
        return encode_referral(
            ReferralBody(int(kind), reason, nonce, cookie, lifetime, where, None, False, ())
        )

    def _peer_referral(self, to: Registration, peer: Registration) -> bytes:
        return encode_referral(
            ReferralBody(
                int(ReferralKind.PEER),
                0,
                to.nonce,
                _NO_COOKIE,
                int(self.config.lifetime),
                (str(to.addr[0]), int(to.addr[1])),
                (str(peer.addr[0]), int(peer.addr[1])),
                peer.side == _LISTENER,
                peer.candidates,
            )
        )
