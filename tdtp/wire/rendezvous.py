"""The rendezvous messages (version 4, docs/PROTOCOL.md 5.12): how two endpoints behind NATs meet
through a relay and test direct paths to each other.

Four CONTROL codes, each behind the usual 5-byte base header (TYPE CONTROL, SEQ = ACK = SACK = 0,
HOLD 255), always in the clear:

* **REGISTER** (21, endpoint -> relay): "I wait under this rendezvous id": the registrant's nonce,
  the id, the relay's cookie (zeros until it has one), and its local addresses (candidates for a
  direct path on the same network). Flags say whether it listens (answers OPENs) and whether it
  leaves the rendezvous.
* **REFERRAL** (22, relay -> endpoint): the relay's answer, echoing the registrant's nonce: a
  cookie to echo, "registered, waiting" with the address the relay sees (server-reflexive), the
  peer's reflexive and local addresses once both sides are there, a refusal, or "unknown source"
  (a datagram to relay from an address that holds no registration: register again).
* **PROBE** (23) and **PROBE_ACK** (24), endpoint <-> endpoint on a candidate path: a fresh token and
  a MAC under the pair's probe key; the answer echoes the token with its own MAC. A validated
  round trip is a direct path (the part QUIC's PATH_CHALLENGE and PATH_RESPONSE play in
  draft-seemann-quic-nat-traversal; the codes of 5.8 stay the slave's path migration).

Only :mod:`struct` and :mod:`ipaddress`: the core never imports :mod:`socket`.
"""

from __future__ import annotations

import enum
import ipaddress
import struct
from typing import Final, NamedTuple

from tdtp.wire.control import ControlCode
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE, PacketType, encode_header
from tdtp.wire.hold import HOLD_NO_ACK

RENDEZVOUS_VERSION: Final = 4
"""The protocol version REGISTER and REFERRAL carry (the rendezvous messages are new in 4)."""

REGISTER: Final = int(ControlCode.REGISTER)
REFERRAL: Final = int(ControlCode.REFERRAL)
PROBE: Final = int(ControlCode.PROBE)
PROBE_ACK: Final = int(ControlCode.PROBE_ACK)
RENDEZVOUS_CODES: Final = frozenset((REGISTER, REFERRAL, PROBE, PROBE_ACK))
"""Code bytes of the rendezvous messages: a relay forwards every other datagram whole."""
PROBE_CODES: Final = frozenset((PROBE, PROBE_ACK))

ID_SIZE: Final = 16
"""Bytes of a rendezvous id (derived from the pair's key or name; the relay sees only this)."""
NONCE_SIZE: Final = 16
COOKIE_SIZE: Final = 16
TOKEN_SIZE: Final = 16
MAC_SIZE: Final = 16
MAX_CANDIDATES: Final = 4
"""Local addresses a REGISTER (and so a REFERRAL) carries at most."""

HEADER: Final = encode_header(int(PacketType.CONTROL), 0, 0, 0, HOLD_NO_ACK)
"""The base header of every rendezvous message."""


class RegisterFlags(enum.IntFlag):
    NONE = 0
    LISTENER = 0x01
    """The registrant listens (answers the OPEN); the other side of the rendezvous dials."""
    LEAVE = 0x02
    """The registrant ends its registration (needs a valid cookie, as any registration does)."""


class ReferralKind(enum.IntEnum):
    COOKIE = 0
    """Echo this cookie in the next REGISTER to prove you receive at your address."""
    WAITING = 1
    """Registered; the other side has not registered yet. Carries the registrant's reflexive
    address."""
    PEER = 2
    """Both sides are registered: the registrant's reflexive address, the peer's reflexive address
    and its local addresses, and whether the peer listens."""
    REFUSED = 3
    """Not registered: the reason (``RENDEZVOUS_FULL``)."""
    UNKNOWN = 4
    """A datagram to relay came from an address that holds no registration (the registrant's NAT
    mapping changed): register again. Nonce zeros: it answers a session datagram."""
    LEFT = 5
    """The registration is gone (answer to a REGISTER with LEAVE)."""


Candidate = tuple[str, int]
"""An address as asyncio gives it: (host, port)."""


class RegisterBody(NamedTuple):
    flags: int
    nonce: bytes
    rendezvous_id: bytes
    cookie: bytes
    candidates: tuple[Candidate, ...]


class ReferralBody(NamedTuple):
    kind: int
    reason: int
    nonce: bytes
    """The registrant's nonce, echoed (zeros in UNKNOWN)."""
    cookie: bytes
    """COOKIE: the cookie; zeros otherwise."""
    lifetime: int
    """WAITING and PEER: seconds the registration lives without a refresh."""
    reflexive: Candidate | None
    """WAITING and PEER: the registrant's address as the relay sees it."""
    peer: Candidate | None
    """PEER: the other side's reflexive address."""
    peer_listens: bool
    peer_candidates: tuple[Candidate, ...]
    """PEER: the other side's local addresses."""


class ProbeBody(NamedTuple):
    code: int
    """PROBE or PROBE_ACK."""
    token: bytes
    mac: bytes


_REGISTER: Final = struct.Struct(">BBBB16s16s16sB")  # code version flags 0 nonce id cookie count
_REFERRAL: Final = struct.Struct(">BBBB16s")  # code version kind reason nonce
_PROBE: Final = struct.Struct(">B16s16s")  # code token mac
_LIFETIME: Final = struct.Struct(">H")
REGISTER_MIN_SIZE: Final = HEADER_SIZE + _REGISTER.size
"""58 bytes: a REGISTER with no candidates, the smallest thing a relay answers with a cookie."""
COOKIE_REFERRAL_SIZE: Final = HEADER_SIZE + _REFERRAL.size + COOKIE_SIZE
"""41 bytes: the relay's answer to an unvalidated REGISTER, smaller than any REGISTER."""
UNKNOWN_REFERRAL_SIZE: Final = HEADER_SIZE + _REFERRAL.size
"""25 bytes: the relay answers a datagram from an unknown source only if it is at least this large."""
PROBE_SIZE: Final = HEADER_SIZE + _PROBE.size
"""38 bytes: a PROBE and its PROBE_ACK are the same size."""


def encode_address(addr: Candidate) -> bytes:
    """``family (4 or 6) | port u16 | 4 or 16 address bytes``; raises ValueError for a host name."""
    ip = ipaddress.ip_address(addr[0].split("%", 1)[0])
    return struct.pack(">BH", ip.version, addr[1]) + ip.packed


def _decode_address(body: bytes | memoryview, at: int) -> tuple[Candidate, int]:
    if len(body) < at + 3:
        raise MalformedPacketError("bad_control", "address cut short")
    family, port = struct.unpack_from(">BH", body, at)
    width = {4: 4, 6: 16}.get(family)
    if width is None:
        raise MalformedPacketError("bad_control", f"address family {family}")
    end = at + 3 + width
    if len(body) < end:
        raise MalformedPacketError("bad_control", "address cut short")
    raw = bytes(body[at + 3 : end])
    ip: ipaddress.IPv4Address | ipaddress.IPv6Address = (
        ipaddress.IPv4Address(raw) if width == 4 else ipaddress.IPv6Address(raw)
    )
    return (str(ip), port), end


def _decode_addresses(
    body: bytes | memoryview, at: int, count: int
) -> tuple[tuple[Candidate, ...], int]:
    if count > MAX_CANDIDATES:
        raise MalformedPacketError("bad_control", f"{count} candidates, more than {MAX_CANDIDATES}")
    found = []
    for _ in range(count):
        addr, at = _decode_address(body, at)
        found.append(addr)
    return tuple(found), at


def encode_register(body: RegisterBody) -> bytes:
    """A whole REGISTER datagram (header included)."""
    candidates = body.candidates[:MAX_CANDIDATES]
    return (
        HEADER
        + _REGISTER.pack(
            REGISTER,
            RENDEZVOUS_VERSION,
            body.flags,
            0,
            body.nonce,
            body.rendezvous_id,
            body.cookie,
            len(candidates),
        )
        + b"".join(encode_address(addr) for addr in candidates)
    )


def decode_register(data: bytes | memoryview) -> RegisterBody:
    """A REGISTER datagram (header included); :class:`MalformedPacketError` unless well formed
    and of version 4 (the caller checks the header's type and code byte)."""
    body = data[HEADER_SIZE:]
    if len(body) < _REGISTER.size:
        raise MalformedPacketError("bad_control", f"REGISTER of {len(data)} bytes is too short")
    code, version, flags, _, nonce, rid, cookie, count = _REGISTER.unpack_from(body)
    if code != REGISTER or version != RENDEZVOUS_VERSION:
        raise MalformedPacketError("bad_control", f"REGISTER version {version}")
    candidates, end = _decode_addresses(body, _REGISTER.size, count)
    if end != len(body):
        raise MalformedPacketError("bad_control", "REGISTER has trailing bytes")
    return RegisterBody(flags, nonce, rid, cookie, candidates)


def encode_referral(body: ReferralBody) -> bytes:
    """A whole REFERRAL datagram (header included); the fields its kind does not use are left out."""
    out = HEADER + _REFERRAL.pack(REFERRAL, RENDEZVOUS_VERSION, body.kind, body.reason, body.nonce)
    if body.kind == ReferralKind.COOKIE:
        return out + body.cookie
    if body.kind not in (ReferralKind.WAITING, ReferralKind.PEER):
        return out
    assert body.reflexive is not None
    out += _LIFETIME.pack(body.lifetime) + encode_address(body.reflexive)
    if body.kind == ReferralKind.WAITING:
        return out
    assert body.peer is not None
    candidates = body.peer_candidates[:MAX_CANDIDATES]
    return (
        out
        + encode_address(body.peer)
        + bytes((int(body.peer_listens), len(candidates)))
        + b"".join(encode_address(addr) for addr in candidates)
    )


def decode_referral(data: bytes | memoryview) -> ReferralBody:
    """A REFERRAL datagram (header included); :class:`MalformedPacketError` unless well formed."""
    body = data[HEADER_SIZE:]
    if len(body) < _REFERRAL.size:
        raise MalformedPacketError("bad_control", f"REFERRAL of {len(data)} bytes is too short")
    code, version, kind, reason, nonce = _REFERRAL.unpack_from(body)
    if code != REFERRAL or version != RENDEZVOUS_VERSION:
        raise MalformedPacketError("bad_control", f"REFERRAL version {version}")
    at = _REFERRAL.size
    cookie = bytes(COOKIE_SIZE)
    lifetime = 0
    reflexive: Candidate | None = None
    peer: Candidate | None = None
    listens = False
    candidates: tuple[Candidate, ...] = ()
    if kind == ReferralKind.COOKIE:
        cookie = bytes(body[at : at + COOKIE_SIZE])
        at += COOKIE_SIZE
        if len(cookie) != COOKIE_SIZE:
            raise MalformedPacketError("bad_control", "REFERRAL cookie cut short")
    elif kind in (ReferralKind.WAITING, ReferralKind.PEER):
        if len(body) < at + _LIFETIME.size:
            raise MalformedPacketError("bad_control", "REFERRAL cut short")
        (lifetime,) = _LIFETIME.unpack_from(body, at)
        reflexive, at = _decode_address(body, at + _LIFETIME.size)
        if kind == ReferralKind.PEER:
            peer, at = _decode_address(body, at)
            if len(body) < at + 2:
                raise MalformedPacketError("bad_control", "REFERRAL cut short")
            listens = bool(body[at])
            candidates, at = _decode_addresses(body, at + 2, body[at + 1])
    elif kind not in (ReferralKind.REFUSED, ReferralKind.UNKNOWN, ReferralKind.LEFT):
        raise MalformedPacketError("bad_control", f"REFERRAL kind {kind}")
    if at != len(body):
        raise MalformedPacketError("bad_control", "REFERRAL has trailing bytes")
    return ReferralBody(kind, reason, nonce, cookie, lifetime, reflexive, peer, listens, candidates)


def encode_probe(code: int, token: bytes, mac: bytes) -> bytes:
    """A whole PROBE or PROBE_ACK datagram (38 bytes)."""
    return HEADER + _PROBE.pack(code, token, mac)


def decode_probe(data: bytes | memoryview) -> ProbeBody:
    """A PROBE or PROBE_ACK datagram (header included)."""
    if len(data) != PROBE_SIZE:
        raise MalformedPacketError("bad_control", f"PROBE of {len(data)} bytes, not {PROBE_SIZE}")
    code, token, mac = _PROBE.unpack_from(data, HEADER_SIZE)
    if code not in PROBE_CODES:
        raise MalformedPacketError("bad_control", f"code {code} is not a probe")
    return ProbeBody(code, token, mac)


def rendezvous_code(data: bytes | memoryview) -> int:
    """The rendezvous code of ``data`` (21..24), or 0 if it is anything else (a session datagram)."""
    if len(data) > HEADER_SIZE and data[0] >> 6 == PacketType.CONTROL:
        code = data[HEADER_SIZE]
        if code in RENDEZVOUS_CODES:
            return code
    return 0
