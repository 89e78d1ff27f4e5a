"""A slave's front door: what it does with an OPEN before any per-session state exists.

Sans-IO, like the connection. :meth:`Admission.admit` takes one OPEN datagram and returns one of

* an :class:`AdmittedOpen`: the master proved it receives at its address (a valid cookie) and, for a
  keyed slave, that it holds a key of the ring (the OPEN's tag verified). Only now may the caller
  create a connection, answer OPEN_ACK and spend a ``max_peers`` slot;
* a :class:`Reply`: a datagram to send back to the source, never larger than the OPEN (a COOKIE, or
  a REJECT that says why the master cannot be served), with the reason the OPEN was not taken;
* a :class:`~tdtp.wire.drop_reason.DropReason`: nothing is sent.

Checks, in order: the version (an unknown one gets REJECT if that is no larger than the OPEN); the
body; the cookie (none or a stale one: the per-source OPEN rate, then a COOKIE within the global
reply budget; a valid one skips the rate, so floods that prove nothing cannot hold back an OPEN that
proves its address); then, with the address validated, the key (REJECT ``KEY_REQUIRED`` / ``KEY_UNKNOWN``
/ ``SUITE_UNSUPPORTED``; a tag that does not verify is dropped silently, as WireGuard answers nothing
unauthenticated) and the payload size (REJECT ``PAYLOAD_TOO_SMALL``).

A server with many sessions shares one :class:`Admission` (one cookie secret, one rate table); a
stand-alone slave :class:`~tdtp.session.connection.Connection` makes its own.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from typing import Final, NamedTuple

from tdtp.admission.cookie import CookieJar
from tdtp.admission.path_migration import PathMigration
from tdtp.admission.rate_limit import SourceRateLimiter, TokenBucket
from tdtp.config import ConnectionConfig, Role
from tdtp.protection.derivation import derive_open_secret, reset_tag
from tdtp.protection.keys import KeyRing, PresharedKey
from tdtp.protection.packet_protection import Direction
from tdtp.wire.address import Address
from tdtp.wire.control import (
    CLOSE_BODY_SIZE,
    NO_COOKIE,
    NO_KEY_ID,
    NONCE_SIZE,
    OPEN_NONCE_OFFSET,
    PROTOCOL_VERSION,
    RESET_ECHO_SIZE,
    RESET_SIZE,
    RESET_TAG_SIZE,
    CipherSuite,
    CloseReason,
    ControlCode,
    OpenBody,
    OpenFlags,
    decode_control,
    encode_close,
    encode_cookie,
    encode_reset,
    open_version,
)
from tdtp.wire.drop_reason import DropReason
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE, PacketType, decode_header, encode_header
from tdtp.wire.hold import HOLD_NO_ACK
from tdtp.wire.protected import TAG_SIZE

_CONTROL: Final = int(PacketType.CONTROL)
_ANSWERED_CONTROL: Final = frozenset(
    int(code) for code in (ControlCode.KEEPALIVE, ControlCode.TIMESTAMP, ControlCode.TIMED_DATA)
)
"""The CONTROL codes a RESET answers: session traffic that stands for a sample or an
acknowledgement (at a low sample rate every sample may be a TIMED_DATA: PROTOCOL.md 5.13)."""
_REJECT_SIZE: Final = HEADER_SIZE + CLOSE_BODY_SIZE
_REPLY_HEADER: Final = encode_header(_CONTROL, 0, 0, 0, HOLD_NO_ACK)
"""The base header of every reply to an unvalidated OPEN (no sequence, nothing acknowledged)."""


@dataclass(frozen=True, slots=True)
class AdmittedOpen:
    """An OPEN from a validated address (and, keyed, an authenticated master)."""

    body: OpenBody
    initial_seq: int
    """The master's initial data sequence number (the OPEN header's SEQ, 12 bits)."""
    key: PresharedKey | None
    """The master's key, found in the slave's ring; ``None`` for an unkeyed session."""
    size: int
    """Bytes of the OPEN datagram."""


class Reply(NamedTuple):
    """An answer to an OPEN that is not admitted."""

    datagram: bytes
    """COOKIE or REJECT, for the OPEN's source address."""
    reason: DropReason
    """``unvalidated`` (a COOKIE), ``refused`` or ``unknown_version`` (a REJECT)."""


@dataclass(slots=True)
class AdmissionStats:
    """What the front door did with the OPENs it saw."""

    opens: int = 0
    admitted: int = 0
    cookies_sent: int = 0
    rejects_sent: int = 0
    drops: dict[str, int] = field(default_factory=dict)
    """OPENs dropped without an answer, by reason (``rate_limited``, ``unauthenticated``, ...)."""
    bytes_in: int = 0
    """Bytes of every OPEN seen."""
    bytes_out: int = 0
    """Bytes of every COOKIE and REJECT sent back: at most ``bytes_in`` by construction."""
    strangers: int = 0
    """Session datagrams (DATA, ACK, KEEPALIVE) of at least 22 bytes (the size of a RESET) from
    addresses holding no session: the ones a RESET may answer."""
    resets_sent: int = 0
    """RESETs answering them (the rest were too small to answer, or over the RESET budget)."""
    reset_bytes_in: int = 0
    """Bytes of the session datagrams answered with a RESET."""
    reset_bytes_out: int = 0
    """Bytes of those RESETs: at most ``reset_bytes_in`` by construction."""

    def count_drop(self, reason: DropReason) -> None:
        self.drops[reason.value] = self.drops.get(reason.value, 0) + 1


def reject_datagram(nonce: bytes, reason: CloseReason) -> bytes:
    """A REJECT for the master that sent ``nonce`` (23 bytes: smaller than any OPEN)."""
    return _REPLY_HEADER + encode_close(ControlCode.REJECT, nonce, reason)


class Admission:
    """Cookie minting and checking, OPEN rate limits and key checks for one slave socket."""

    def __init__(
        self,
        config: ConnectionConfig | None = None,
        keys: KeyRing | None = None,
        *,
        rng: random.Random | None = None,
        role: Role = Role.SLAVE,
    ) -> None:
        self.config = config if config is not None else ConnectionConfig()
        self.keys = keys
        self.role = role
        """The listener's own role: an OPEN from a dialer of the same role is refused
        (``ROLE_CONFLICT``)."""
        policy = self.config.admission
        rng = rng if rng is not None else random.SystemRandom()
        self._cookies = CookieJar(rng.randbytes(32), policy.cookie_lifetime)
        self._per_source = SourceRateLimiter(
            policy.opens_per_source, policy.open_burst, policy.max_sources
        )
        self._replies = TokenBucket(policy.replies_per_second, policy.replies_per_second)
        self._resets = TokenBucket(policy.resets_per_second, policy.resets_per_second)
        self._reset_keys: tuple[bytes, ...] = (
            tuple(key.reset_key for key in keys) if keys is not None else ()
        )
        self.stats = AdmissionStats()
        self.paths = PathMigration(policy, rng, self._replies)
        """Path migration: finds the session a datagram from an unknown address belongs to."""

    def reset(self, data: bytes, now: float) -> bytes | None:
        """A RESET for a session datagram (DATA, ACK, KEEPALIVE, TIMESTAMP, TIMED_DATA) from an address holding no
        session, or ``None``: not a session datagram, too small to answer without amplifying, or
        over the RESET budget. Unkeyed it echoes the datagram's first 16 bytes; keyed it adds one
        tag per key of the ring, as many as fit in the datagram's size (PROTOCOL.md 5.7)."""
        size = len(data)
        if size < RESET_SIZE:
            return None
        ptype = data[0] >> 6
        if ptype > _CONTROL or (ptype == _CONTROL and data[HEADER_SIZE] not in _ANSWERED_CONTROL):
            return None
        stats = self.stats
        stats.strangers += 1
        reset_keys = self._reset_keys
        tags: tuple[bytes, ...] = ()
        echo = data[:RESET_ECHO_SIZE]
        if reset_keys:
            fit = (size - RESET_SIZE) // RESET_TAG_SIZE
            if fit == 0:
                return None
            if not self._resets.take(now):
                return None
            tags = tuple(reset_tag(key, echo) for key in reset_keys[:fit])
        elif not self._resets.take(now):
            return None
        datagram = _REPLY_HEADER + encode_reset(echo, tags)
        stats.resets_sent += 1
        stats.reset_bytes_in += size
        stats.reset_bytes_out += len(datagram)
        return datagram

    def admit(self, data: bytes, addr: Address, now: float) -> AdmittedOpen | Reply | DropReason:
        """Judge one datagram that claims to be an OPEN (see the module docstring)."""
        stats = self.stats
        stats.opens += 1
        size = len(data)
        stats.bytes_in += size
        verdict = self._judge(data, addr, now)
        if isinstance(verdict, DropReason):
            stats.count_drop(verdict)
        elif isinstance(verdict, Reply):
            if len(verdict.datagram) > size:  # never amplify: the layouts make this unreachable
                stats.count_drop(DropReason.OVERSIZED)
                return DropReason.OVERSIZED
            if verdict.reason is DropReason.UNVALIDATED:
                stats.cookies_sent += 1
            else:
                stats.rejects_sent += 1
            stats.bytes_out += len(verdict.datagram)
        else:
            stats.admitted += 1
        return verdict

    def reject(self, admitted: AdmittedOpen, reason: CloseReason) -> bytes:
        """A REJECT for an admitted master that cannot be served (e.g. ``BUSY``)."""
        self.stats.rejects_sent += 1
        datagram = reject_datagram(admitted.body.nonce, reason)
        self.stats.bytes_out += len(datagram)
        return datagram

    def _reply(self, datagram: bytes, reason: DropReason, now: float) -> Reply | DropReason:
        """An answer to a source not validated yet, within the global reply budget."""
        return Reply(datagram, reason) if self._replies.take(now) else DropReason.RATE_LIMITED

    def _judge(self, data: bytes, addr: Address, now: float) -> AdmittedOpen | Reply | DropReason:
        if (
            len(data) <= HEADER_SIZE
            or data[0] >> 6 != _CONTROL
            or data[HEADER_SIZE] != ControlCode.OPEN
        ):
            return DropReason.UNEXPECTED_CONTROL
        body_bytes = data[HEADER_SIZE:]
        version = open_version(body_bytes)
        if version != PROTOCOL_VERSION:
            if not self._per_source.allow(addr, now):
                return DropReason.RATE_LIMITED
            if size_allows_reject(len(data)):
                # The nonce where versions 2 and 3 have it: a later version that keeps it there can tell.
                nonce = bytes(body_bytes[OPEN_NONCE_OFFSET : OPEN_NONCE_OFFSET + NONCE_SIZE]).ljust(
                    NONCE_SIZE, b"\0"
                )
                return self._reply(
                    reject_datagram(nonce, CloseReason.VERSION_UNSUPPORTED),
                    DropReason.UNKNOWN_VERSION,
                    now,
                )
            return DropReason.UNKNOWN_VERSION
        try:
            body = decode_control(body_bytes)
        except MalformedPacketError:
            return DropReason.BAD_CONTROL
        assert isinstance(body, OpenBody)  # the code byte said OPEN
        keyed = bool(body.flags & OpenFlags.KEYED)
        if (
            body.max_payload == 0
            or (body.flags & OpenFlags.ENCRYPTED and not keyed)
            or keyed != (body.suite != CipherSuite.NONE)
            or (not keyed and body.key_id != NO_KEY_ID)
        ):
            return DropReason.BAD_CONTROL
        if body.cookie == NO_COOKIE or not self._cookies.check(body.cookie, addr, body.nonce, now):
            # Not validated yet: the per-source limit applies, per address *and port*, so that
            # forged OPENs from the master's host with other ports cannot use up the master's
            # share. An OPEN with a valid cookie skips it: no flood of OPENs that prove nothing
            # can hold back one that proves its address (PROTOCOL.md 5.1, rule 2).
            if not self._per_source.allow(addr, now):
                return DropReason.RATE_LIMITED
            cookie = self._cookies.mint(addr, body.nonce, now)
            return self._reply(
                _REPLY_HEADER + encode_cookie(body.nonce, cookie),
                DropReason.UNVALIDATED,
                now,
            )
        # The master receives at this address: answers to it are no longer reflections.
        if bool(body.flags & OpenFlags.SLAVE_DIALS) != (self.role is Role.MASTER):
            return _refuse(body.nonce, CloseReason.ROLE_CONFLICT)
        key: PresharedKey | None = None
        keys = self.keys
        if keys is not None and not keyed:
            return _refuse(body.nonce, CloseReason.KEY_REQUIRED)
        if keyed:
            key = keys.find(body.key_id) if keys is not None else None
            if key is None:
                return _refuse(body.nonce, CloseReason.KEY_UNKNOWN)
            try:
                suite = CipherSuite(body.suite)
            except ValueError:
                return _refuse(body.nonce, CloseReason.SUITE_UNSUPPORTED)
            verifier = Direction(suite, derive_open_secret(key.secret, body.nonce, suite))
            if not verifier.verify(body.attempt, data[:-TAG_SIZE], data[-TAG_SIZE:]):
                return DropReason.UNAUTHENTICATED
        if body.max_payload < self.config.min_peer_payload:
            return _refuse(body.nonce, CloseReason.PAYLOAD_TOO_SMALL)
        return AdmittedOpen(body, decode_header(data).seq, key, len(data))


def _refuse(nonce: bytes, reason: CloseReason) -> Reply:
    return Reply(reject_datagram(nonce, reason), DropReason.REFUSED)


def size_allows_reject(open_size: int) -> bool:
    """A REJECT may answer an unvalidated source only if it is no larger than what it answers."""
    return open_size >= _REJECT_SIZE
