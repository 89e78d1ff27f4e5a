"""Packet protection for keyed sessions: one AEAD layer around the codec, as aioquic's crypto pair is.

Every datagram of a keyed session after the opening handshake is::

    prefix | PN (2 bytes) | body, sealed | tag (16 bytes)

``prefix`` is the 5-byte base header, plus the code byte for a CONTROL packet. ``PN`` is the low 16 bits
of the sender's *packet number*, a per-direction counter that every protected datagram consumes (DATA,
ACK, KEEPALIVE, CLOSE alike), so no two datagrams are ever sealed with the same AEAD nonce. The nonce is
the direction's IV XOR the full packet number; the associated data is ``prefix | PN``, so the header
(sequence numbers, acknowledgement, hold time) is authenticated although it travels in the clear. With
encryption off the body travels in the clear too and the tag covers it as associated data.

The receiver rebuilds the full packet number from the 16 wire bits (nearest to the highest
authenticated one + 1), refuses numbers its replay window has seen, verifies the tag, and only then
moves the window. 16 bits decode unambiguously while fewer than 32768 of the peer's datagrams are lost
in a row. After a longer loss run (a 33-second blackout at 1000 packets/s) that nearest number lies in
the past and the datagram would be refused as a replay for the rest of the session; so a datagram that
fails at the nearest number is tried at the numbers with the same 16 low bits further ahead
(:meth:`PacketOpener.open`, "resynchronisation"): as many steps of 65536 as the peer can have sent since
its last authenticated datagram (twice its fastest observed rate, at least 1000/s, times the silence,
plus two), at most :data:`RESYNC_TRIES_PER_SECOND` such searches a second. Only numbers above the
highest accepted are tried and the window only moves on a tag that verifies, so the replay guarantee
is unchanged; the budget bounds what a flood of forgeries can cost (docs/SECURITY.md).

The Connection calls this layer; the layer knows nothing about what the body means.
"""

from __future__ import annotations

import struct
from typing import Final

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives.ciphers.aead import AESGCM, ChaCha20Poly1305

from tdtp.protection.derivation import IV_SIZE, TrafficSecret
from tdtp.protection.replay_window import ReplayWindow
from tdtp.wire.control import CipherSuite
from tdtp.wire.protected import PN_SIZE, TAG_SIZE

PN_MODULUS: Final = 1 << (8 * PN_SIZE)
_PN_HALF: Final = PN_MODULUS >> 1

PACKET_LIMIT: Final = 1 << 32
"""Datagrams one direction's key may seal. AES-GCM keeps its confidentiality margin (2^-57, the bound
QUIC and TLS 1.3 aim for) for about 2^32 packets of up to 128 bytes; at 1000 packets/s that is 49 days of
one session. The connection ends with KEY_EXHAUSTED before the limit."""
FORGERY_LIMIT: Final = 1 << 36
"""Failed authentications one key tolerates (RFC 9001, section 6.6, for both suites here), after which
the connection ends. Far beyond any attacker's budget at any realistic link rate."""

RESYNC_TRIES_PER_SECOND: Final = 50.0
"""Resynchronisation searches a second (and at most this many saved up): the peer's first datagram
after a blackout is found within 20 ms at 1000 datagrams/s, and forgeries cannot make the receiver
spend more than this many searches' worth of AEAD checks a second."""
RESYNC_MAX_STEPS: Final = 4096
"""The longest search, in steps of 65536 packet numbers (268 million datagrams: three days at 1000/s)."""
_MIN_PEER_RATE: Final = 1000.0
_RATE_WINDOW: Final = 1.0

_PN: Final = struct.Struct(">H")
_pack_pn = _PN.pack
_unpack_pn = _PN.unpack_from

Aead = AESGCM | ChaCha20Poly1305


def make_aead(suite: CipherSuite, key: bytes) -> Aead:
    if suite is CipherSuite.AES_128_GCM:
        return AESGCM(key)
    if suite is CipherSuite.CHACHA20_POLY1305:
        return ChaCha20Poly1305(key)
    raise ValueError(f"no AEAD for cipher suite {suite!r}")


class Direction:
    """The AEAD state of one direction: key, IV and the nonce for a packet number."""

    __slots__ = ("_aead", "_iv")

    def __init__(self, suite: CipherSuite, secret: TrafficSecret) -> None:
        self._aead = make_aead(suite, secret.key)
        self._iv = int.from_bytes(secret.iv, "big")

    def _nonce(self, number: int) -> bytes:
        return (self._iv ^ number).to_bytes(IV_SIZE, "big")

    def tag(self, number: int, message: bytes) -> bytes:
        """A tag over ``message`` (authenticated, not encrypted) under packet number ``number``."""
        return self._aead.encrypt(self._nonce(number), b"", message)

    def verify(self, number: int, message: bytes | memoryview, tag: bytes | memoryview) -> bool:
        try:
            self._aead.decrypt(self._nonce(number), bytes(tag), bytes(message))
        except InvalidTag:
            return False
        return True


class PacketSealer(Direction):
    """Seals what one endpoint sends."""

    __slots__ = ("_encrypt", "next_number")

    def __init__(self, suite: CipherSuite, secret: TrafficSecret, *, encrypt: bool) -> None:
        super().__init__(suite, secret)
        self._encrypt = encrypt
        self.next_number = 0
        """The packet number the next sealed datagram gets."""

    @property
    def exhausted(self) -> bool:
        return self.next_number >= PACKET_LIMIT

    def take_number(self) -> int:
        number = self.next_number
        self.next_number = number + 1
        return number

    def seal(self, prefix: bytes, body: bytes) -> bytes:
        """``prefix | PN | sealed body | tag``."""
        number = self.next_number
        self.next_number = number + 1
        aad = prefix + _pack_pn(number & 0xFFFF)
        nonce = (self._iv ^ number).to_bytes(IV_SIZE, "big")
        if self._encrypt:
            return aad + self._aead.encrypt(nonce, body, aad)
        return aad + body + self._aead.encrypt(nonce, b"", aad + body)


class PacketOpener(Direction):
    """Checks and opens what the peer sends: packet-number expansion, replay window, AEAD."""

    __slots__ = (
        "_counted",
        "_counted_since",
        "_encrypt",
        "_last_accepted",
        "_peak_rate",
        "_resync_budget",
        "_resync_checked",
        "failure",
        "forgeries",
        "resyncs",
        "window",
    )

    def __init__(self, suite: CipherSuite, secret: TrafficSecret, *, encrypt: bool) -> None:
        super().__init__(suite, secret)
        self._encrypt = encrypt
        self.window = ReplayWindow()
        self.forgeries = 0
        """Datagrams whose tag did not verify."""
        self.failure = ""
        """Why the last :meth:`open` returned ``None``: ``"unauthenticated"`` or ``"replayed"``."""
        self.resyncs = 0
        """Datagrams found only by the resynchronisation search (after a long loss run)."""
        self._last_accepted: float | None = None  # ``now`` of the last authenticated datagram
        self._peak_rate = 0.0  # the peer's fastest authenticated datagrams/s over a whole window
        self._counted = 0
        self._counted_since: float | None = None
        self._resync_budget = RESYNC_TRIES_PER_SECOND
        self._resync_checked: float | None = None

    @property
    def exhausted(self) -> bool:
        return self.forgeries >= FORGERY_LIMIT

    def expand(self, truncated: int) -> int:
        """The full packet number nearest to the highest accepted + 1 with these 16 low bits."""
        expected = self.window.highest + 1
        number = expected + ((truncated - expected + _PN_HALF) % PN_MODULUS) - _PN_HALF
        return number if number >= 0 else number + PN_MODULUS

    def open(self, datagram: bytes, prefix_size: int, now: float | None = None) -> bytes | None:
        """The plaintext body of ``datagram`` (at least ``prefix_size + PROTECTION_OVERHEAD`` bytes long), or
        ``None`` with :attr:`failure` saying why. ``now`` (the caller's clock) bounds the search for
        the packet number after a long loss run; without it the search spans two steps."""
        head = prefix_size + PN_SIZE
        number = self.expand(_unpack_pn(datagram, prefix_size)[0])
        window = self.window
        if window.seen(number):
            self.failure = "replayed"
            body = None
        else:
            body = self._decrypt(datagram, head, number)
            if body is None:
                self.forgeries += 1
                self.failure = "unauthenticated"
        if body is None:
            number = self._resync(datagram, head, number, now)
            if number < 0:
                return None
            body = self._decrypt(datagram, head, number)
            assert body is not None  # _resync verified it
        window.accept(number)
        if now is not None:
            self._on_accepted(now)
        return body

    def trial_open(self, datagram: bytes, prefix_size: int, now: float) -> bytes | None:
        """:meth:`open` for a datagram from an address that is not the peer's (path migration):
        only a packet number above every one accepted so far qualifies (a replay, or a late packet
        of the old path, never moves a session), a failure is not counted as a forgery (the
        datagram may simply belong to another session) and there is no resynchronisation search.
        ``None`` with :attr:`failure` ``"replayed"`` when the datagram authenticates at a number
        accepted already or too old (a copy of one of this session's own datagrams: its owner is
        alive, and nobody may answer it with a RESET), else ``"unauthenticated"``."""
        head = prefix_size + PN_SIZE
        number = self.expand(_unpack_pn(datagram, prefix_size)[0])
        window = self.window
        body = self._decrypt(datagram, head, number)
        if body is None:
            self.failure = "unauthenticated"
            return None
        if number <= window.highest:
            self.failure = "replayed"
            return None
        window.accept(number)
        self._on_accepted(now)
        return body

    def _decrypt(self, datagram: bytes, head: int, number: int) -> bytes | None:
        aad = datagram[:head]
        nonce = (self._iv ^ number).to_bytes(IV_SIZE, "big")
        try:
            if self._encrypt:
                return self._aead.decrypt(nonce, datagram[head:], aad)
            self._aead.decrypt(nonce, datagram[-TAG_SIZE:], datagram[:-TAG_SIZE])
        except InvalidTag:
            return None
        return datagram[head:-TAG_SIZE]

    def _resync(self, datagram: bytes, head: int, nearest: int, now: float | None) -> int:
        """The packet number ahead of ``nearest`` (same 16 low bits) under which ``datagram``
        authenticates, or -1. Only numbers above the highest accepted are tried, within the budget."""
        if now is not None:
            checked = self._resync_checked
            if checked is not None and now > checked:
                self._resync_budget = min(
                    RESYNC_TRIES_PER_SECOND,
                    self._resync_budget + (now - checked) * RESYNC_TRIES_PER_SECOND,
                )
            self._resync_checked = now
        if self._resync_budget < 1.0:
            return -1
        self._resync_budget -= 1.0
        steps = 2
        last = self._last_accepted
        if now is not None and last is not None and now > last:
            rate = 2.0 * max(self._peak_rate, _MIN_PEER_RATE)
            steps += int((now - last) * rate / PN_MODULUS) + 1
        if steps > RESYNC_MAX_STEPS:
            steps = RESYNC_MAX_STEPS
        highest = self.window.highest
        number = nearest
        while number <= highest:
            number += PN_MODULUS
        for _ in range(steps):
            if self._decrypt(datagram, head, number) is not None:
                self.resyncs += 1
                return number
            number += PN_MODULUS
        return -1

    def _on_accepted(self, now: float) -> None:
        self._last_accepted = now
        since = self._counted_since
        if since is None:
            self._counted_since = now
            self._counted = 1
            return
        self._counted += 1
        elapsed = now - since
        if elapsed >= _RATE_WINDOW:
            rate = self._counted / elapsed
            if rate > self._peak_rate:
                self._peak_rate = rate
            self._counted_since = now
            self._counted = 0

    def verify_numbered(self, truncated: int, message: bytes, tag: bytes) -> bool:
        """Check a tag over a clear ``message`` that names its own packet number (OPEN_ACK), through
        the same replay window as :meth:`open`."""
        number = self.expand(truncated)
        if self.window.seen(number):
            self.failure = "replayed"
            return False
        if not self.verify(number, message, tag):
            self.forgeries += 1
            self.failure = "unauthenticated"
            return False
        self.window.accept(number)
        return True
