"""Finding the session a datagram from an unknown address belongs to (path migration, PROTOCOL.md 5.8).

A NAT rebinding gives a master a new source address in the middle of a session: its datagrams reach
the slave from an address no session holds. Sans-IO, like the admission it belongs to,
:meth:`PathMigration.on_unattached` takes such a datagram and the slave's sessions and returns

* the :class:`~tdtp.session.connection.Connection` that moved to the new address: keyed, the datagram
  authenticated under that session's keys (WireGuard's roaming); unkeyed, it is a PATH_RESPONSE that
  echoes a token minted for that address and carries the session's master nonce (QUIC's path
  validation, with the nonce an off-path attacker does not know as the proof);
* a PATH_CHALLENGE datagram to send back to the address (unkeyed: some session's master is quiet),
  never larger than the datagram it answers and within the slave's global reply budget;
* ``None``: dropped, counted in :attr:`MigrationStats.drops` by reason; :attr:`PathMigration.unclaimed`
  then says whether no session can own it (the caller answers those with a RESET, PROTOCOL.md 5.7).

Only sessions whose master has gone quiet are candidates (a master whose old address still works has
not moved): a keyed one after ``migration_quiet``, an unkeyed one only once it has been silent longer
than a live master ever is (its keep-alive interval and two round trips), because an unkeyed move
rests on the master's nonce, which an on-path attacker has seen. An unkeyed session that moved is
held to the amplification limit until its old address has stayed silent for its ``silence_timeout``,
and moves straight back if the old address speaks first. A keyed datagram that authenticates as a
copy of one a session already accepted belongs to that live session: it moves nothing and is no
datagram "no session can own" (``replayed``). Trial authentications draw from a global token bucket
(``migration_trials_per_second``), PATH_CHALLENGEs from a bucket of each session's (at most
:data:`~tdtp.session.path.CHALLENGES_PER_SECOND` a second) and the slave's global reply budget: a
flood from unknown addresses costs a bounded amount of CPU and never more replies than it brings
bytes.
"""

from __future__ import annotations

import hmac
import random
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Final, Protocol, TypeVar

from tdtp.admission.cookie import CookieJar
from tdtp.admission.rate_limit import TokenBucket
from tdtp.config import AdmissionConfig
from tdtp.wire.address import Address
from tdtp.wire.control import (
    PATH_CHALLENGE_BODY_SIZE,
    ControlCode,
    PathResponseBody,
    decode_control,
    encode_path_challenge,
)
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE, PacketType, encode_header
from tdtp.wire.hold import HOLD_NO_ACK


class MigratingSession(Protocol):
    """What path migration needs of a session (:class:`~tdtp.session.connection.Connection`)."""

    @property
    def migratable(self) -> bool: ...
    @property
    def keyed(self) -> bool: ...
    @property
    def master_nonce(self) -> bytes: ...
    @property
    def live_gap(self) -> float: ...
    def quiet_for(self, now: float) -> float: ...
    def roam(self, data: bytes, addr: Address, *, now: float) -> int: ...
    def migrate(self, addr: Address, *, now: float) -> None: ...
    def move_back(self, data: bytes, addr: Address, *, now: float) -> bool: ...
    def take_challenge(self, now: float) -> bool: ...


NOT_OURS: Final = 0
""":meth:`MigratingSession.roam`: the datagram does not authenticate under the session's keys."""
ROAMED: Final = 1
"""The session moved to the datagram's address and took it in."""
OURS: Final = 2
"""The datagram authenticates at a packet number the session has accepted already (or too old to
tell): a copy of one of its master's datagrams, replayed from elsewhere. It moves nothing, and a
RESET must never answer it (PROTOCOL.md 5.7)."""


Session = TypeVar("Session", bound=MigratingSession)

_CONTROL: Final = int(PacketType.CONTROL)
_CHALLENGE_HEADER: Final = encode_header(_CONTROL, 0, 0, 0, HOLD_NO_ACK)
CHALLENGE_SIZE: Final = HEADER_SIZE + PATH_CHALLENGE_BODY_SIZE
"""22 bytes: the smallest datagram that may trigger a PATH_CHALLENGE (an unkeyed KEEPALIVE is 22)."""
_TOKEN_DOMAIN: Final = b"tdtp path challenge"
"""Bound into the token's MAC in place of the cookie's nonce: a path token is never a valid cookie."""


@dataclass
class MigrationStats:
    """What the slave did with datagrams from addresses no session holds."""

    unattached: int = 0
    """Datagrams from unknown addresses that were not an OPEN."""
    trials: int = 0
    """Trial authentications (keyed) spent on them."""
    challenges_sent: int = 0
    bytes_in: int = 0
    """Bytes of the datagrams that drew a PATH_CHALLENGE or a trial."""
    bytes_out: int = 0
    """Bytes of PATH_CHALLENGEs sent: at most ``bytes_in``."""
    migrations: int = 0
    """Sessions moved to a new address (keyed roaming and unkeyed path validation)."""
    moved_back: int = 0
    """Unkeyed sessions that went back to their old address: it spoke before the new one was
    proven (included in ``migrations``)."""
    drops: dict[str, int] = field(default_factory=dict)
    """Datagrams that moved no session, by reason: ``no_quiet_session``, ``trial_budget``,
    ``replayed`` (a copy of a datagram a live keyed session accepted), ``unauthenticated``,
    ``too_small``, ``challenge_budget`` (every quiet unkeyed session drew its share of
    PATH_CHALLENGEs), ``rate_limited``, ``bad_token``, ``no_session``, ``bad_control``."""

    def count_drop(self, reason: str) -> None:
        self.drops[reason] = self.drops.get(reason, 0) + 1


class PathMigration:
    """The slave's side of path migration, shared by every session of one socket."""

    def __init__(self, policy: AdmissionConfig, rng: random.Random, replies: TokenBucket) -> None:
        self._tokens = CookieJar(rng.randbytes(32), policy.cookie_lifetime)
        self._quiet = policy.migration_quiet
        rate = policy.migration_trials_per_second
        self._trials = TokenBucket(rate, max(1.0, rate / 10.0))
        self._replies = replies
        self.stats = MigrationStats()
        self.unclaimed = False
        """After :meth:`on_unattached` returned ``None``: True when no session can own the datagram
        (there is no established session, or every one is keyed, quiet, and none authenticated it),
        so that the caller may answer with a RESET; False when it may be a master's that moved
        (still heard at its old address, over the trial budget, an unkeyed session to validate) or
        was a PATH_RESPONSE."""

    def on_unattached(
        self, data: bytes, addr: Address, now: float, sessions: Iterable[Session]
    ) -> Session | bytes | None:
        """A datagram (not an OPEN) from ``addr``, which no session holds."""
        stats = self.stats
        stats.unattached += 1
        self.unclaimed = False
        size = len(data)
        if (
            size > HEADER_SIZE
            and data[0] >> 6 == _CONTROL
            and data[HEADER_SIZE] == ControlCode.PATH_RESPONSE
        ):
            return self._on_response(data, addr, now, sessions)
        movable = [conn for conn in sessions if conn.migratable]
        for conn in movable:
            if conn.move_back(data, addr, now=now):
                stats.migrations += 1
                stats.moved_back += 1
                return conn
        least = self._quiet
        quiet = [
            conn
            for conn in movable
            if conn.quiet_for(now) >= (least if conn.keyed else max(least, conn.live_gap))
        ]
        if not quiet:
            stats.count_drop("no_quiet_session")
            # A master that just moved may still be heard at its old address for a moment: only
            # with no established session at all can nobody own this datagram.
            self.unclaimed = not movable
            return None
        unkeyed: list[Session] = []
        tried = False
        for conn in quiet:
            if not conn.keyed:
                unkeyed.append(conn)
                continue
            if not self._trials.take(now):
                stats.count_drop("trial_budget")
                return None
            if not tried:
                stats.bytes_in += size
                tried = True
            stats.trials += 1
            verdict = conn.roam(data, addr, now=now)
            if verdict == ROAMED:
                stats.migrations += 1
                return conn
            if verdict == OURS:
                stats.count_drop("replayed")  # a live session's own: nobody answers it
                return None
        if not unkeyed:
            stats.count_drop("unauthenticated")
            self.unclaimed = len(quiet) == len(movable)  # every session tried, none owns it
            return None
        if size < CHALLENGE_SIZE:
            stats.count_drop("too_small")
            return None
        # Each quiet unkeyed session may have moved here: each pays for the challenge, and one
        # goes out if any has a token left (a flood draws at most its budget per session).
        granted = [conn.take_challenge(now) for conn in unkeyed]
        if not any(granted):
            stats.count_drop("challenge_budget")
            return None
        if not self._replies.take(now):
            stats.count_drop("rate_limited")
            return None
        token = self._tokens.mint(addr, _TOKEN_DOMAIN, now)
        datagram = _CHALLENGE_HEADER + encode_path_challenge(token)
        stats.challenges_sent += 1
        if not tried:
            stats.bytes_in += size
        stats.bytes_out += len(datagram)
        return datagram

    def _on_response(
        self, data: bytes, addr: Address, now: float, sessions: Iterable[Session]
    ) -> Session | None:
        stats = self.stats
        try:
            body = decode_control(data[HEADER_SIZE:])
        except MalformedPacketError:
            stats.count_drop("bad_control")
            return None
        assert isinstance(body, PathResponseBody)
        if not self._tokens.check(body.token, addr, _TOKEN_DOMAIN, now):
            stats.count_drop("bad_token")
            return None
        for conn in sessions:
            if (
                conn.migratable
                and not conn.keyed
                and hmac.compare_digest(conn.master_nonce, body.nonce)
            ):
                conn.migrate(addr, now=now)
                stats.migrations += 1
                return conn
        stats.count_drop("no_session")
        return None
