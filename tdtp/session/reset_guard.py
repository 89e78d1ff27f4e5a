"""A master's memory of what it sent lately, to tell a real RESET from a forged one.

A slave that restarted holds no session for its old master, and answers the master's next session
datagram with a RESET echoing that datagram's first 16 bytes (docs/PROTOCOL.md section 5.7). The master
takes a RESET only if the echo is the first 16 bytes of one of the last :data:`RESET_MEMORY` datagrams it
sent in this session: an off-path attacker never sees them (header, packet number, then payload or
ciphertext bytes), as RFC 5961 makes a TCP RST match the exact sequence number. A keyed master also
requires one of the RESET's tags to be HMAC-SHA256 of the echo under its key's reset key, which only a
holder of the pre-shared key can compute: an on-path attacker who sees the echo cannot end a keyed
session either.

Neither proves that the slave lost the session: a copy of one of our datagrams, replayed to the
slave from another address or to another slave holding the same key, draws a RESET as genuine as a
restarted slave's (docs/SECURITY.md). What only a slave that lost our session shows is silence: a
slave that holds it answers, or at least sends a KEEPALIVE, within our ``silence_timeout``. So a
RESET is taken only while the slave has been silent that long (the watchdog's verdict); one that
arrives while the slave is heard is dropped as ``peer_alive``, and the next RESET (each datagram we
send into a restarted slave draws one) ends the session once the silence is long enough.

The per-datagram cost is one 16-byte slice appended to a bounded deque.
"""

from __future__ import annotations

import hmac
from collections import deque
from typing import Final

from tdtp.protection.derivation import reset_tag
from tdtp.session.stats import DropReason
from tdtp.wire.control import RESET_ECHO_SIZE, ResetBody, decode_reset
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE

RESET_MEMORY: Final = 256
"""Datagrams whose first bytes a master remembers: a RESET answers one of them (at 1 kHz, the last
256 ms; a RESET takes one RTT to come back)."""


class ResetGuard:
    """The first bytes of the datagrams a master sent lately, and its key's reset key (keyed)."""

    def __init__(self, reset_key: bytes | None) -> None:
        self.recent: deque[bytes] = deque(maxlen=RESET_MEMORY)
        """First :data:`RESET_ECHO_SIZE` bytes of each recent session datagram, oldest first."""
        self.reset_key = reset_key

    def record(self, datagram: bytes) -> None:
        self.recent.append(datagram[:RESET_ECHO_SIZE])

    def judge(self, data: bytes, silent: bool) -> DropReason | None:
        """``None`` for a RESET datagram that answers a datagram we sent while the slave is
        ``silent`` (nothing from it for our ``silence_timeout``), else why it is dropped."""
        try:
            body = decode_reset(data[HEADER_SIZE:])
        except MalformedPacketError:
            return DropReason.BAD_CONTROL
        if not self.verify(body):
            return DropReason.UNMATCHED_RESET
        return None if silent else DropReason.PEER_ALIVE

    def verify(self, body: ResetBody) -> bool:
        """Whether the RESET answers a datagram we sent (and, keyed, comes from a key holder)."""
        echo = body.echo
        if echo not in self.recent:
            return False
        reset_key = self.reset_key
        if reset_key is None:
            return True
        expected = reset_tag(reset_key, echo)
        return any(hmac.compare_digest(tag, expected) for tag in body.tags)
