"""Bodies of CONTROL packets: the opening handshake, keep-alive, close and reject.

A CONTROL datagram is the 5-byte base header (TYPE = CONTROL) followed by a one-byte code and a
code-specific body. Control packets are rare (a handful per connection plus one keep-alive per idle
interval), so they carry what the data path leaves out: the protocol version, 128-bit nonces that tie
every control packet to one connection, the address-validation cookie and, in a keyed session, the key
identifier and the authentication tag.

Four kinds of control packet exist:

* **Handshake messages** (OPEN, COOKIE, OPEN_ACK, REJECT) have fixed layouts with every field in the
  clear, because the receiver needs them before it has session keys. In a keyed session OPEN and
  OPEN_ACK end in a 16-byte AEAD tag over everything before it (``KEYED`` flag).
* **Path validation** (PATH_CHALLENGE, PATH_RESPONSE) moves an unkeyed session to its master's new
  address after a NAT rebinding; always in the clear (a keyed session follows its master on any
  authenticated datagram instead).
* **RESET** (a restarted slave's "no session for you") is stateless and in the clear: an echo of the
  datagram that found no session and, keyed, tags under the slave's keys.
* **Multipath** (MP_CHALLENGE, MP_RESPONSE, MP_REPORT, MP_ABANDON; version 4, sessions opened with
  the ``MULTIPATH`` flag): the validation and probing of a session's further paths, each path's
  receiver report, and the end of a path. MP_CHALLENGE and MP_RESPONSE carry the master's nonce in
  the clear after the code byte (a server finds the session by it before it knows the address); the
  rest is sealed like session control in a keyed session (``header | code | nonce | PN | sealed |
  tag``). MP_REPORT and MP_ABANDON are plain session control.
* **Session control** (KEEPALIVE, CLOSE, and the reliable control channel's MESSAGE and MESSAGE_ACK)
  uses the session's packet protection when keyed, exactly like
  DATA and ACK: ``header | code | PN | sealed body | tag`` (``tdtp.protection``). Unkeyed, it is
  ``header | code | body``.

The code byte is always the sixth byte of a CONTROL datagram, in both modes, so a receiver can tell a
handshake message from session control before it decides how to read the rest.
"""

from __future__ import annotations

import enum
import struct
from typing import Final, NamedTuple

from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.protected import TAG_SIZE

PROTOCOL_VERSION: Final = 4
"""The only version this implementation speaks (version 1 had no cookie and no keyed mode; version 2
had no RESET, no path validation, and its KEEPALIVE carried no nonce; version 3 had no multipath,
no send timestamps (TIMESTAMP, TIMED_DATA), no dialing slave (``SLAVE_DIALS``) and no rendezvous
messages, and its MESSAGE and MESSAGE_ACK carried no nonce)."""

NONCE_SIZE: Final = 16
"""Bytes of a connection nonce (the master's and, in OPEN_ACK, the slave's): 128 random bits."""
COOKIE_SIZE: Final = 16
"""Bytes of an address-validation cookie (opaque to the master)."""
KEY_ID_SIZE: Final = 8
"""Bytes of a pre-shared key's public identifier (``tdtp.protection.keys``)."""
NO_COOKIE: Final = bytes(COOKIE_SIZE)
NO_KEY_ID: Final = bytes(KEY_ID_SIZE)


class ControlCode(enum.IntEnum):
    OPEN = 1
    """master -> slave: version, flags, cipher suite, max payload, nonce, key id, cookie."""
    OPEN_ACK = 2
    """slave -> master, once the OPEN carried a valid cookie: both nonces and the slave's max payload."""
    KEEPALIVE = 3
    """either way, only after ``keepalive_interval`` with nothing else sent."""
    CLOSE = 4
    """either way: the connection is over (reason code)."""
    REJECT = 5
    """slave -> master: the OPEN was refused (reason code). Never answers an OPEN without a valid
    cookie, except for an unsupported version."""
    COOKIE = 6
    """slave -> master: echo this cookie in the OPEN to prove you receive at your address. Sent
    statelessly, and never larger than the OPEN it answers."""
    RESET = 7
    """slave -> master: "I hold no session for you" (the slave restarted). Sent statelessly in answer
    to a session datagram from an unknown address, never larger than it: the datagram's first
    :data:`RESET_ECHO_SIZE` bytes echoed, then (keyed) one tag per key of the slave's ring that fits."""
    PATH_CHALLENGE = 8
    """slave -> master, unkeyed sessions: a session datagram arrived from an address the slave does
    not know while a session's master is silent; echo this token with your nonce (PATH_RESPONSE) to
    move the session there. Sent statelessly, never larger than the datagram it answers. (Code 7 is
    RESET's.)"""
    PATH_RESPONSE = 9
    """master -> slave: the PATH_CHALLENGE's token and the master's nonce, from the master's current
    address."""
    MESSAGE = 10
    """either way: one message of the reliable control channel (the master's nonce, its 16-bit
    number, the cumulative acknowledgement of the peer's messages, the message), retransmitted until
    acknowledged."""
    MESSAGE_ACK = 11
    """either way: the master's nonce and the cumulative acknowledgement of the peer's control
    messages alone, when no MESSAGE of ours leaves to carry it."""
    TIMESTAMP = 15
    """either way, sessions with the TIMESTAMPS flag: a stand-alone acknowledgement (the header's
    ACK fields, as an ACK's) with the sender's clock when it left, in microseconds."""
    TIMED_DATA = 16
    """either way, sessions with the TIMESTAMPS flag: a DATA packet (its header consumes a data
    sequence number and carries the acknowledgement as DATA's does) with the sender's clock when it
    left, in microseconds, before the payload."""
    MP_CHALLENGE = 17
    """either way, multipath sessions: on a path, "answer this token on the same path": validates a
    new path (its opener's first datagram on it; the other side's proof that the opener receives at
    that address) and probes an idle or failed one (its round trip)."""
    MP_RESPONSE = 18
    """either way, multipath sessions: the challenge's token echoed on the path it came on, with
    a token of the responder's own to validate the path the other way (zeros: none)."""
    MP_REPORT = 19
    """either way, multipath sessions: a receiver report for one path: what arrived on it (count,
    first copies, the newest sequence number and how long ago) and how far it lags the first copy."""
    MP_ABANDON = 20
    """either way, multipath sessions: this path is no longer used (reason code)."""
    REGISTER = 21
    """endpoint -> relay (version 4): wait under a rendezvous id (:mod:`tdtp.wire.rendezvous`)."""
    REFERRAL = 22
    """relay -> endpoint (version 4): a cookie, "waiting", the peer's addresses, or a refusal."""
    PROBE = 23
    """endpoint -> endpoint (version 4): does this candidate path work? A token and a MAC under
    the pair's probe key."""
    PROBE_ACK = 24
    """endpoint -> endpoint (version 4): the PROBE's token echoed on the path it came on."""


HANDSHAKE_CODES: Final = frozenset(
    int(code)
    for code in (ControlCode.OPEN, ControlCode.OPEN_ACK, ControlCode.REJECT, ControlCode.COOKIE)
)
"""Codes (as the byte on the wire) whose fields travel in the clear; KEEPALIVE and CLOSE are sealed
in a keyed session."""
PATH_CODES: Final = frozenset(
    int(code) for code in (ControlCode.PATH_CHALLENGE, ControlCode.PATH_RESPONSE)
)
"""Path validation (unkeyed sessions only; always in the clear)."""
MESSAGE_CODES: Final = frozenset(
    int(code) for code in (ControlCode.MESSAGE, ControlCode.MESSAGE_ACK)
)
"""The reliable control channel (docs/PROTOCOL.md section 5.10): session control, sealed when keyed."""
STAMP_CODES: Final = frozenset(
    int(code) for code in (ControlCode.TIMESTAMP, ControlCode.TIMED_DATA)
)
"""Packets that carry their sender's clock (docs/PROTOCOL.md section 5.13): session traffic, sealed
when keyed."""
MULTIPATH_CODES: Final = frozenset(
    int(code)
    for code in (
        ControlCode.MP_CHALLENGE,
        ControlCode.MP_RESPONSE,
        ControlCode.MP_REPORT,
        ControlCode.MP_ABANDON,
    )
)
"""Multipath (docs/PROTOCOL.md section 5.11): taken by the session's paths, sealed when keyed."""
PROBE_CODES: Final = frozenset(
    int(code) for code in (ControlCode.MP_CHALLENGE, ControlCode.MP_RESPONSE)
)
"""The two multipath codes that carry the master's nonce in the clear before their sealed body."""


class OpenFlags(enum.IntFlag):
    NONE = 0
    SEPARATE_ACKS = 0x01
    """The connection runs in separate-ACK (Trinomial) mode instead of bidirectional (TDTP) mode."""
    KEYED = 0x02
    """Pre-shared-key session: OPEN and OPEN_ACK end in a tag, every later packet is protected."""
    ENCRYPTED = 0x04
    """Keyed session whose payloads are encrypted (otherwise only authenticated). Needs KEYED."""
    TAKEOVER = 0x08
    """OPEN only, keyed only: an exclusive slave hands control to this master at once, ending the
    session of the master that had it (docs/PROTOCOL.md 5.9). Never echoed in the OPEN_ACK."""
    TIMESTAMPS = 0x20
    """Both ends time a share of their packets (TIMESTAMP, TIMED_DATA: docs/PROTOCOL.md 5.13), so
    that each learns the one-way delay of its own direction. Echoed in the OPEN_ACK."""
    MULTIPATH = 0x40
    """The session may run over several paths at once (docs/PROTOCOL.md 5.11): either side may
    validate further paths with MP_CHALLENGE, DATA may travel on several of them, and receivers
    take the first copy of each sequence number. Echoed in the OPEN_ACK."""
    SLAVE_DIALS = 0x80
    """Version 4: the sender of the OPEN is the slave (the robot) and the listener the master (the
    operator); without it the dialer is the master. Echoed in the OPEN_ACK; a listener whose own
    role is the dialer's answers REJECT ``ROLE_CONFLICT`` (docs/PROTOCOL.md 5.1)."""


KNOWN_FLAGS: Final = int(
    OpenFlags.SEPARATE_ACKS
    | OpenFlags.KEYED
    | OpenFlags.ENCRYPTED
    | OpenFlags.TAKEOVER
    | OpenFlags.TIMESTAMPS
    | OpenFlags.MULTIPATH
    | OpenFlags.SLAVE_DIALS
)


class CipherSuite(enum.IntEnum):
    """The AEAD a keyed session seals its datagrams with (the OPEN's ``suite`` byte)."""

    NONE = 0
    """Unkeyed session."""
    AES_128_GCM = 1
    """AES-128 in GCM mode, 128-bit tag: fastest where the CPU has AES instructions (the default)."""
    CHACHA20_POLY1305 = 2
    """ChaCha20-Poly1305 (RFC 8439), 128-bit tag: fast in software on any CPU."""


class CloseReason(enum.IntEnum):
    NORMAL = 0
    IDLE_TIMEOUT = 1
    PROTOCOL_ERROR = 2
    VERSION_UNSUPPORTED = 3
    REFUSED = 4
    BUSY = 5
    """The slave serves as many masters as it may (``max_peers``) or its accept backlog is full."""
    KEY_REQUIRED = 6
    """The slave accepts keyed sessions only and the OPEN had no key."""
    KEY_UNKNOWN = 7
    """The OPEN names a key the slave does not hold (or the slave holds no keys at all)."""
    PAYLOAD_TOO_SMALL = 8
    """The OPEN's max_payload is below the smallest payload the slave must be able to send."""
    SUITE_UNSUPPORTED = 9
    """The OPEN asks for a cipher suite the slave does not implement."""
    REPLACED = 10
    """The same master opened a new connection; this older one is over."""
    KEY_EXHAUSTED = 11
    """The session sent as many packets as its keys may protect; open a new connection."""
    IN_USE = 12
    """REJECT: the slave is exclusive and another master commands it (docs/PROTOCOL.md 5.9)."""
    TAKEN_OVER = 13
    """CLOSE: the slave is exclusive and another master took control (after this one was silent,
    or at once with the TAKEOVER flag)."""
    EVICTED = 14
    """CLOSE, slave -> master: the slave was full and gave this session's slot to another master,
    after this one had been silent for the slave's reclaim time (docs/PROTOCOL.md 5.1, rule 2.7).
    The master may reopen later; it should wait (back off) first."""
    RESTARTING = 15
    """CLOSE: the sender is stopping but expects to be back soon (a service restart: ``tdtp slave``
    stopped by Ctrl-C or SIGTERM). A master should reopen at once, at its usual OPEN pacing
    (docs/PROTOCOL.md 5.2). ``NORMAL`` says the opposite: the session is over for good."""
    PATH_CLOSED = 19
    """MP_ABANDON: the sender stopped using this path (the application removed it, its interface
    went away)."""
    PATH_LIMIT = 20
    """MP_ABANDON: the path was refused: the session has as many paths as the receiver allows, or
    new paths come faster than it takes them."""
    ROLE_CONFLICT = 21
    """REJECT (version 4): the dialer plays the listener's own role: a master dialed a master, or
    a slave dialed a slave (the OPEN's SLAVE_DIALS flag, docs/PROTOCOL.md 5.1)."""
    RENDEZVOUS_FULL = 22
    """REFERRAL (version 4): the relay holds as many rendezvous as it may, or this source registers
    too often; try again later or use another relay (docs/PROTOCOL.md 5.12)."""


class OpenBody(NamedTuple):
    """OPEN (master -> slave)."""

    version: int
    flags: int
    suite: int
    max_payload: int
    attempt: int
    """Counts the master's OPEN transmissions; the AEAD nonce of a keyed OPEN's tag."""
    nonce: bytes
    key_id: bytes
    cookie: bytes

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.OPEN


class OpenAckBody(NamedTuple):
    """OPEN_ACK (slave -> master)."""

    version: int
    flags: int
    suite: int
    max_payload: int
    packet_number: int
    """Keyed: the slave's first packet number under the session keys (the tag's AEAD nonce)."""
    nonce: bytes
    """The master's nonce, echoed."""
    slave_nonce: bytes

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.OPEN_ACK


class CookieBody(NamedTuple):
    """COOKIE (slave -> master)."""

    version: int
    nonce: bytes
    """The master's nonce, echoed."""
    cookie: bytes

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.COOKIE


class CloseBody(NamedTuple):
    """CLOSE (either way) and REJECT (slave -> master)."""

    code: ControlCode
    nonce: bytes
    """The master's nonce."""
    reason: int


class KeepaliveBody(NamedTuple):
    """KEEPALIVE (either way): the master's nonce, so that a blind attacker cannot forge one."""

    code: ControlCode
    nonce: bytes
    """The master's nonce."""


class ResetBody(NamedTuple):
    """RESET (slave -> master)."""

    echo: bytes
    """The first :data:`RESET_ECHO_SIZE` bytes of the datagram that found no session."""
    tags: tuple[bytes, ...]
    """Keyed: one tag per key the slave holds (as many as fit), empty when unkeyed."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.RESET


class PathChallengeBody(NamedTuple):
    """PATH_CHALLENGE (slave -> master)."""

    token: bytes

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.PATH_CHALLENGE


class PathResponseBody(NamedTuple):
    """PATH_RESPONSE (master -> slave)."""

    token: bytes
    """The challenge's token, echoed."""
    nonce: bytes
    """The master's nonce."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.PATH_RESPONSE


class MessageBody(NamedTuple):
    """MESSAGE (either way): one message of the reliable control channel."""

    nonce: bytes
    """The master's nonce, as a KEEPALIVE carries it: a blind attacker cannot forge a message."""
    seq: int
    """The low 16 bits of the message's number (the sender numbers its messages consecutively)."""
    ack: int
    """The low 16 bits of the next message number the sender expects from its peer: every one
    below it arrived (cumulative acknowledgement)."""
    data: bytes
    """The application's message, at least one byte."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.MESSAGE


class MessageAckBody(NamedTuple):
    """MESSAGE_ACK (either way): the cumulative acknowledgement of control messages alone."""

    nonce: bytes
    """The master's nonce."""
    ack: int
    """As :attr:`MessageBody.ack`."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.MESSAGE_ACK


class TimestampBody(NamedTuple):
    """TIMESTAMP (either way): the sender's clock when it left; the header carries an ACK's fields."""

    time: int
    """The sender's clock in microseconds, its low 32 bits (any origin: only differences count)."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.TIMESTAMP


class TimedDataBody(NamedTuple):
    """TIMED_DATA (either way): a sample with the sender's clock when it left."""

    time: int
    """As :attr:`TimestampBody.time`."""
    payload: bytes
    """The application's sample, at least one byte."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.TIMED_DATA


class MpChallengeBody(NamedTuple):
    """MP_CHALLENGE (either way, multipath sessions)."""

    nonce: bytes
    """The master's nonce (in the clear: names the session)."""
    path_id: int
    token: bytes
    """8 random bytes the answer must echo on the same path."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.MP_CHALLENGE


class MpResponseBody(NamedTuple):
    """MP_RESPONSE (either way, multipath sessions)."""

    nonce: bytes
    """The master's nonce (in the clear)."""
    path_id: int
    echo: bytes
    """The challenge's token."""
    token: bytes
    """The responder's own challenge for the same path (zeros: none)."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.MP_RESPONSE


class MpReportBody(NamedTuple):
    """MP_REPORT (either way, multipath sessions): what one path delivered to the sender of this
    report."""

    nonce: bytes
    """The master's nonce (a blind attacker does not know it)."""
    path_id: int
    """The path the report is about (and travels on)."""
    seq: int
    """The low 12 bits of the highest data sequence number received on the path (a u16 whose top
    four bits senders set to zero and receivers ignore)."""
    hold: int
    """HOLD code: how long ago that packet arrived (255: nothing has arrived on the path)."""
    received: int
    """DATA datagrams received on the path so far, copies included (mod 2^32)."""
    first: int
    """Of those, the first copies of their sequence number (mod 2^32)."""
    lag: int
    """How far the path recently lagged the first copy, in units of 100 us (65535: saturated)."""
    clock: int
    """The reporter's clock when the report was built: microseconds, low 32 bits, any origin (as a
    TIMESTAMP's): with ``hold`` it times the named packet's arrival on the reporter's clock, so
    its sender learns the path's delay in its own direction alone."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.MP_REPORT


class MpAbandonBody(NamedTuple):
    """MP_ABANDON (either way, multipath sessions)."""

    nonce: bytes
    """The master's nonce (a blind attacker cannot abandon a path, as it cannot CLOSE)."""
    path_id: int
    reason: int
    """A close reason (PATH_CLOSED, PATH_LIMIT)."""

    @property
    def code(self) -> ControlCode:
        """The control code this body is sent under."""
        return ControlCode.MP_ABANDON


ControlBody = (
    ResetBody
    | OpenBody
    | OpenAckBody
    | CookieBody
    | CloseBody
    | KeepaliveBody
    | PathChallengeBody
    | PathResponseBody
    | MessageBody
    | MessageAckBody
    | TimestampBody
    | TimedDataBody
    | MpChallengeBody
    | MpResponseBody
    | MpReportBody
    | MpAbandonBody
)

# Layouts, byte offsets from the code byte (the first byte after the base header).
_OPEN: Final = struct.Struct(
    ">BBBBHH16s8s16s"
)  # code version flags suite max_payload attempt nonce key_id cookie
_OPEN_ACK: Final = struct.Struct(
    ">BBBBHH16s16s"
)  # code version flags suite max_payload pn nonce slave_nonce
_COOKIE: Final = struct.Struct(">BB16s16s")  # code version nonce cookie
_CLOSE: Final = struct.Struct(">B16sB")  # code nonce reason
_KEEPALIVE: Final = struct.Struct(">B16s")  # code nonce
_PATH_CHALLENGE: Final = struct.Struct(">B16s")  # code token
_PATH_RESPONSE: Final = struct.Struct(">B16s16s")  # code token nonce
_MESSAGE: Final = struct.Struct(">B16sHH")  # code nonce seq ack, then the message
_MESSAGE_ACK: Final = struct.Struct(">B16sH")  # code nonce ack
_STAMP: Final = struct.Struct(">BI")  # code time (TIMESTAMP; TIMED_DATA's payload follows)
_MP_CHALLENGE: Final = struct.Struct(">B16sB8s")  # code nonce path_id token
_MP_RESPONSE: Final = struct.Struct(">B16sB8s8s")  # code nonce path_id echo token
_MP_REPORT: Final = struct.Struct(
    ">B16sBHBIIHI"
)  # code nonce path seq hold received first lag clock
_MP_ABANDON: Final = struct.Struct(">B16sBB")  # code nonce path_id reason

OPEN_BODY_SIZE: Final = _OPEN.size
"""48 bytes: with the header an unkeyed OPEN is 53 bytes, a keyed one 69."""
OPEN_ACK_BODY_SIZE: Final = _OPEN_ACK.size
"""40 bytes: with the header an unkeyed OPEN_ACK is 45 bytes, a keyed one 61."""
COOKIE_BODY_SIZE: Final = _COOKIE.size
"""34 bytes: a COOKIE datagram is 39 bytes, smaller than the smallest OPEN (53)."""
RESET_ECHO_SIZE: Final = 16
"""Bytes of the triggering datagram a RESET echoes: header, packet number (keyed) and the first
bytes after it, which an off-path attacker never sees."""
RESET_TAG_SIZE: Final = 16
"""Bytes of one keyed RESET tag: HMAC-SHA256 under a key's reset key, truncated."""
RESET_SIZE: Final = 5 + 1 + RESET_ECHO_SIZE
"""22 bytes: an unkeyed RESET (header, code, echo); a keyed one adds 16 per tag."""
CLOSE_BODY_SIZE: Final = _CLOSE.size
"""18 bytes: an unkeyed CLOSE or any REJECT is 23 bytes."""
KEEPALIVE_BODY_SIZE: Final = _KEEPALIVE.size
"""17 bytes: an unkeyed KEEPALIVE is 22 bytes, a keyed one 40."""
PATH_TOKEN_SIZE: Final = 16
"""Bytes of a PATH_CHALLENGE token (opaque to the master; the cookie's format)."""
PATH_CHALLENGE_BODY_SIZE: Final = _PATH_CHALLENGE.size
"""17 bytes: a PATH_CHALLENGE datagram is 22 bytes, no larger than the smallest session datagram
that can trigger one (an unkeyed KEEPALIVE)."""
PATH_RESPONSE_BODY_SIZE: Final = _PATH_RESPONSE.size
"""33 bytes: a PATH_RESPONSE datagram is 38 bytes."""
MESSAGE_PREFIX_SIZE: Final = _MESSAGE.size
"""21 bytes before a MESSAGE's data (code, nonce, seq, ack): an unkeyed MESSAGE is 26 bytes + the
message."""
MESSAGE_NONCE_OFFSET: Final = 1
"""Where a MESSAGE or MESSAGE_ACK body carries the master's nonce (after the code byte)."""
MESSAGE_NUMBERS_OFFSET: Final = MESSAGE_NONCE_OFFSET + NONCE_SIZE
"""Where a MESSAGE body carries its seq and ack (a MESSAGE_ACK its ack): 17."""
MESSAGE_ACK_BODY_SIZE: Final = _MESSAGE_ACK.size
"""19 bytes: an unkeyed MESSAGE_ACK is 24 bytes, a keyed one 42."""
STAMP_SIZE: Final = _STAMP.size
"""5 bytes: a TIMESTAMP body (code and time); TIMED_DATA puts them before the payload, so a timed
sample's datagram is 5 bytes longer than its DATA packet would be."""
STAMP_MODULUS: Final = 1 << 32
"""Send times travel as their low 32 bits, in microseconds (they wrap every 71.6 minutes)."""
MESSAGE_SEQ_MODULUS: Final = 1 << 16
"""Message numbers travel as their low 16 bits."""
MP_TOKEN_SIZE: Final = 8
"""Bytes of a multipath challenge token (random; a path is validated by its echo)."""
NO_MP_TOKEN: Final = bytes(MP_TOKEN_SIZE)
MP_PROBE_PREFIX_SIZE: Final = 1 + NONCE_SIZE
"""MP_CHALLENGE and MP_RESPONSE: the code byte and the master's nonce, in the clear before the
(keyed: sealed) rest; with the header, the 22-byte prefix a keyed session authenticates."""
MP_CHALLENGE_BODY_SIZE: Final = _MP_CHALLENGE.size
"""26 bytes: an unkeyed MP_CHALLENGE is 31 bytes, a keyed one 49."""
MP_RESPONSE_BODY_SIZE: Final = _MP_RESPONSE.size
"""34 bytes: an unkeyed MP_RESPONSE is 39 bytes, a keyed one 57."""
MP_REPORT_BODY_SIZE: Final = _MP_REPORT.size
"""35 bytes: an unkeyed MP_REPORT is 40 bytes, a keyed one 58."""
MP_ABANDON_BODY_SIZE: Final = _MP_ABANDON.size
"""19 bytes: an unkeyed MP_ABANDON is 24 bytes, a keyed one 42."""
MP_LAG_UNIT: Final = 0.0001
"""Seconds per unit of MP_REPORT's lag (100 us)."""
MP_LAG_MAX: Final = 0xFFFF
OPEN_NONCE_OFFSET: Final = struct.calcsize(">BBBBHH")
"""Where an OPEN body carries the master's nonce (after code, version, flags, suite, max_payload and
attempt): 8."""


def encode_open(body: OpenBody) -> bytes:
    """The OPEN body without the tag (a keyed sender appends it over header + body)."""
    return _OPEN.pack(
        ControlCode.OPEN,
        body.version,
        body.flags,
        body.suite,
        body.max_payload,
        body.attempt,
        body.nonce,
        body.key_id,
        body.cookie,
    )


def encode_open_ack(body: OpenAckBody) -> bytes:
    """The OPEN_ACK body without the tag (a keyed sender appends it over header + body)."""
    return _OPEN_ACK.pack(
        ControlCode.OPEN_ACK,
        body.version,
        body.flags,
        body.suite,
        body.max_payload,
        body.packet_number,
        body.nonce,
        body.slave_nonce,
    )


def encode_cookie(nonce: bytes, cookie: bytes) -> bytes:
    """A COOKIE body (code byte included): the version, the master's nonce echoed, the cookie."""
    return _COOKIE.pack(ControlCode.COOKIE, PROTOCOL_VERSION, nonce, cookie)


def encode_close(code: ControlCode, nonce: bytes, reason: int) -> bytes:
    """A CLOSE or REJECT body (code byte included)."""
    return _CLOSE.pack(code, nonce, reason)


def encode_reset(echo: bytes, tags: tuple[bytes, ...] = ()) -> bytes:
    """A RESET body (code byte included): the echo, then the tags (keyed)."""
    if len(echo) != RESET_ECHO_SIZE or any(len(tag) != RESET_TAG_SIZE for tag in tags):
        raise ValueError("a RESET echoes 16 bytes and carries 16-byte tags")
    return bytes((ControlCode.RESET,)) + echo + b"".join(tags)


def decode_reset(body: bytes | memoryview) -> ResetBody:
    """A RESET body (code byte included); raises :class:`MalformedPacketError` unless it is the
    code, a 16-byte echo and whole 16-byte tags."""
    size = len(body)
    if size < 1 + RESET_ECHO_SIZE or body[0] != ControlCode.RESET:
        raise MalformedPacketError("bad_control", f"RESET body of {size} bytes is too short")
    rest = size - 1 - RESET_ECHO_SIZE
    if rest % RESET_TAG_SIZE:
        raise MalformedPacketError("bad_control", f"RESET tags of {rest} bytes are not whole")
    start = 1 + RESET_ECHO_SIZE
    tags = tuple(bytes(body[i : i + RESET_TAG_SIZE]) for i in range(start, size, RESET_TAG_SIZE))
    return ResetBody(bytes(body[1:start]), tags)


def encode_keepalive(nonce: bytes) -> bytes:
    """A KEEPALIVE body (code byte included) carrying the master's nonce."""
    return _KEEPALIVE.pack(ControlCode.KEEPALIVE, nonce)


def encode_path_challenge(token: bytes) -> bytes:
    """A PATH_CHALLENGE body (code byte included): the token the new address must echo."""
    return _PATH_CHALLENGE.pack(ControlCode.PATH_CHALLENGE, token)


def encode_path_response(token: bytes, nonce: bytes) -> bytes:
    """A PATH_RESPONSE body (code byte included): the challenge's token and the session's nonce."""
    return _PATH_RESPONSE.pack(ControlCode.PATH_RESPONSE, token, nonce)


def encode_message(nonce: bytes, seq: int, ack: int, data: bytes) -> bytes:
    """A MESSAGE body (code byte included): the master's nonce, the low 16 bits of ``seq`` and
    ``ack``, then ``data``."""
    return _MESSAGE.pack(ControlCode.MESSAGE, nonce, seq & 0xFFFF, ack & 0xFFFF) + data


def encode_message_ack(nonce: bytes, ack: int) -> bytes:
    """A MESSAGE_ACK body (code byte included): the master's nonce and ``ack``'s low 16 bits."""
    return _MESSAGE_ACK.pack(ControlCode.MESSAGE_ACK, nonce, ack & 0xFFFF)


def encode_timestamp(code: ControlCode, time_us: int) -> bytes:
    """A TIMESTAMP body, or the part of a TIMED_DATA body before its payload: the code and the low
    32 bits of ``time_us``."""
    return _STAMP.pack(code, time_us & 0xFFFFFFFF)


def encode_mp_challenge(nonce: bytes, path_id: int, token: bytes) -> bytes:
    """An MP_CHALLENGE body (code byte included)."""
    return _MP_CHALLENGE.pack(ControlCode.MP_CHALLENGE, nonce, path_id, token)


def encode_mp_response(nonce: bytes, path_id: int, echo: bytes, token: bytes) -> bytes:
    """An MP_RESPONSE body (code byte included)."""
    return _MP_RESPONSE.pack(ControlCode.MP_RESPONSE, nonce, path_id, echo, token)


def encode_mp_report(body: MpReportBody) -> bytes:
    """An MP_REPORT body (code byte included); counters and the clock wrap at 2^32, the lag
    saturates."""
    return _MP_REPORT.pack(
        ControlCode.MP_REPORT,
        body.nonce,
        body.path_id,
        body.seq & 0xFFF,
        body.hold,
        body.received & 0xFFFFFFFF,
        body.first & 0xFFFFFFFF,
        min(body.lag, MP_LAG_MAX),
        body.clock & 0xFFFFFFFF,
    )


def encode_mp_abandon(nonce: bytes, path_id: int, reason: int) -> bytes:
    """An MP_ABANDON body (code byte included)."""
    return _MP_ABANDON.pack(ControlCode.MP_ABANDON, nonce, path_id, reason)


def _decode_multipath(code: ControlCode, body: bytes | memoryview) -> ControlBody:
    """The four multipath bodies (code byte included), unprotected."""
    size = len(body)
    if code is ControlCode.MP_CHALLENGE:
        if size != MP_CHALLENGE_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control", f"MP_CHALLENGE body is {size} bytes, not {MP_CHALLENGE_BODY_SIZE}"
            )
        _, nonce, path_id, token = _MP_CHALLENGE.unpack(body)
        return MpChallengeBody(nonce, path_id, token)
    if code is ControlCode.MP_RESPONSE:
        if size != MP_RESPONSE_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control", f"MP_RESPONSE body is {size} bytes, not {MP_RESPONSE_BODY_SIZE}"
            )
        _, nonce, path_id, echo, token = _MP_RESPONSE.unpack(body)
        return MpResponseBody(nonce, path_id, echo, token)
    if code is ControlCode.MP_REPORT:
        if size != MP_REPORT_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control", f"MP_REPORT body is {size} bytes, not {MP_REPORT_BODY_SIZE}"
            )
        _, nonce, path_id, seq, hold, received, first, lag, clock = _MP_REPORT.unpack(body)
        return MpReportBody(nonce, path_id, seq & 0xFFF, hold, received, first, lag, clock)
    if size != MP_ABANDON_BODY_SIZE:
        raise MalformedPacketError(
            "bad_control", f"MP_ABANDON body is {size} bytes, not {MP_ABANDON_BODY_SIZE}"
        )
    _, nonce, path_id, reason = _MP_ABANDON.unpack(body)
    return MpAbandonBody(nonce, path_id, reason)


def _tagged(body: bytes | memoryview, size: int, name: str) -> bytes | memoryview:
    """The fixed part of a handshake body whose KEYED flag (its third byte) says whether a tag
    follows."""
    if len(body) < 3:
        raise MalformedPacketError("bad_control", f"{name} body is too short for its flags")
    expected = size + (TAG_SIZE if body[2] & OpenFlags.KEYED else 0)
    if len(body) != expected:
        raise MalformedPacketError(
            "bad_control", f"{name} body is {len(body)} bytes, not {expected}"
        )
    return body[:size]


def decode_control(body: bytes | memoryview) -> ControlBody:
    """Decode the body after the base header; raises :class:`MalformedPacketError` on anything else.

    Handshake messages are checked in full (a keyed OPEN or OPEN_ACK must carry its tag, which is
    not verified here). For KEEPALIVE, CLOSE, MESSAGE and the multipath codes this reads the
    *unprotected* form: a keyed session
    removes the packet protection first.
    """
    if not body:
        raise MalformedPacketError("bad_control", "control packet without a control code")
    raw = body[0]
    try:
        code = ControlCode(raw)
    except ValueError:
        raise MalformedPacketError("bad_control", f"unknown control code {raw}") from None
    if code is ControlCode.OPEN:
        fixed = _tagged(body, OPEN_BODY_SIZE, "OPEN")
        _, version, flags, suite, max_payload, attempt, nonce, key_id, cookie = _OPEN.unpack(fixed)
        return OpenBody(version, flags, suite, max_payload, attempt, nonce, key_id, cookie)
    if code is ControlCode.OPEN_ACK:
        fixed = _tagged(body, OPEN_ACK_BODY_SIZE, "OPEN_ACK")
        _, version, flags, suite, max_payload, pn, nonce, slave_nonce = _OPEN_ACK.unpack(fixed)
        return OpenAckBody(version, flags, suite, max_payload, pn, nonce, slave_nonce)
    if code is ControlCode.COOKIE:
        if len(body) != COOKIE_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control", f"COOKIE body is {len(body)} bytes, not {COOKIE_BODY_SIZE}"
            )
        _, version, nonce, cookie = _COOKIE.unpack(body)
        return CookieBody(version, nonce, cookie)
    if code is ControlCode.RESET:
        return decode_reset(body)
    if code in (ControlCode.CLOSE, ControlCode.REJECT):
        if len(body) != CLOSE_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control", f"{code.name} body is {len(body)} bytes, not {CLOSE_BODY_SIZE}"
            )
        _, nonce, reason = _CLOSE.unpack(body)
        return CloseBody(code, nonce, reason)
    if code is ControlCode.MESSAGE:
        if len(body) <= MESSAGE_PREFIX_SIZE:
            raise MalformedPacketError(
                "bad_control", f"MESSAGE body of {len(body)} bytes carries no message"
            )
        _, nonce, seq, ack = _MESSAGE.unpack_from(body)
        return MessageBody(nonce, seq, ack, bytes(body[MESSAGE_PREFIX_SIZE:]))
    if code is ControlCode.MESSAGE_ACK:
        if len(body) != MESSAGE_ACK_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control",
                f"MESSAGE_ACK body is {len(body)} bytes, not {MESSAGE_ACK_BODY_SIZE}",
            )
        _, nonce, ack = _MESSAGE_ACK.unpack(body)
        return MessageAckBody(nonce, ack)
    if code is ControlCode.TIMESTAMP:
        if len(body) != STAMP_SIZE:
            raise MalformedPacketError(
                "bad_control", f"TIMESTAMP body is {len(body)} bytes, not {STAMP_SIZE}"
            )
        return TimestampBody(_STAMP.unpack(body)[1])
    if code is ControlCode.TIMED_DATA:
        if len(body) <= STAMP_SIZE:
            raise MalformedPacketError(
                "bad_control", f"TIMED_DATA body of {len(body)} bytes carries no payload"
            )
        return TimedDataBody(_STAMP.unpack_from(body)[1], bytes(body[STAMP_SIZE:]))
    if raw in MULTIPATH_CODES:
        return _decode_multipath(code, body)
    if code is ControlCode.PATH_CHALLENGE:
        if len(body) != PATH_CHALLENGE_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control",
                f"PATH_CHALLENGE body is {len(body)} bytes, not {PATH_CHALLENGE_BODY_SIZE}",
            )
        _, token = _PATH_CHALLENGE.unpack(body)
        return PathChallengeBody(token)
    if code >= ControlCode.REGISTER:
        # The rendezvous messages (tdtp.wire.rendezvous) belong to relays and path probing,
        # never to a session.
        raise MalformedPacketError("bad_control", f"{code.name} is not a session's message")
    if code is ControlCode.PATH_RESPONSE:
        if len(body) != PATH_RESPONSE_BODY_SIZE:
            raise MalformedPacketError(
                "bad_control",
                f"PATH_RESPONSE body is {len(body)} bytes, not {PATH_RESPONSE_BODY_SIZE}",
            )
        _, token, nonce = _PATH_RESPONSE.unpack(body)
        return PathResponseBody(token, nonce)
    if len(body) != KEEPALIVE_BODY_SIZE:
        raise MalformedPacketError(
            "bad_control", f"KEEPALIVE body is {len(body)} bytes, not {KEEPALIVE_BODY_SIZE}"
        )
    _, nonce = _KEEPALIVE.unpack(body)
    return KeepaliveBody(code, nonce)


def open_version(body: bytes | memoryview) -> int | None:
    """The version byte of an OPEN body of any version (``None`` if it has none), so that an OPEN
    this implementation cannot parse can still be answered with VERSION_UNSUPPORTED."""
    if len(body) >= 2 and body[0] == ControlCode.OPEN:
        return body[1]
    return None
