"""Stateless address-validation cookies, as QUIC's Retry token and WireGuard's cookie reply provide.

A slave answers an OPEN that carries no valid cookie with a COOKIE message and keeps no state. The
cookie binds the master's source address and port, its nonce and a coarse timestamp under a secret
only the slave knows::

    cookie = timestamp (4 bytes, 1/16 s) | HMAC-SHA256(secret, timestamp | address | port | nonce)[:12]

A master that echoes it within ``lifetime`` proves it receives datagrams at that address: a forged
source address never sees the cookie. A 96-bit MAC cannot be guessed; the timestamp bounds how long a
captured cookie can be replayed from the same address.
"""

from __future__ import annotations

import hmac
import struct
from typing import Final

from tdtp.wire.address import Address
from tdtp.wire.control import COOKIE_SIZE

TICKS_PER_SECOND: Final = 16
_TICK_MODULUS: Final = 1 << 32
_TIMESTAMP: Final = struct.Struct(">I")
_MAC_SIZE: Final = COOKIE_SIZE - _TIMESTAMP.size


def _address_bytes(addr: Address) -> bytes:
    return f"{addr[0]}|{addr[1]}".encode()


class CookieJar:
    """Mints and checks cookies. Holds only its secret: checking needs no table."""

    __slots__ = ("_lifetime_ticks", "_secret")

    def __init__(self, secret: bytes, lifetime: float) -> None:
        if len(secret) < 16:
            raise ValueError("a cookie secret needs at least 16 random bytes")
        self._secret = secret
        self._lifetime_ticks = max(1, round(lifetime * TICKS_PER_SECOND))

    def _mac(self, stamp: bytes, addr: Address, nonce: bytes) -> bytes:
        message = stamp + _address_bytes(addr) + nonce
        return hmac.digest(self._secret, message, "sha256")[:_MAC_SIZE]

    def mint(self, addr: Address, nonce: bytes, now: float) -> bytes:
        stamp = _TIMESTAMP.pack(int(now * TICKS_PER_SECOND) % _TICK_MODULUS)
        return stamp + self._mac(stamp, addr, nonce)

    def check(self, cookie: bytes, addr: Address, nonce: bytes, now: float) -> bool:
        """True if ``cookie`` was minted by this jar for ``addr`` and ``nonce`` within the lifetime."""
        if len(cookie) != COOKIE_SIZE:
            return False
        stamp = cookie[: _TIMESTAMP.size]
        (ticks,) = _TIMESTAMP.unpack(stamp)
        age = (int(now * TICKS_PER_SECOND) - ticks) % _TICK_MODULUS
        if age > self._lifetime_ticks:
            return False
        return hmac.compare_digest(cookie[_TIMESTAMP.size :], self._mac(stamp, addr, nonce))
