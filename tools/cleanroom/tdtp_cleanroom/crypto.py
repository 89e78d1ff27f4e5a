"""Keyed sessions (sections 4.4, 5.6, 5.7): key derivation, handshake tags, sealing, the replay
window with its resynchronisation search, RESET tags."""

from __future__ import annotations

import hashlib
import hmac
from dataclasses import dataclass

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.ciphers.aead import AESGCM, ChaCha20Poly1305
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from .bucket import TokenBucket
from .wire import expand

SUITE_KEY_SIZE = {1: 16, 2: 32}  # 1 AES-128-GCM, 2 ChaCha20-Poly1305 (section 4.3)
IV_SIZE = 12
TAG_SIZE = 16
AEAD = AESGCM | ChaCha20Poly1305


def hkdf(ikm: bytes, salt: bytes | None, info: str, length: int) -> bytes:
    return HKDF(
        algorithm=hashes.SHA256(), length=length, salt=salt, info=info.encode("ascii")
    ).derive(ikm)


def key_id(psk: bytes) -> bytes:
    return hkdf(psk, None, "tdtp2 key id", 8)


def reset_key(psk: bytes) -> bytes:
    return hkdf(psk, None, "tdtp3 reset", 32)


def reset_tag(rkey: bytes, echo: bytes) -> bytes:
    """HMAC-SHA256(reset_key, echo)[:16] (section 5.6)."""
    return hmac.new(rkey, echo, hashlib.sha256).digest()[:16]


def open_key_iv(psk: bytes, suite: int, master_nonce: bytes) -> tuple[bytes, bytes]:
    k = SUITE_KEY_SIZE[suite]
    out = hkdf(psk, master_nonce, f"tdtp2 open {suite}", k + IV_SIZE)
    return out[:k], out[k:]


@dataclass(frozen=True)
class SessionKeys:
    m2s_key: bytes
    m2s_iv: bytes
    s2m_key: bytes
    s2m_iv: bytes


def session_keys(psk: bytes, suite: int, master_nonce: bytes, slave_nonce: bytes) -> SessionKeys:
    k = SUITE_KEY_SIZE[suite]
    out = hkdf(psk, master_nonce + slave_nonce, f"tdtp2 session {suite}", 2 * (k + IV_SIZE))
    return SessionKeys(
        out[:k], out[k : k + IV_SIZE], out[k + IV_SIZE : 2 * k + IV_SIZE], out[2 * k + IV_SIZE :]
    )


def make_aead(suite: int, key: bytes) -> AEAD:
    return AESGCM(key) if suite == 1 else ChaCha20Poly1305(key)


def aead_nonce(iv: bytes, counter: int) -> bytes:
    """IV XOR the counter as a 96-bit big-endian number (section 5.6)."""
    c = counter.to_bytes(IV_SIZE, "big")
    return bytes(a ^ b for a, b in zip(iv, c, strict=True))


def handshake_tag(aead: AEAD, iv: bytes, counter: int, datagram_without_tag: bytes) -> bytes:
    """A keyed OPEN's or OPEN_ACK's tag: the AEAD over an empty plaintext, the datagram as AD."""
    return aead.encrypt(aead_nonce(iv, counter), b"", datagram_without_tag)


def handshake_tag_ok(
    aead: AEAD, iv: bytes, counter: int, datagram_without_tag: bytes, tag: bytes
) -> bool:
    try:
        aead.decrypt(aead_nonce(iv, counter), tag, datagram_without_tag)
        return True
    except InvalidTag:
        return False


def seal(
    aead: AEAD, iv: bytes, packet_number: int, prefix: bytes, body: bytes, encrypt: bool
) -> bytes:
    """prefix | PN | body sealed | tag (section 4.4)."""
    pn = (packet_number & 0xFFFF).to_bytes(2, "big")
    nonce = aead_nonce(iv, packet_number)
    if encrypt:
        return prefix + pn + aead.encrypt(nonce, body, prefix + pn)
    return prefix + pn + body + aead.encrypt(nonce, b"", prefix + pn + body)


def unseal(
    aead: AEAD, iv: bytes, packet_number: int, datagram: bytes, prefix_size: int, encrypt: bool
) -> bytes | None:
    """The body if the tag verifies under this full packet number, else None."""
    prefix_pn = datagram[: prefix_size + 2]
    rest = datagram[prefix_size + 2 :]
    nonce = aead_nonce(iv, packet_number)
    try:
        if encrypt:
            return aead.decrypt(nonce, rest, prefix_pn)
        body, tag = rest[:-TAG_SIZE], rest[-TAG_SIZE:]
        aead.decrypt(nonce, tag, prefix_pn + body)
        return body
    except InvalidTag:
        return None


REPLAY_WINDOW = 64
SEARCH_MAX = 4096


class Sealer:
    """One direction's sending side: every protected datagram consumes a packet number."""

    def __init__(self, suite: int, key: bytes, iv: bytes, encrypt: bool) -> None:
        self.aead = make_aead(suite, key)
        self.iv = iv
        self.encrypt = encrypt
        self.next_pn = 0

    def take_pn(self) -> int:
        pn = self.next_pn
        self.next_pn += 1
        return pn

    def seal(self, prefix: bytes, body: bytes) -> bytes:
        return seal(self.aead, self.iv, self.take_pn(), prefix, body, self.encrypt)


class Opener:
    """One direction's receiving side (section 5.6): replay window, tag check, resynchronisation."""

    def __init__(self, suite: int, key: bytes, iv: bytes, encrypt: bool, now: float = 0.0) -> None:
        self.aead = make_aead(suite, key)
        self.iv = iv
        self.encrypt = encrypt
        self.highest: int | None = None
        self.mask = 0  # bit i: highest - i accepted
        self.search_budget = TokenBucket(50, 50, now)  # at most 50 searches a second
        self.last_auth: float | None = None
        # the fastest rate seen over a whole second: datagrams authenticated per 1-s window
        self._win_start: float | None = None
        self._win_count = 0
        self.fastest_rate = 0.0
        self.failures = 0

    # -- the window --
    def seen(self, pn: int) -> bool:
        """Accepted already, or 64 or more below the highest (too old to tell)."""
        if self.highest is None:
            return pn < 0
        if pn > self.highest:
            return False
        d = self.highest - pn
        return d >= REPLAY_WINDOW or bool(self.mask >> d & 1)

    def accept(self, pn: int, now: float) -> None:
        if self.highest is None or pn > self.highest:
            shift = pn - self.highest if self.highest is not None else REPLAY_WINDOW
            self.mask = ((self.mask << shift) | 1) & ((1 << REPLAY_WINDOW) - 1)
            self.highest = pn
        else:
            self.mask |= 1 << (self.highest - pn)
        self.last_auth = now
        if self._win_start is None or now - self._win_start >= 1.0:
            if self._win_start is not None and now - self._win_start >= 1.0:
                self.fastest_rate = max(
                    self.fastest_rate, self._win_count / (now - self._win_start)
                )
            self._win_start, self._win_count = now, 0
        self._win_count += 1

    def nearest(self, pn16: int) -> int:
        return expand(pn16, (self.highest + 1) if self.highest is not None else 0, 16)

    def try_at(self, pn: int, datagram: bytes, prefix_size: int) -> bytes | None:
        if pn < 0:
            return None
        return unseal(self.aead, self.iv, pn, datagram, prefix_size, self.encrypt)

    def _search_count(self, now: float) -> int:
        # 3 + floor(S * R / 65536), S the time since the last authenticated datagram, R twice the
        # fastest rate seen, at least 2000/s; S = 0 when nothing was authenticated yet.
        s = 0.0 if self.last_auth is None else max(0.0, now - self.last_auth)
        r = max(2.0 * self.fastest_rate, 2000.0)
        return min(3 + int(s * r // 65536), SEARCH_MAX)

    def open(self, datagram: bytes, prefix_size: int, now: float) -> tuple[str, bytes | None, int]:
        """('accepted', body, pn), ('replayed', None, pn) or ('unauthenticated', None, pn)."""
        pn16 = int.from_bytes(datagram[prefix_size : prefix_size + 2], "big")
        pn = self.nearest(pn16)
        if self.seen(pn):
            verdict = "replayed"
        else:
            body = self.try_at(pn, datagram, prefix_size)
            if body is not None:
                self.accept(pn, now)
                return "accepted", body, pn
            verdict = "unauthenticated"
        # Resynchronisation (section 5.6): the same 16 low bits further ahead, above the highest.
        if self.search_budget.take(now):
            floor_ = max(pn, self.highest if self.highest is not None else -1)
            cand = pn + 65536
            while cand <= floor_:
                cand += 65536
            for _ in range(self._search_count(now)):
                body = self.try_at(cand, datagram, prefix_size)
                if body is not None:
                    self.accept(cand, now)
                    return "accepted", body, cand
                cand += 65536
        if verdict == "unauthenticated":
            self.failures += 1
        return verdict, None, pn

    def trial(self, datagram: bytes, prefix_size: int) -> str:
        """Path migration's trial (section 5.8): 'ahead' (authenticates above every accepted
        number), 'replayed' (authenticates at a number accepted already, or too old) or 'failed'.
        Never searches, never counts a forgery, changes nothing."""
        pn16 = int.from_bytes(datagram[prefix_size : prefix_size + 2], "big")
        pn = self.nearest(pn16)
        if self.try_at(pn, datagram, prefix_size) is None:
            return "failed"
        if self.highest is not None and pn <= self.highest:
            return "replayed"
        return "ahead"
