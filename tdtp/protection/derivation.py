"""Key derivation (HKDF-SHA256, RFC 5869): key identifiers, OPEN keys and per-session keys.

* ``key_id = HKDF(ikm=psk, salt="", info="tdtp2 key id")[:8]``: public, names the key in an OPEN.
* OPEN key and IV: ``HKDF(ikm=psk, salt=master_nonce, info="tdtp2 open <suite>")``. Fresh for every
  connection attempt because the master's nonce is; it only authenticates the master's OPENs.
* Reset key: ``HKDF(ikm=psk, salt="", info="tdtp3 reset")`` (32 bytes): a slave that lost its sessions
  (it restarted) still holds it, so its RESET can prove it holds the master's key (HMAC-SHA256 over
  the echoed bytes, truncated to 16).
* Session keys: ``HKDF(ikm=psk, salt=master_nonce | slave_nonce, info="tdtp2 session <suite>")`` split
  into master-to-slave key and IV, then slave-to-master key and IV. Both nonces are fresh random
  128-bit values, so every session has its own keys: a session captured yesterday cannot be replayed
  into today's, and one direction's packets cannot be reflected back as the other's.

The secret is a random pre-shared key, not a password, so no stretching is needed (RFC 5869, section 4).
"""

from __future__ import annotations

import hashlib
import hmac
from typing import Final, NamedTuple

from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from tdtp.wire.control import KEY_ID_SIZE, CipherSuite

IV_SIZE: Final = 12
"""Bytes of an AEAD nonce; per packet it is the IV XOR the packet number (as TLS 1.3 and QUIC do)."""

KEY_SIZES: Final = {CipherSuite.AES_128_GCM: 16, CipherSuite.CHACHA20_POLY1305: 32}
"""Bytes of the AEAD key for each suite."""


class TrafficSecret(NamedTuple):
    """The key and IV that protect one direction of one session."""

    key: bytes
    iv: bytes


class SessionSecrets(NamedTuple):
    master_to_slave: TrafficSecret
    slave_to_master: TrafficSecret


def _hkdf(ikm: bytes, salt: bytes, info: bytes, length: int) -> bytes:
    return HKDF(algorithm=hashes.SHA256(), length=length, salt=salt or None, info=info).derive(ikm)


def derive_key_id(psk: bytes) -> bytes:
    return _hkdf(psk, b"", b"tdtp2 key id", KEY_ID_SIZE)


RESET_KEY_SIZE: Final = 32


def derive_reset_key(psk: bytes) -> bytes:
    return _hkdf(psk, b"", b"tdtp3 reset", RESET_KEY_SIZE)


def reset_tag(reset_key: bytes, echo: bytes) -> bytes:
    """The 16-byte tag a keyed RESET carries for the key whose reset key is ``reset_key``."""
    return hmac.new(reset_key, echo, hashlib.sha256).digest()[:16]


def derive_open_secret(psk: bytes, master_nonce: bytes, suite: CipherSuite) -> TrafficSecret:
    size = KEY_SIZES[suite]
    material = _hkdf(psk, master_nonce, b"tdtp2 open %d" % suite, size + IV_SIZE)
    return TrafficSecret(material[:size], material[size:])


def derive_session_secrets(
    psk: bytes, master_nonce: bytes, slave_nonce: bytes, suite: CipherSuite
) -> SessionSecrets:
    size = KEY_SIZES[suite]
    material = _hkdf(
        psk, master_nonce + slave_nonce, b"tdtp2 session %d" % suite, 2 * (size + IV_SIZE)
    )
    half = size + IV_SIZE
    return SessionSecrets(
        TrafficSecret(material[:size], material[size:half]),
        TrafficSecret(material[half : half + size], material[half + size :]),
    )


RENDEZVOUS_SECRET_SIZE: Final = 32


def derive_rendezvous_secret(psk: bytes) -> bytes:
    """The secret a keyed pair meets under at a relay (docs/PROTOCOL.md 5.12): the relay sees only an
    id derived from it, and the pair's path probes are MACed with another key derived from it."""
    return _hkdf(psk, b"", b"tdtp4 rendezvous", RENDEZVOUS_SECRET_SIZE)


def expand_rendezvous(secret: bytes, label: bytes, length: int) -> bytes:
    """``HKDF(secret, info = "tdtp4 " + label)``: the rendezvous id, the probe key."""
    return _hkdf(secret, b"", b"tdtp4 " + label, length)
