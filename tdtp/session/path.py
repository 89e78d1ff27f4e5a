"""The path to the peer: whether the slave has validated its master's current address, and the
amplification limit that applies until it has (docs/PROTOCOL.md section 5.8).

A NAT rebinding moves a master to a new source address in the middle of a session. The slave follows
it (a keyed session on the first datagram from there that authenticates, an unkeyed one after a
PATH_CHALLENGE its master answers), but an address a datagram merely *came from* may be a victim's: a
replayed or spoofed datagram must not turn the slave's 1 kHz stream into a flood at somebody else. So
until the new address is validated the slave sends it at most three times the bytes it received from
it (QUIC's rule, RFC 9000 section 8.1) and holds everything else. A keyed path is validated by an
authenticated datagram from it that acknowledges a packet sent on it (only the key holder receiving at
that address can write one). An unkeyed path rests on the master's nonce, which an on-path attacker
has seen: the PATH_RESPONSE that moved it proves nothing against one, so it counts as validated only
once the old address has stayed silent for ``silence_timeout`` after the move, and the session goes
straight back to the old address (validated before) if that speaks first. PATH_CHALLENGEs sent on a
session's behalf draw from a bucket of its own (:data:`CHALLENGES_PER_SECOND`).

:class:`PeerPath` holds that state and its counters; the connection asks it before it sends. A master
keeps its socket and needs nothing but the pacing of its PATH_RESPONSEs, also kept here.
"""

from __future__ import annotations

import math
from typing import Final

from tdtp.admission.rate_limit import TokenBucket
from tdtp.config import ConnectionConfig
from tdtp.protection.packet_protection import PacketOpener
from tdtp.session.stats import ConnectionStats, DropReason
from tdtp.wire.control import (
    HANDSHAKE_CODES,
    KEEPALIVE_BODY_SIZE,
    OPEN_BODY_SIZE,
    PATH_CODES,
    PathChallengeBody,
    decode_control,
    encode_path_response,
)
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE, PacketType, encode_header
from tdtp.wire.hold import HOLD_NO_ACK
from tdtp.wire.protected import PROTECTION_OVERHEAD, TAG_SIZE

AMPLIFICATION_FACTOR: Final = 3
"""Bytes the slave may send to an unvalidated address per byte received from it."""
CHALLENGES_PER_SECOND: Final = 10.0
"""PATH_CHALLENGEs a quiet unkeyed session may draw a second (in bursts of :data:`CHALLENGE_BURST`):
a flood of datagrams from unknown addresses cannot turn into a stream of challenges."""
CHALLENGE_BURST: Final = 3.0
PATH_RESPONSE_INTERVAL: Final = 0.005
"""A master answers at most one PATH_CHALLENGE per this many seconds (a forged challenge from the
slave's address buys at most this many responses, each sent to the slave)."""
_CONTROL: Final = int(PacketType.CONTROL)
_RESPONSE_HEADER: Final = encode_header(_CONTROL, 0, 0, 0, HOLD_NO_ACK)
_NOT_SESSION: Final = HANDSHAKE_CODES | PATH_CODES


class PeerPath:
    """Validation state of the peer's current address and its amplification budget."""

    __slots__ = (
        "_challenges",
        "_exchange",
        "_stats",
        "allowance",
        "first_seq",
        "last_response",
        "limited",
        "most",
        "previous",
        "proven_at",
    )

    def __init__(self, config: ConnectionConfig, stats: ConnectionStats) -> None:
        self._stats = stats
        # Besides a sample, one flush emits at most two ACKs and a KEEPALIVE.
        self._exchange = 3 * (
            max(config.ack_size, HEADER_SIZE + KEEPALIVE_BODY_SIZE) + PROTECTION_OVERHEAD
        )
        self.limited = False
        """True while the peer's address is not validated: sends are limited by :attr:`allowance`."""
        self.allowance = 0
        """Bytes still allowed to the unvalidated address."""
        self.most = 0
        """The most bytes one flush of the connection can emit (it waits for that much allowance)."""
        self.first_seq = 0
        """Keyed: the first sequence number sent on the new path; an ACK at or above it validates."""
        self.last_response = -1.0
        """Master: ``now`` of the last PATH_RESPONSE sent (-1 before any)."""
        self.previous: tuple[str, int] | None = None
        """Unkeyed, after a move not proven yet: the address the session moved from."""
        self.proven_at = math.inf
        """Unkeyed, after a move: when the new path counts as validated (the old address silent)."""
        self._challenges = TokenBucket(CHALLENGES_PER_SECOND, CHALLENGE_BURST)

    @staticmethod
    def trial(opener: PacketOpener, data: bytes, now: float) -> bytes | None:
        """A keyed session datagram from an unknown address, opened (header, code and plaintext)
        if it authenticates with a packet number above every one accepted; else ``None``."""
        opener.failure = ""
        size = len(data)
        ptype = data[0] >> 6 if data else _CONTROL
        prefix = HEADER_SIZE + 1 if ptype == _CONTROL else HEADER_SIZE
        if ptype > _CONTROL or size < prefix + PROTECTION_OVERHEAD:
            return None
        if ptype == _CONTROL and data[HEADER_SIZE] in _NOT_SESSION:
            return None
        body = opener.trial_open(data, prefix, now)
        return None if body is None else data[:prefix] + body

    def move(self, received: int, next_seq: int, payload_limit: int) -> None:
        """A keyed session follows its master to a new address; ``received``: the bytes of the
        datagram that moved it; ``payload_limit``: the largest payload we send."""
        self._limit(payload_limit)
        self.first_seq = next_seq
        self.on_received(received)

    def move_unproven(
        self, previous: tuple[str, int] | None, proven_at: float, payload_limit: int
    ) -> None:
        """An unkeyed session follows its PATH_RESPONSE from ``previous``: limited until
        ``proven_at`` (:meth:`blocked` lifts it), or until ``previous`` speaks (:meth:`returning`)."""
        self._limit(payload_limit)
        if self.previous is None:  # a second move before the first was proven: back to the first
            self.previous = previous
        self.proven_at = proven_at

    def _limit(self, payload_limit: int) -> None:
        self._stats.migrations += 1
        self.limited = True
        self.allowance = 0
        largest = HEADER_SIZE + max(payload_limit, OPEN_BODY_SIZE + TAG_SIZE) + PROTECTION_OVERHEAD
        self.most = largest + self._exchange

    def returning(self, addr: tuple[str, int]) -> bool:
        """Unkeyed, moved and not proven yet: ``addr`` is the old address (it speaks again), and
        the session goes back there (validated before): True."""
        previous = self.previous
        if previous is None or addr[:2] != previous[:2]:
            return False
        self.previous = None
        self.proven_at = math.inf
        self.limited = False
        self._stats.migrations += 1
        return True

    def take_challenge(self, now: float) -> bool:
        """One of this session's PATH_CHALLENGE tokens, if it has one left."""
        return self._challenges.take(now)

    def blocked(self, queued: list[tuple[bytes, tuple[str, int], int, bool]], now: float) -> bool:
        """Whether the allowance left is too small for a flush, ``queued`` control datagrams
        included (nothing may leave before more arrives from the new path). Lifts the limit of an
        unkeyed move whose old address stayed silent until ``proven_at``."""
        if not self.limited:
            return False
        if now >= self.proven_at:
            self.previous = None
            self.proven_at = math.inf
            self.limited = False
            self._stats.paths_validated += 1
            return False
        return self.allowance < self.most + sum(len(entry[0]) for entry in queued)

    def on_received(self, size: int) -> None:
        """A datagram of ``size`` bytes from the unvalidated address (:attr:`limited`)."""
        self.allowance += AMPLIFICATION_FACTOR * size
        self._stats.unvalidated_bytes_in += size

    def on_sent(self, out: list[tuple[bytes, tuple[str, int]]]) -> None:
        """What one flush sent to the unvalidated address."""
        size = sum(len(entry[0]) for entry in out)
        self.allowance -= size
        self._stats.unvalidated_bytes_out += size

    def on_acked(self, largest_acked: int) -> None:
        """An authenticated acknowledgement from the new address: validated once it covers a packet
        sent on the new path."""
        if self.previous is None and largest_acked >= self.first_seq:
            self.limited = False
            self._stats.paths_validated += 1

    def answer(self, data: bytes, now: float, answering: bool, nonce: bytes) -> bytes | None:
        """A PATH_RESPONSE to a PATH_CHALLENGE from the slave's address (``answering``: we are an
        established unkeyed master), else ``None`` with the drop counted. Not a sign of life: anyone
        can send a challenge. A PATH_RESPONSE sent to a connection is unexpected (the server takes
        those)."""
        stats = self._stats
        try:
            body = decode_control(data[HEADER_SIZE:])
        except MalformedPacketError:
            stats.count_drop(DropReason.BAD_CONTROL)
            return None
        if not answering or not isinstance(body, PathChallengeBody):
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)
            return None
        if self.last_response >= 0.0 and now - self.last_response < PATH_RESPONSE_INTERVAL:
            stats.count_drop(DropReason.RATE_LIMITED)
            return None
        self.last_response = now
        stats.received.control_packets += 1
        return _RESPONSE_HEADER + encode_path_response(body.token, nonce)
