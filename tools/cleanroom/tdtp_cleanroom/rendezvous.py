"""The rendezvous (section 5.12): names, the four messages REGISTER, REFERRAL, PROBE and PROBE_ACK,
and a relay's rules. The endpoints' side (registering, probing, moving between paths) is not here:
no vector drives it (README.md, "What it does not cover")."""

from __future__ import annotations

import hashlib
import hmac
import ipaddress
from collections import OrderedDict
from dataclasses import dataclass, field

from . import wire
from .admission import Tokens
from .bucket import TokenBucket
from .config import Addr
from .crypto import hkdf

REGISTER, REFERRAL, PROBE, PROBE_ACK = 21, 22, 23, 24
RENDEZVOUS_CODES = (REGISTER, REFERRAL, PROBE, PROBE_ACK)
RENDEZVOUS_VERSION = 4
FLAG_LISTENER, FLAG_LEAVE = 0x01, 0x02
MAX_ADDRESSES = 4
COOKIE, WAITING, PEER, REFUSED, UNKNOWN, LEFT = range(6)
KIND_NAMES = ["COOKIE", "WAITING", "PEER", "REFUSED", "UNKNOWN", "LEFT"]
DIALER, LISTENER = 0, 1  # a PROBE's side byte


# -- names ---------------------------------------------------------------------------------------
def rendezvous_secret(psk: bytes | None, name: str | None) -> bytes:
    """S: from the PSK alone, or from a name (and the PSK's secret, empty when unkeyed)."""
    s_key = hkdf(psk, None, "tdtp4 rendezvous", 32) if psk is not None else b""
    if name is None:
        if psk is None:
            raise ValueError("an unkeyed pair needs a rendezvous name")
        return s_key
    return hashlib.sha256(b"tdtp4 rendezvous name|" + s_key + name.encode()).digest()


def rendezvous_id(secret: bytes) -> bytes:
    return hkdf(secret, None, "tdtp4 rendezvous id", 16)


def probe_key(secret: bytes) -> bytes:
    return hkdf(secret, None, "tdtp4 probe", 32)


def probe_mac(key: bytes, side: int, token: bytes, ack: bool) -> bytes:
    """HMAC-SHA256(probe key, "P" or "A" | side | token)[:16]."""
    label = b"A" if ack else b"P"
    return hmac.new(key, label + bytes([side]) + token, hashlib.sha256).digest()[:16]


# -- addresses: family u8 (4 or 6) | port u16 | 4 or 16 bytes ------------------------------------
def encode_addr(addr: Addr) -> bytes:
    ip = ipaddress.ip_address(addr[0])
    return bytes([ip.version]) + addr[1].to_bytes(2, "big") + ip.packed


def decode_addr(b: bytes, off: int) -> tuple[Addr, int]:
    """An address at `off`, and the offset after it; BadControlError if malformed."""
    if off + 3 > len(b) or b[off] not in (4, 6):
        raise wire.BadControlError("address")
    n = 4 if b[off] == 4 else 16
    end = off + 3 + n
    if end > len(b):
        raise wire.BadControlError("address")
    host = str(ipaddress.ip_address(b[off + 3 : end]))
    return (host, int.from_bytes(b[off + 1 : off + 3], "big")), end


# -- the messages (bodies from the code byte on) --------------------------------------------------
@dataclass
class Register:
    flags: int
    nonce: bytes
    rendezvous_id: bytes
    cookie: bytes
    candidates: list[Addr] = field(default_factory=list)  # the registrant's local addresses
    version: int = RENDEZVOUS_VERSION


@dataclass
class Referral:
    kind: int
    nonce: bytes
    reason: int = 0
    cookie: bytes = bytes(16)  # COOKIE
    lifetime: int = 0  # WAITING, PEER (seconds)
    reflexive: Addr | None = None  # WAITING, PEER: the registrant's address as the relay sees it
    peer: Addr | None = None  # PEER: the peer's reflexive address
    peer_listens: bool = False
    peer_candidates: list[Addr] = field(default_factory=list)
    version: int = RENDEZVOUS_VERSION


@dataclass
class Probe:
    token: bytes
    mac: bytes
    ack: bool = False  # PROBE_ACK


Message = Register | Referral | Probe


def _addresses(b: bytes, off: int) -> tuple[list[Addr], int]:
    if off >= len(b) or b[off] > MAX_ADDRESSES:
        raise wire.BadControlError("address count")
    out: list[Addr] = []
    off += 1
    for _ in range(b[off - 1]):
        a, off = decode_addr(b, off)
        out.append(a)
    return out, off


def decode(body: bytes) -> Message:
    """A rendezvous body (code byte first); BadControlError if malformed."""
    if not body or body[0] not in RENDEZVOUS_CODES:
        raise wire.BadControlError("not a rendezvous code")
    code, n = body[0], len(body)
    if code in (PROBE, PROBE_ACK):
        if n != 33:
            raise wire.BadControlError("PROBE length")
        return Probe(body[1:17], body[17:33], code == PROBE_ACK)
    if code == REGISTER:
        if n < 53:
            raise wire.BadControlError("REGISTER length")
        cands, end = _addresses(body, 52)
        if end != n:
            raise wire.BadControlError("REGISTER length")
        return Register(body[2], body[4:20], body[20:36], body[36:52], cands, body[1])
    if n < 20:
        raise wire.BadControlError("REFERRAL length")
    r = Referral(body[2], body[4:20], body[3], version=body[1])
    off = 20
    if r.kind == COOKIE:
        r.cookie, off = body[20:36], 36
    elif r.kind in (WAITING, PEER):
        if n < 22:
            raise wire.BadControlError("REFERRAL length")
        r.lifetime = int.from_bytes(body[20:22], "big")
        r.reflexive, off = decode_addr(body, 22)
        if r.kind == PEER:
            r.peer, off = decode_addr(body, off)
            if off >= n:
                raise wire.BadControlError("REFERRAL length")
            r.peer_listens = bool(body[off])
            r.peer_candidates, off = _addresses(body, off + 1)
    elif r.kind not in (REFUSED, UNKNOWN, LEFT):
        raise wire.BadControlError("REFERRAL kind")
    if off != n:
        raise wire.BadControlError("REFERRAL length")
    return r


def encode(msg: Message) -> bytes:
    if isinstance(msg, Probe):
        return bytes([PROBE_ACK if msg.ack else PROBE]) + msg.token + msg.mac
    if isinstance(msg, Register):
        return (
            bytes([REGISTER, msg.version, msg.flags, 0])
            + msg.nonce
            + msg.rendezvous_id
            + msg.cookie
            + bytes([len(msg.candidates)])
            + b"".join(encode_addr(a) for a in msg.candidates)
        )
    out = bytes([REFERRAL, msg.version, msg.kind, msg.reason]) + msg.nonce
    if msg.kind == COOKIE:
        out += msg.cookie
    elif msg.kind in (WAITING, PEER):
        assert msg.reflexive is not None
        out += msg.lifetime.to_bytes(2, "big") + encode_addr(msg.reflexive)
        if msg.kind == PEER:
            assert msg.peer is not None
            out += encode_addr(msg.peer) + bytes([msg.peer_listens, len(msg.peer_candidates)])
            out += b"".join(encode_addr(a) for a in msg.peer_candidates)
    return out


def datagram(msg: Message) -> bytes:
    """Always in the clear, behind TYPE 2, SEQ = ACK = SACK = 0, HOLD 255."""
    return wire.plain_header().encode() + encode(msg)


def probe_datagram(key: bytes, side: int, token: bytes, ack: bool) -> bytes:
    return datagram(Probe(token, probe_mac(key, side, token, ack), ack))


# -- a relay (relay rules 1 to 4) ----------------------------------------------------------------
COOKIE_LIFETIME = 5.0
REGISTRATION_LIFETIME = 30.0
MAX_REGISTRATIONS = 4096
UNKNOWN_MIN = 25  # the size of REFERRAL UNKNOWN: nothing smaller is answered
FORWARD_RATE = 20000.0


@dataclass
class Registration:
    rid: bytes
    side: int  # LISTENER or DIALER
    addr: Addr
    nonce: bytes
    candidates: list[Addr]
    expires: float
    forwarding: TokenBucket


@dataclass
class Sent:
    data: bytes
    addr: Addr
    label: str  # "REFERRAL <kind>" or "FORWARD"


class Relay:
    def __init__(self, now: float = 0.0) -> None:
        self.tokens = Tokens(COOKIE_LIFETIME)
        self.replies = TokenBucket(20000.0, 20000.0, now)  # answers to unvalidated sources
        self.sources: OrderedDict[Addr, TokenBucket] = OrderedDict()
        self.regs: dict[tuple[bytes, int], Registration] = {}

    def _source_token(self, addr: Addr, now: float) -> bool:
        b = self.sources.pop(addr, None) or TokenBucket(10.0, 20.0, now)
        self.sources[addr] = b
        while len(self.sources) > MAX_REGISTRATIONS:
            self.sources.popitem(last=False)
        return b.take(now)

    def _expire(self, now: float) -> None:
        for k in [k for k, r in self.regs.items() if r.expires <= now]:
            del self.regs[k]

    def _at(self, addr: Addr) -> Registration | None:
        return next((r for r in self.regs.values() if r.addr == addr), None)

    @staticmethod
    def _answer(msg: Referral, addr: Addr) -> Sent:
        return Sent(datagram(msg), addr, f"REFERRAL {KIND_NAMES[msg.kind]}")

    def receive(self, data: bytes, addr: Addr, now: float) -> list[Sent]:
        self._expire(now)
        code = data[5] if len(data) >= 6 and data[0] >> 6 == wire.CONTROL else None
        if code == REGISTER:
            return self._register(data, addr, now)
        reg = self._at(addr)
        if reg is not None:  # rule 4: forwarded whole to the other side, if there is one
            other = self.regs.get((reg.rid, 1 - reg.side))
            if other is None or not reg.forwarding.take(now):
                return []
            return [Sent(data, other.addr, "FORWARD")]
        if len(data) < UNKNOWN_MIN or code in RENDEZVOUS_CODES or not self.replies.take(now):
            return []
        return [self._answer(Referral(UNKNOWN, bytes(16)), addr)]

    def _register(self, data: bytes, addr: Addr, now: float) -> list[Sent]:
        try:
            msg = decode(data[5:])
        except wire.BadControlError:
            return []
        if not isinstance(msg, Register) or msg.version != RENDEZVOUS_VERSION:
            return []
        if not self._source_token(addr, now):
            return []
        if not self.tokens.cookie_ok(msg.cookie, now, addr, msg.nonce):  # rule 1
            if not self.replies.take(now):
                return []
            cookie = self.tokens.cookie(now, addr, msg.nonce)
            return [self._answer(Referral(COOKIE, msg.nonce, cookie=cookie), addr)]
        side = LISTENER if msg.flags & FLAG_LISTENER else DIALER
        key = (msg.rendezvous_id, side)
        if msg.flags & FLAG_LEAVE:  # rule 2: the registration of that address ends
            old = self.regs.get(key)
            if old is not None and old.addr == addr:
                del self.regs[key]
            return [self._answer(Referral(LEFT, msg.nonce), addr)]
        old = self.regs.get(key)
        if old is None and len(self.regs) >= MAX_REGISTRATIONS:
            refused = Referral(REFUSED, msg.nonce, reason=wire.RENDEZVOUS_FULL)
            return [self._answer(refused, addr)]
        forwarding = old.forwarding if old is not None and old.addr == addr else None
        reg = Registration(
            msg.rendezvous_id,
            side,
            addr,
            msg.nonce,
            list(msg.candidates),
            now + REGISTRATION_LIFETIME,
            forwarding or TokenBucket(FORWARD_RATE, FORWARD_RATE, now),
        )
        self.regs[key] = reg  # a new address replaces the old one (rule 2)
        other = self.regs.get((msg.rendezvous_id, 1 - side))
        life = int(REGISTRATION_LIFETIME)
        if other is None:  # rule 3
            return [self._answer(Referral(WAITING, msg.nonce, lifetime=life, reflexive=addr), addr)]
        return [
            self._answer(self._peer(reg, other, life), addr),
            self._answer(self._peer(other, reg, life), other.addr),  # the other side too
        ]

    @staticmethod
    def _peer(to: Registration, of: Registration, life: int) -> Referral:
        return Referral(
            PEER,
            to.nonce,
            lifetime=life,
            reflexive=to.addr,
            peer=of.addr,
            peer_listens=of.side == LISTENER,
            peer_candidates=list(of.candidates),
        )
