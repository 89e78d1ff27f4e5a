"""One endpoint's side of a rendezvous, sans-IO (docs/PROTOCOL.md 5.12): register at the relay,
learn the peer's addresses, punch holes with PROBEs, and say which path the session should use.

The driver (``tdtp.aio.traversal``) feeds it the rendezvous datagrams (codes 21..24) that arrive on
the endpoint's socket, sends what :meth:`RendezvousClient.datagrams_to_send` returns, runs
:meth:`RendezvousClient.handle_timer` at :meth:`RendezvousClient.get_timer`, and applies the
:class:`PathChange` events to the session. Like the session core it never reads a clock.

**Paths.** The relay path is always there once both sides are registered. A *direct* path is a
candidate address of the peer (the reflexive address the relay saw, its local addresses, or the
source of an authentic PROBE from it) to which a PROBE of ours was answered: a round trip proven
under the pair's probe key, which the relay does not hold, so neither the relay nor anyone without
the rendezvous name can make us take one. While the session runs on a direct path it is checked
every ``check_interval``; unanswered for ``path_timeout`` it is given up for the relay, and the
candidates are probed again every ``retry_interval``, so a path that starts working later is moved
to (:class:`PathChange`).

**Amplification.** A PROBE is answered only when its MAC verifies, with a PROBE_ACK of the same size,
so no third party can use an endpoint as a reflector; PROBEs go only to the peer's candidates.
"""

from __future__ import annotations

import enum
import hmac
import random
from collections import OrderedDict, deque
from dataclasses import dataclass, field
from typing import Final

from tdtp.admission.rate_limit import TokenBucket
from tdtp.rendezvous.settings import Meeting, Rendezvous
from tdtp.wire.address import Address
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.rendezvous import (
    COOKIE_SIZE,
    NONCE_SIZE,
    PROBE,
    PROBE_ACK,
    REFERRAL,
    TOKEN_SIZE,
    Candidate,
    ReferralBody,
    ReferralKind,
    RegisterBody,
    RegisterFlags,
    decode_probe,
    decode_referral,
    encode_probe,
    encode_register,
    rendezvous_code,
)

REGISTER_RETRY: Final = 0.25
"""Seconds between REGISTERs until the relay answers (and after an answer is missing)."""
UNKNOWN_PATIENCE: Final = 0.1
"""At most one REGISTER per this many seconds in answer to "unknown source" referrals (which a third
party can forge: they cost us a REGISTER, nothing more)."""
MAX_OUTSTANDING: Final = 256
"""PROBE tokens remembered (oldest forgotten first)."""
MAX_PEER_CANDIDATES: Final = 8
PROBE_ACKS_PER_SECOND: Final = 200.0
"""PROBE_ACKs an endpoint sends at most per second, all together: authentic PROBEs replayed from a
spoofed source draw no more (the peer itself sends a few dozen a second)."""
_NO_COOKIE: Final = bytes(COOKIE_SIZE)


class PathKind(enum.Enum):
    DIRECT = "direct"
    RELAYED = "relayed"


@dataclass(frozen=True, slots=True)
class PathChange:
    """The session should send to ``addr`` from now on (both paths stay accepted)."""

    addr: Address
    kind: PathKind
    at: float


@dataclass(slots=True)
class RendezvousStats:
    """What one endpoint's rendezvous did (``--json``: ``path``, candidates tried)."""

    registers_sent: int = 0
    referrals: int = 0
    probes_sent: int = 0
    probes_answered: int = 0
    """PROBEs from the peer answered with a PROBE_ACK."""
    acks: int = 0
    """PROBE_ACKs that validated or confirmed a direct path."""
    candidates_tried: int = 0
    """Distinct peer addresses probed."""
    direct_paths: int = 0
    """Times a direct path was validated."""
    direct_lost: int = 0
    """Times the direct path in use stopped answering and the session went back to the relay."""
    peer_known_at: float | None = None
    direct_at: float | None = None
    """When a direct path was first validated."""
    drops: dict[str, int] = field(default_factory=dict)

    def count_drop(self, reason: str) -> None:
        self.drops[reason] = self.drops.get(reason, 0) + 1


def _key(addr: Address | Candidate) -> tuple[str, int]:
    return (str(addr[0]), int(addr[1]))


class RendezvousClient:
    """Registration, hole punching and path choice for one endpoint (see the module docstring)."""

    def __init__(
        self,
        settings: Rendezvous,
        meeting: Meeting,
        *,
        listener: bool,
        relay: Address,
        local: tuple[Candidate, ...] = (),
        rng: random.Random | None = None,
    ) -> None:
        self.settings = settings
        self._meeting = meeting
        self.listener = listener
        self.relay: Address = relay
        self._local = local
        self._rng = rng if rng is not None else random.SystemRandom()
        self._nonce = self._rng.randbytes(NONCE_SIZE)
        self._cookie = _NO_COOKIE
        self._side = b"\x01" if listener else b"\x00"
        self._peer_side = b"\x00" if listener else b"\x01"
        self.stats = RendezvousStats()
        self.registered = False
        self.reflexive: Candidate | None = None
        """Our address as the relay sees it."""
        self.peer: Candidate | None = None
        """The peer's address as the relay sees it (None until both sides registered)."""
        self._candidates: dict[tuple[str, int], float] = {}
        """Peer candidates -> when the next PROBE to each is due."""
        self._tried: set[tuple[str, int]] = set()
        self._outstanding: OrderedDict[bytes, tuple[tuple[str, int], float]] = OrderedDict()
        self.accepted: set[tuple[str, int]] = set()
        """Addresses the peer's datagrams may come from: the relay's, and those its authentic PROBEs
        and PROBE_ACKs came from."""
        self.validated: dict[tuple[str, int], float] = {}
        """Direct paths whose round trip is proven -> when last confirmed."""
        self.active: Address | None = None
        """Where the session sends now (None before it runs)."""
        self.events: deque[PathChange] = deque(maxlen=64)
        self._register_at = 0.0
        self._unknown_at = -1.0
        self._answered = True
        self._punch_until = 0.0
        self._check_at = 0.0
        self._out: list[tuple[bytes, Address]] = []
        self._ack_budget = TokenBucket(PROBE_ACKS_PER_SECOND, PROBE_ACKS_PER_SECOND / 10.0)

    # ------------------------------------------------------------------ driver inputs

    def start(self, now: float) -> None:
        """Register at once."""
        self._register_at = now

    @property
    def peer_known(self) -> bool:
        return self.peer is not None

    @property
    def direct(self) -> Address | None:
        """A validated direct path (the first found), or None."""
        for addr in self.validated:
            return addr
        return None

    def choice(self, now: float) -> Address | None:
        """Where a dialer should send its OPEN now: a validated direct path; the relay once
        ``direct_wait`` has passed since the peer's addresses arrived; None: keep waiting."""
        direct = self.direct
        if direct is not None:
            return direct
        known = self.stats.peer_known_at
        if known is not None and now >= known + self.settings.direct_wait:
            return self.relay
        return None

    def in_session(self, addr: Address, now: float) -> None:
        """The session runs on ``addr`` now (where the dialer sent its OPEN, where the listener's
        came from); from here on the client moves it (:attr:`events`)."""
        self.active = addr
        self.accepted.add(_key(addr))
        if _key(addr) != _key(self.relay) and _key(addr) not in self.validated:
            self.validated[_key(addr)] = now  # its OPEN handshake went both ways
        self._check_at = now
        self._steer(now)

    def path_kind(self) -> PathKind | None:
        active = self.active
        if active is None:
            return None
        return PathKind.RELAYED if _key(active) == _key(self.relay) else PathKind.DIRECT

    def leave(self) -> bytes:
        """A REGISTER that ends our registration (send it when the endpoint closes)."""
        flags = RegisterFlags.LEAVE | (RegisterFlags.LISTENER if self.listener else 0)
        return self._register_datagram(int(flags))

    def receive(self, data: bytes, addr: Address, now: float) -> None:
        """A rendezvous datagram (code 21..24) from ``addr``."""
        code = rendezvous_code(data)
        if code == REFERRAL:
            if _key(addr) != _key(self.relay):
                self.stats.count_drop("referral not from the relay")
                return
            self._on_referral(data, now)
        elif code == PROBE:
            self._on_probe(data, addr, now)
        elif code == PROBE_ACK:
            self._on_probe_ack(data, addr, now)
        else:
            self.stats.count_drop("unexpected")

    def get_timer(self) -> float:
        deadline = self._register_at
        if self.active is not None and self.path_kind() is PathKind.DIRECT:
            deadline = min(deadline, self._check_at)  # the path in use; candidates wait
        else:
            validated = self.validated
            for candidate, due in self._candidates.items():
                if candidate not in validated:
                    deadline = min(deadline, due)
        known = self.stats.peer_known_at
        if known is not None and self.active is None and not self.listener and self.direct is None:
            deadline = min(deadline, known + self.settings.direct_wait)  # the dialer's choice
        return deadline

    def handle_timer(self, now: float) -> None:
        settings = self.settings
        if now >= self._register_at:
            self._send_register(now)
            self._register_at = now + (
                settings.refresh_interval if self._answered and self.registered else REGISTER_RETRY
            )
            self._answered = False
        interval = settings.punch_interval if now < self._punch_until else settings.retry_interval
        on_direct = self.path_kind() is PathKind.DIRECT
        for candidate, due in list(self._candidates.items()):
            if on_direct or candidate in self.validated:
                continue
            if now >= due:
                self._probe(candidate, now)
                self._candidates[candidate] = now + interval
        if self.active is not None and self.path_kind() is PathKind.DIRECT:
            key = _key(self.active)
            if now - self.validated.get(key, -1e9) > settings.path_timeout:
                self._lose(key, now)
            elif now >= self._check_at:
                self._probe(key, now)
                self._check_at = now + settings.check_interval

    def datagrams_to_send(self, now: float) -> list[tuple[bytes, Address]]:
        out, self._out = self._out, []
        return out

    # ------------------------------------------------------------------ registration

    def _register_datagram(self, flags: int) -> bytes:
        return encode_register(
            RegisterBody(flags, self._nonce, self._meeting.rendezvous_id, self._cookie, self._local)
        )

    def _send_register(self, now: float) -> None:
        flags = int(RegisterFlags.LISTENER) if self.listener else 0
        self._out.append((self._register_datagram(flags), self.relay))
        self.stats.registers_sent += 1

    def _on_referral(self, data: bytes, now: float) -> None:
        stats = self.stats
        try:
            body = decode_referral(data)
        except MalformedPacketError:
            stats.count_drop("bad_control")
            return
        if body.kind == ReferralKind.UNKNOWN:
            # The relay does not know our address (our NAT's mapping changed, or it restarted).
            if now - self._unknown_at >= UNKNOWN_PATIENCE:
                self._unknown_at = now
                self._register_at = now
            return
        if not hmac.compare_digest(body.nonce, self._nonce):
            stats.count_drop("nonce_mismatch")  # not an answer to us: forged or stale
            return
        stats.referrals += 1
        if body.kind == ReferralKind.COOKIE:
            self._cookie = body.cookie
            self._register_at = now
            self._answered = True
            return
        self._answered = True
        if body.kind == ReferralKind.REFUSED:
            stats.count_drop("refused")
            return
        if body.kind not in (ReferralKind.WAITING, ReferralKind.PEER):
            return
        self.registered = True
        self._register_at = now + self.settings.refresh_interval
        self.reflexive = body.reflexive
        if body.kind == ReferralKind.PEER:
            self._on_peer(body, now)

    def _on_peer(self, body: ReferralBody, now: float) -> None:
        stats = self.stats
        first = self.peer is None
        self.peer = body.peer
        self.accepted.add(_key(self.relay))
        if stats.peer_known_at is None:
            stats.peer_known_at = now
        fresh = [body.peer] if body.peer is not None else []
        fresh += list(body.peer_candidates)
        added = False
        for candidate in fresh:
            added = self._add_candidate(_key(candidate), now) or added
        if first or added:
            self._punch_until = now + self.settings.punch_for

    def _add_candidate(self, key: tuple[str, int], now: float) -> bool:
        if key in self._candidates or key == _key(self.relay):
            return False
        if len(self._candidates) >= MAX_PEER_CANDIDATES:
            return False
        self._candidates[key] = now
        return True

    # ------------------------------------------------------------------ probing

    def _mac(self, kind: bytes, side: bytes, token: bytes) -> bytes:
        return hmac.digest(self._meeting.probe_key, kind + side + token, "sha256")[:TOKEN_SIZE]

    def _probe(self, candidate: tuple[str, int], now: float) -> None:
        token = self._rng.randbytes(TOKEN_SIZE)
        outstanding = self._outstanding
        outstanding[token] = (candidate, now)
        while len(outstanding) > MAX_OUTSTANDING:
            outstanding.popitem(last=False)
        if candidate not in self._tried:
            self._tried.add(candidate)
            self.stats.candidates_tried += 1
        self.stats.probes_sent += 1
        self._out.append(
            (encode_probe(PROBE, token, self._mac(b"P", self._side, token)), candidate)
        )

    def _on_probe(self, data: bytes, addr: Address, now: float) -> None:
        try:
            body = decode_probe(data)
        except MalformedPacketError:
            self.stats.count_drop("bad_control")
            return
        if not hmac.compare_digest(body.mac, self._mac(b"P", self._peer_side, body.token)):
            self.stats.count_drop("unauthenticated")  # not our peer: never answered
            return
        key = _key(addr)
        self.accepted.add(key)
        if self._add_candidate(key, now):  # a peer-reflexive address: probe it too
            self._punch_until = max(self._punch_until, now + self.settings.punch_for)
        if not self._ack_budget.take(now):
            self.stats.count_drop("rate_limited")
            return
        self.stats.probes_answered += 1
        ack = encode_probe(PROBE_ACK, body.token, self._mac(b"A", self._side, body.token))
        self._out.append((ack, addr))

    def _on_probe_ack(self, data: bytes, addr: Address, now: float) -> None:
        stats = self.stats
        try:
            body = decode_probe(data)
        except MalformedPacketError:
            stats.count_drop("bad_control")
            return
        sent = self._outstanding.get(body.token)
        key = _key(addr)
        if sent is None or sent[0] != key:
            stats.count_drop("unmatched")  # a token we never sent there (or forgot): a replay
            return
        if not hmac.compare_digest(body.mac, self._mac(b"A", self._peer_side, body.token)):
            stats.count_drop("unauthenticated")
            return
        del self._outstanding[body.token]
        stats.acks += 1
        self.accepted.add(key)
        if key not in self.validated:
            stats.direct_paths += 1
            if stats.direct_at is None:
                stats.direct_at = now
        self.validated[key] = now
        self._steer(now)

    # ------------------------------------------------------------------ the session's path

    def _steer(self, now: float) -> None:
        """A session on the relay moves to a validated direct path."""
        active = self.active
        if active is None or self.path_kind() is PathKind.DIRECT:
            return
        direct = self.direct
        if direct is not None:
            self.active = direct
            self._check_at = now
            self.events.append(PathChange(direct, PathKind.DIRECT, now))

    def _lose(self, key: tuple[str, int], now: float) -> None:
        """The direct path in use stopped answering: back to the relay, probe again."""
        self.stats.direct_lost += 1
        self.validated.pop(key, None)
        self._candidates.setdefault(key, now)
        for candidate in self._candidates:
            self._candidates[candidate] = min(self._candidates[candidate], now)
        direct = self.direct
        if direct is not None:
            self.active = direct
            self.events.append(PathChange(direct, PathKind.DIRECT, now))
            return
        self.active = self.relay
        self.events.append(PathChange(self.relay, PathKind.RELAYED, now))
