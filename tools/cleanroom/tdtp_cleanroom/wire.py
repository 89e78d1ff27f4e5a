"""The wire formats: base header (section 2), HOLD (3.4), serial arithmetic (3.1), CONTROL bodies (4.3)."""

from __future__ import annotations

from dataclasses import dataclass, field

PROTOCOL_VERSION = 4  # section 2.2: this document specifies version 4

# -- TYPE (section 2.1) ------------------------------------------------------------------------
DATA, ACK, CONTROL, RESERVED = 0, 1, 2, 3
HEADER_SIZE = 5

# -- CONTROL codes (section 4.3) ---------------------------------------------------------------
OPEN, OPEN_ACK, KEEPALIVE, CLOSE, REJECT, COOKIE, RESET = 1, 2, 3, 4, 5, 6, 7
PATH_CHALLENGE, PATH_RESPONSE, MESSAGE, MESSAGE_ACK = 8, 9, 10, 11
TIMESTAMP, TIMED_DATA = 15, 16  # send timestamps (section 5.13)
MP_CHALLENGE, MP_RESPONSE, MP_REPORT, MP_ABANDON = 17, 18, 19, 20  # multipath (section 5.11)
CODE_NAMES = {
    OPEN: "OPEN",
    OPEN_ACK: "OPEN_ACK",
    KEEPALIVE: "KEEPALIVE",
    CLOSE: "CLOSE",
    REJECT: "REJECT",
    COOKIE: "COOKIE",
    RESET: "RESET",
    PATH_CHALLENGE: "PATH_CHALLENGE",
    PATH_RESPONSE: "PATH_RESPONSE",
    MESSAGE: "MESSAGE",
    MESSAGE_ACK: "MESSAGE_ACK",
    TIMESTAMP: "TIMESTAMP",
    TIMED_DATA: "TIMED_DATA",
    MP_CHALLENGE: "MP_CHALLENGE",
    MP_RESPONSE: "MP_RESPONSE",
    MP_REPORT: "MP_REPORT",
    MP_ABANDON: "MP_ABANDON",
}
HANDSHAKE_CODES = (OPEN, OPEN_ACK, COOKIE, REJECT)  # row 5 of section 5.5
PATH_CODES = (PATH_CHALLENGE, PATH_RESPONSE)  # row 5b
MP_CODES = (MP_CHALLENGE, MP_RESPONSE, MP_REPORT, MP_ABANDON)  # row 6a
STAMP_CODES = (TIMESTAMP, TIMED_DATA)  # row 13, section 5.13

# -- OPEN flags (section 4.3) ------------------------------------------------------------------
FLAG_SEPARATE_ACKS, FLAG_KEYED, FLAG_ENCRYPTED, FLAG_TAKEOVER = 0x01, 0x02, 0x04, 0x08
FLAG_TIMESTAMPS, FLAG_MULTIPATH, FLAG_SLAVE_DIALS = 0x20, 0x40, 0x80
MODE_FLAGS = 0xE7  # bits 0..2 and 5..7: what an OPEN_ACK echoes

# -- CLOSE / REJECT reasons (section 4.3) ------------------------------------------------------
REASON_NAMES = [
    "NORMAL",
    "IDLE_TIMEOUT",
    "PROTOCOL_ERROR",
    "VERSION_UNSUPPORTED",
    "REFUSED",
    "BUSY",
    "KEY_REQUIRED",
    "KEY_UNKNOWN",
    "PAYLOAD_TOO_SMALL",
    "SUITE_UNSUPPORTED",
    "REPLACED",
    "KEY_EXHAUSTED",
    "IN_USE",
    "TAKEN_OVER",
    "EVICTED",
    "RESTARTING",
    "16",
    "17",
    "18",
    "PATH_CLOSED",
    "PATH_LIMIT",
    "ROLE_CONFLICT",
    "RENDEZVOUS_FULL",
]
(
    NORMAL,
    IDLE_TIMEOUT,
    PROTOCOL_ERROR,
    VERSION_UNSUPPORTED,
    REFUSED,
    BUSY,
    KEY_REQUIRED,
    KEY_UNKNOWN,
    PAYLOAD_TOO_SMALL,
    SUITE_UNSUPPORTED,
    REPLACED,
    KEY_EXHAUSTED,
    IN_USE,
    TAKEN_OVER,
    EVICTED,
    RESTARTING,
) = range(16)
PATH_CLOSED, PATH_LIMIT = 19, 20  # MP_ABANDON reasons (section 4.3)
ROLE_CONFLICT, RENDEZVOUS_FULL = 21, 22  # a REJECT's (5.1 rule 2.5), a REFERRAL's (5.12)


def reason_name(reason: int) -> str:
    return REASON_NAMES[reason] if reason < len(REASON_NAMES) else str(reason)


class TruncatedError(ValueError):
    """A datagram shorter than the 5-byte base header."""


class BadControlError(ValueError):
    """A CONTROL body of the wrong length or with an unknown code (`bad_control`, section 4.3)."""


# -- base header (section 2) -------------------------------------------------------------------
@dataclass(frozen=True)
class Header:
    type: int
    seq: int
    ack: int
    sack: int
    hold: int

    def encode(self) -> bytes:
        w = (self.type << 38) | (self.seq << 26) | (self.ack << 14) | (self.sack << 8) | self.hold
        return w.to_bytes(5, "big")

    @staticmethod
    def decode(data: bytes) -> Header:
        if len(data) < HEADER_SIZE:
            raise TruncatedError(len(data))
        w = int.from_bytes(data[:5], "big")
        return Header(
            (w >> 38) & 3, (w >> 26) & 0xFFF, (w >> 14) & 0xFFF, (w >> 8) & 0x3F, w & 0xFF
        )


def plain_header(type_: int = CONTROL, seq: int = 0) -> Header:
    """A header carrying no acknowledgement: ACK = SACK = 0, HOLD 255 (section 4.3)."""
    return Header(type_, seq & 0xFFF, 0, 0, HOLD_NO_ACK)


# -- HOLD (section 3.4) ------------------------------------------------------------------------
HOLD_UNIT_NS = 8000
HOLD_SATURATED, HOLD_NO_ACK = 254, 255
HOLD_SATURATION_NS = ((32 + 30) << 6) * HOLD_UNIT_NS  # 31.744 ms, where code 254 would decode


def hold_decode_ns(code: int) -> int | None:
    """The hold a code stands for, in ns; None for 254 (saturated) and 255 (no acknowledgement)."""
    if code >= HOLD_SATURATED:
        return None
    e, m = code >> 5, code & 31
    units = m if e == 0 else (32 + m) << (e - 1)
    return units * HOLD_UNIT_NS


def hold_encode_ns(hold_ns: int) -> int:
    """The largest code 0..253 not above the true hold; 254 from 31.744 ms; 0 for hold <= 0."""
    if hold_ns <= 0:
        return 0
    if hold_ns >= HOLD_SATURATION_NS:
        return HOLD_SATURATED
    units = hold_ns // HOLD_UNIT_NS
    if units < 32:
        return units
    e = units.bit_length() - 5
    return min(e * 32 + (units >> (e - 1)) - 32, 253)


def hold_encode_seconds(hold_s: float) -> int:
    return hold_encode_ns(int(hold_s * 1e9))


def clock_us(now: float) -> int:
    """A side's clock as TIMESTAMP, TIMED_DATA and MP_REPORT carry it (sections 4.3, 5.13): µs,
    its low 32 bits, from any origin; the clean room's origin is the runner's time 0 and it rounds
    to the nearest µs (FINDINGS.md, clock)."""
    return round(now * 1e6) & 0xFFFFFFFF


# -- serial arithmetic (section 3.1; 16-bit variant in 5.6 and 5.10) ---------------------------
def expand(value: int, expected: int, bits: int = 12) -> int:
    """The full number with these low bits nearest to `expected` (-half..half-1 around it)."""
    mod = 1 << bits
    d = (value - expected) & (mod - 1)
    if d >= mod // 2:
        d -= mod
    return expected + d


# -- CONTROL bodies (section 4.3); every body below starts with its code byte ------------------
@dataclass
class Open:
    version: int
    flags: int
    suite: int
    max_payload: int
    attempt: int
    nonce: bytes
    key_id: bytes
    cookie: bytes
    tag: bytes | None = None
    code: int = field(default=OPEN, init=False)


@dataclass
class OpenAck:
    version: int
    flags: int
    suite: int
    max_payload: int
    packet_number: int
    nonce: bytes
    slave_nonce: bytes
    tag: bytes | None = None
    code: int = field(default=OPEN_ACK, init=False)


@dataclass
class Keepalive:
    nonce: bytes
    code: int = field(default=KEEPALIVE, init=False)


@dataclass
class Close:
    nonce: bytes
    reason: int
    code: int = field(default=CLOSE, init=False)


@dataclass
class Reject:
    nonce: bytes
    reason: int
    code: int = field(default=REJECT, init=False)


@dataclass
class Cookie:
    version: int
    nonce: bytes
    cookie: bytes
    code: int = field(default=COOKIE, init=False)


@dataclass
class Reset:
    echo: bytes
    tags: list[bytes]
    code: int = field(default=RESET, init=False)


@dataclass
class PathChallenge:
    token: bytes
    code: int = field(default=PATH_CHALLENGE, init=False)


@dataclass
class PathResponse:
    token: bytes
    nonce: bytes
    code: int = field(default=PATH_RESPONSE, init=False)


@dataclass
class MpChallenge:
    nonce: bytes
    path_id: int
    token: bytes
    code: int = field(default=MP_CHALLENGE, init=False)


@dataclass
class MpResponse:
    nonce: bytes
    path_id: int
    echo: bytes
    token: bytes  # zeros: none
    code: int = field(default=MP_RESPONSE, init=False)


@dataclass
class MpReport:
    nonce: bytes
    path_id: int
    seq: int  # 12 bits
    hold: int  # a HOLD code; 255: nothing arrived on the path
    received: int
    first: int
    lag: int  # 100-us units, saturating at 65535
    clock: int  # the reporter's clock when it built the report, µs, low 32 bits
    code: int = field(default=MP_REPORT, init=False)


@dataclass
class MpAbandon:
    nonce: bytes
    path_id: int
    reason: int
    code: int = field(default=MP_ABANDON, init=False)


@dataclass
class Message:
    nonce: bytes
    seq: int
    ack: int
    data: bytes
    code: int = field(default=MESSAGE, init=False)


@dataclass
class MessageAck:
    nonce: bytes
    ack: int
    code: int = field(default=MESSAGE_ACK, init=False)


@dataclass
class Timestamp:
    """Stands for a stand-alone ACK; its header carries the ACK's fields (section 5.13)."""

    time: int  # the sender's clock, µs, low 32 bits
    code: int = field(default=TIMESTAMP, init=False)


@dataclass
class TimedData:
    """Stands for a DATA: its SEQ is a data sequence number (section 5.13)."""

    time: int
    payload: bytes  # the sample, at least one byte
    code: int = field(default=TIMED_DATA, init=False)


ControlBody = (
    Open
    | OpenAck
    | Keepalive
    | Close
    | Reject
    | Cookie
    | Reset
    | PathChallenge
    | PathResponse
    | Message
    | MessageAck
    | Timestamp
    | TimedData
    | MpChallenge
    | MpResponse
    | MpReport
    | MpAbandon
)

OPEN_SIZE, OPEN_ACK_SIZE, TAG_SIZE = 48, 40, 16  # body sizes including the code byte


def _u16(b: bytes, off: int) -> int:
    return int.from_bytes(b[off : off + 2], "big")


def decode_control(body: bytes) -> ControlBody:
    """Decode the bytes after the base header (code byte first); raise BadControlError if malformed."""
    if not body:
        raise BadControlError("no code byte")
    code, n = body[0], len(body)
    if code == OPEN:
        if n < 3:
            raise BadControlError("OPEN too short to hold its flags")
        keyed = bool(body[2] & FLAG_KEYED)
        if n != OPEN_SIZE + (TAG_SIZE if keyed else 0):
            raise BadControlError("OPEN length")
        return Open(
            body[1],
            body[2],
            body[3],
            _u16(body, 4),
            _u16(body, 6),
            body[8:24],
            body[24:32],
            body[32:48],
            body[48:64] if keyed else None,
        )
    if code == OPEN_ACK:
        if n < 3:
            raise BadControlError("OPEN_ACK too short to hold its flags")
        keyed = bool(body[2] & FLAG_KEYED)
        if n != OPEN_ACK_SIZE + (TAG_SIZE if keyed else 0):
            raise BadControlError("OPEN_ACK length")
        return OpenAck(
            body[1],
            body[2],
            body[3],
            _u16(body, 4),
            _u16(body, 6),
            body[8:24],
            body[24:40],
            body[40:56] if keyed else None,
        )
    if code == KEEPALIVE:
        if n != 17:
            raise BadControlError("KEEPALIVE length")
        return Keepalive(body[1:17])
    if code in (CLOSE, REJECT):
        if n != 18:
            raise BadControlError("CLOSE/REJECT length")
        return (Close if code == CLOSE else Reject)(body[1:17], body[17])
    if code == COOKIE:
        if n != 34:
            raise BadControlError("COOKIE length")
        return Cookie(body[1], body[2:18], body[18:34])
    if code == RESET:
        if n < 17 or (n - 17) % 16:
            raise BadControlError("RESET length")
        return Reset(body[1:17], [body[i : i + 16] for i in range(17, n, 16)])
    if code == PATH_CHALLENGE:
        if n != 17:
            raise BadControlError("PATH_CHALLENGE length")
        return PathChallenge(body[1:17])
    if code == PATH_RESPONSE:
        if n != 33:
            raise BadControlError("PATH_RESPONSE length")
        return PathResponse(body[1:17], body[17:33])
    if code == MESSAGE:
        if n < 22:  # nonce 16, seq 2, ack 2 and at least one message byte
            raise BadControlError("MESSAGE length")
        return Message(body[1:17], _u16(body, 17), _u16(body, 19), body[21:])
    if code == MESSAGE_ACK:
        if n != 19:
            raise BadControlError("MESSAGE_ACK length")
        return MessageAck(body[1:17], _u16(body, 17))
    if code == TIMESTAMP:
        if n != 5:
            raise BadControlError("TIMESTAMP length")
        return Timestamp(int.from_bytes(body[1:5], "big"))
    if code == TIMED_DATA:
        if n < 6:  # the time and at least one byte of sample
            raise BadControlError("TIMED_DATA without a sample")
        return TimedData(int.from_bytes(body[1:5], "big"), body[5:])
    if code == MP_CHALLENGE:
        if n != 26:
            raise BadControlError("MP_CHALLENGE length")
        return MpChallenge(body[1:17], body[17], body[18:26])
    if code == MP_RESPONSE:
        if n != 34:
            raise BadControlError("MP_RESPONSE length")
        return MpResponse(body[1:17], body[17], body[18:26], body[26:34])
    if code == MP_REPORT:
        if n != 35:
            raise BadControlError("MP_REPORT length")
        return MpReport(
            body[1:17],
            body[17],
            _u16(body, 18) & 0xFFF,  # the top four bits are zero; receivers ignore them
            body[20],
            int.from_bytes(body[21:25], "big"),
            int.from_bytes(body[25:29], "big"),
            _u16(body, 29),
            int.from_bytes(body[31:35], "big"),
        )
    if code == MP_ABANDON:
        if n != 19:
            raise BadControlError("MP_ABANDON length")
        return MpAbandon(body[1:17], body[17], body[18])
    raise BadControlError(f"unknown code {code}")


def encode_control(msg: ControlBody) -> bytes:
    """The body (code byte first) of a CONTROL packet; a keyed OPEN/OPEN_ACK's tag is appended later."""
    c = bytes([msg.code])
    if isinstance(msg, Open):
        return (
            c
            + bytes([msg.version, msg.flags, msg.suite])
            + msg.max_payload.to_bytes(2, "big")
            + msg.attempt.to_bytes(2, "big")
            + msg.nonce
            + msg.key_id
            + msg.cookie
            + (msg.tag or b"")
        )
    if isinstance(msg, OpenAck):
        return (
            c
            + bytes([msg.version, msg.flags, msg.suite])
            + msg.max_payload.to_bytes(2, "big")
            + msg.packet_number.to_bytes(2, "big")
            + msg.nonce
            + msg.slave_nonce
            + (msg.tag or b"")
        )
    if isinstance(msg, Keepalive):
        return c + msg.nonce
    if isinstance(msg, (Close, Reject)):
        return c + msg.nonce + bytes([msg.reason])
    if isinstance(msg, Cookie):
        return c + bytes([msg.version]) + msg.nonce + msg.cookie
    if isinstance(msg, Reset):
        return c + msg.echo + b"".join(msg.tags)
    if isinstance(msg, PathChallenge):
        return c + msg.token
    if isinstance(msg, PathResponse):
        return c + msg.token + msg.nonce
    if isinstance(msg, Message):
        return (
            c
            + msg.nonce
            + (msg.seq & 0xFFFF).to_bytes(2, "big")
            + (msg.ack & 0xFFFF).to_bytes(2, "big")
            + msg.data
        )
    if isinstance(msg, MessageAck):
        return c + msg.nonce + (msg.ack & 0xFFFF).to_bytes(2, "big")
    if isinstance(msg, Timestamp):
        return c + (msg.time & 0xFFFFFFFF).to_bytes(4, "big")
    if isinstance(msg, TimedData):
        return c + (msg.time & 0xFFFFFFFF).to_bytes(4, "big") + msg.payload
    if isinstance(msg, MpChallenge):
        return c + msg.nonce + bytes([msg.path_id]) + msg.token
    if isinstance(msg, MpResponse):
        return c + msg.nonce + bytes([msg.path_id]) + msg.echo + msg.token
    if isinstance(msg, MpReport):
        return (
            c
            + msg.nonce
            + bytes([msg.path_id])
            + (msg.seq & 0xFFF).to_bytes(2, "big")
            + bytes([msg.hold])
            + (msg.received & 0xFFFFFFFF).to_bytes(4, "big")
            + (msg.first & 0xFFFFFFFF).to_bytes(4, "big")
            + min(msg.lag, 0xFFFF).to_bytes(2, "big")
            + (msg.clock & 0xFFFFFFFF).to_bytes(4, "big")
        )
    if isinstance(msg, MpAbandon):
        return c + msg.nonce + bytes([msg.path_id, msg.reason])
    raise TypeError(msg)


def control_datagram(msg: ControlBody, header: Header) -> bytes:
    return header.encode() + encode_control(msg)
