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
in a row: at 1000 packets/s, a 32-second outage with the peer sending all the while.

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

    __slots__ = ("_encrypt", "failure", "forgeries", "window")

    def __init__(self, suite: CipherSuite, secret: TrafficSecret, *, encrypt: bool) -> None:
        super().__init__(suite, secret)
        self._encrypt = encrypt
        self.window = ReplayWindow()
        self.forgeries = 0
        """Datagrams whose tag did not verify."""
        self.failure = ""
        """Why the last :meth:`open` returned ``None``: ``"unauthenticated"`` or ``"replayed"``."""

    @property
    def exhausted(self) -> bool:
        return self.forgeries >= FORGERY_LIMIT

    def expand(self, truncated: int) -> int:
        """The full packet number nearest to the highest accepted + 1 with these 16 low bits."""
        expected = self.window.highest + 1
        number = expected + ((truncated - expected + _PN_HALF) % PN_MODULUS) - _PN_HALF
        return number if number >= 0 else number + PN_MODULUS

    def open(self, datagram: bytes, prefix_size: int) -> bytes | None:
        """The plaintext body of ``datagram`` (at least ``prefix_size + PROTECTION_OVERHEAD`` bytes long), or
        ``None`` with :attr:`failure` saying why."""
        head = prefix_size + PN_SIZE
        number = self.expand(_unpack_pn(datagram, prefix_size)[0])
        window = self.window
        if window.seen(number):
            self.failure = "replayed"
            return None
        aad = datagram[:head]
        nonce = (self._iv ^ number).to_bytes(IV_SIZE, "big")
        try:
            if self._encrypt:
                body = self._aead.decrypt(nonce, datagram[head:], aad)
            else:
                body = datagram[head:-TAG_SIZE]
                self._aead.decrypt(nonce, datagram[-TAG_SIZE:], datagram[:-TAG_SIZE])
        except InvalidTag:
            self.forgeries += 1
            self.failure = "unauthenticated"
            return None
        window.accept(number)
        return body

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
