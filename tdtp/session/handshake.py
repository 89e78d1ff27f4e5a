"""The opening of a session: what each side chose and learned, and the OPEN / OPEN_ACK messages.

A master opens with OPEN (its nonce, keyed or not, cipher suite, ACK mode, largest payload, and the
slave's cookie once it has one), resent every ``open_retry_interval`` until ``open_timeout``; a slave
admits it (:mod:`tdtp.admission`: address cookie, rate limits, keys), answers OPEN_ACK with its own nonce,
and waits for the master's first packet of the session to confirm it (docs/PROTOCOL.md section 5).
:class:`Handshake` holds that state for the connection's lifetime (the master's nonce stays the
connection's identifier on control packets), builds both messages, checks an OPEN_ACK against what we
asked for, and derives the session's packet protection from the pre-shared key and both nonces.

It also reads the opening messages that arrive: a master's COOKIE, OPEN_ACK and REJECT, a slave's
OPENs (through admission), counting each in the statistics and queueing the answers that need no
state change (a COOKIE or REJECT for an OPEN not admitted, an OPEN_ACK again). What a message changes
in the session (its state, the receive window, the events) it reports as a :class:`Reaction` for
:class:`~tdtp.session.connection.Connection` to carry out: this class never reaches back.
"""

from __future__ import annotations

import enum
import math
import random

from tdtp.admission.admission import Admission, AdmittedOpen, Reply
from tdtp.config import AckMode, ConnectionConfig, Role
from tdtp.errors import InvalidKeyError
from tdtp.protection.derivation import derive_open_secret, derive_session_secrets
from tdtp.protection.keys import KeysInput, OneKeyInput, PresharedKey, as_key, as_key_ring
from tdtp.protection.packet_protection import Direction, PacketOpener, PacketSealer
from tdtp.session.events import Address
from tdtp.session.liveness import Liveness
from tdtp.session.one_way import wants_timestamps
from tdtp.session.outbox import Outbox
from tdtp.session.stats import ConnectionStats, DropReason
from tdtp.wire.control import (
    NO_COOKIE,
    NO_KEY_ID,
    NONCE_SIZE,
    PROTOCOL_VERSION,
    CipherSuite,
    CloseBody,
    CloseReason,
    ControlCode,
    CookieBody,
    KeepaliveBody,
    MessageAckBody,
    MessageBody,
    MpReportBody,
    OpenAckBody,
    OpenBody,
    OpenFlags,
    PathChallengeBody,
    PathResponseBody,
    ResetBody,
    TimedDataBody,
    TimestampBody,
    decode_control,
    encode_open,
    encode_open_ack,
)
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE, PacketType, encode_header
from tdtp.wire.hold import HOLD_NO_ACK
from tdtp.wire.protected import TAG_SIZE

_CONTROL = int(PacketType.CONTROL)
_OPEN = int(ControlCode.OPEN)
_MAX_OPEN_ATTEMPT = 0xFFFF  # the OPEN tag's nonce counter must never repeat


class Reaction(enum.Enum):
    """What an opening message asks of the connection (it has been counted already)."""

    IGNORED = "ignored"
    """Dropped (counted by reason), or answered from here: nothing changes."""
    HEARD = "heard"
    """Taken in (a COOKIE, an OPEN_ACK again): a sign of life from the peer."""
    REJECTED = "rejected"
    """The slave refused us: a sign of life, then the end (:attr:`Handshake.detail` says why)."""
    OPENED = "opened"
    """A valid OPEN_ACK: a sign of life; the session opens (:attr:`Handshake.peer_max_payload`,
    :attr:`Handshake.keys`)."""
    ANSWER_AGAIN = "answer again"
    """A slave's master resent its OPEN (counted, not a sign of life): send the OPEN_ACK again."""
    REPLACED = "replaced"
    """A slave's master restarted from the same address: this session ends."""


class Handshake:
    """Nonces, the keyed / encrypted / cipher-suite choice, the cookie, and the OPEN retry times.

    A master presents one ``key`` (or none: unkeyed); a slave accepts ``keys`` through its
    ``admission`` (its own, or one shared by a server). Misuse raises :class:`InvalidKeyError`.
    """

    def __init__(
        self,
        config: ConnectionConfig,
        role: Role,
        rng: random.Random,
        *,
        dials: bool,
        key: OneKeyInput | None,
        keys: KeysInput | None,
        admission: Admission | None,
        stats: ConnectionStats,
        outbox: Outbox,
        liveness: Liveness,
    ) -> None:
        self._config = config
        self._stats = stats
        self._outbox = outbox
        self._liveness = liveness
        self.key: PresharedKey | None = None
        self.admission: Admission | None = None
        if dials:
            if keys is not None or admission is not None:
                raise InvalidKeyError(
                    "the side that dials presents one key: pass key=, not keys= or admission="
                )
            self.key = as_key(key) if key is not None else None
        else:
            if key is not None:
                raise InvalidKeyError(
                    "the side that listens accepts keys=: one key, several, or a KeyRing (key= is "
                    "the dialer's)"
                )
            if admission is not None and keys is not None:
                raise InvalidKeyError("pass keys= or a shared admission=, not both")
            self.admission = (
                admission
                if admission is not None
                else Admission(
                    config, as_key_ring(keys) if keys is not None else None, rng=rng, role=role
                )
            )
        # The protocol's "master" is the dialer (its nonce names the session, its direction is
        # master-to-slave in the key schedule); SLAVE_DIALS says when it is the application's slave.
        self._master = dials
        self._slave_dials = dials == (role is Role.SLAVE)
        self.master_nonce = rng.randbytes(NONCE_SIZE)
        """The connection's identifier on control packets: the master's; a slave adopts it."""
        self.slave_nonce = rng.randbytes(NONCE_SIZE)
        self.keyed = self.key is not None
        """Whether this session is keyed: the master's choice, adopted by the slave at the open."""
        self.encrypt = config.encrypt
        self.suite = config.cipher_suite if self.keyed else CipherSuite.NONE
        self.multipath = self._master and config.multipath is not None
        """Whether the session may run over several paths (the OPEN's MULTIPATH flag): the
        master's choice, adopted by the slave at the open (PROTOCOL.md 5.11)."""
        self.confirming = False
        """A slave that answered OPEN_ACK and waits for the master's first packet of the session."""
        self.open_attempt = 0
        self.open_deadline = 0.0
        self.open_next = 0.0
        """A master's next OPEN (re)transmission."""
        self._max_opens = max(
            1, math.floor(config.open_timeout / config.open_retry_interval + 1e-9)
        )
        """OPENs a master sends in all: one per retry interval of ``open_timeout`` (20). A COOKIE
        pulls an OPEN forward but never adds one to the budget."""
        self.keys: tuple[PacketSealer, PacketOpener] | None = None
        """A keyed session's packet protection, ours and the peer's, once derived at the open."""
        self.peer_max_payload = 0
        """The largest payload the slave sends, from its OPEN_ACK (a master's)."""
        self.detail = ""
        """Why the slave refused us (:attr:`Reaction.REJECTED`)."""
        self.reject_reason: int | None = None
        """The REJECT's reason code (:attr:`Reaction.REJECTED`)."""
        self.timestamps = self._master and wants_timestamps(config) and not self.multipath
        """The TIMESTAMPS flag (PROTOCOL.md 5.13): the dialer's choice (its controller reads one-way
        delays, ``timestamp_interval`` is not 0, and the session is single-path), the listener's
        from the OPEN. Stamps leave only in a session without MULTIPATH (:attr:`stamps`)."""
        self._open_tagger: Direction | None = None  # a keyed master's OPEN key
        self._cookie = NO_COOKIE
        self._cookie_answered_at = -math.inf

    @property
    def tag_size(self) -> int:
        """Bytes of the tag a keyed OPEN or OPEN_ACK ends in."""
        return TAG_SIZE if self.keyed else 0

    @property
    def stamps(self) -> bool:
        """Whether the session stamps send times: TIMESTAMPS, and not MULTIPATH (a path's own
        controller is fed by its MP_REPORTs; PROTOCOL.md 5.13)."""
        return self.timestamps and not self.multipath

    def open_flags(self, ack_mode: AckMode) -> int:
        flags = OpenFlags.SEPARATE_ACKS if ack_mode is AckMode.SEPARATE else OpenFlags.NONE
        if self.timestamps:
            flags |= OpenFlags.TIMESTAMPS
        if self._slave_dials:
            flags |= OpenFlags.SLAVE_DIALS
        if self.keyed:
            flags |= OpenFlags.KEYED
            if self.encrypt:
                flags |= OpenFlags.ENCRYPTED
        if self.multipath:
            flags |= OpenFlags.MULTIPATH
        return int(flags)

    # ------------------------------------------------------------------ master

    def start(self, now: float) -> None:
        """A master starts opening at ``now``: the first OPEN is due at once."""
        self.open_deadline = now + self._config.open_timeout
        self.open_next = now
        key = self.key
        if key is not None:
            self._open_tagger = Direction(
                self.suite, derive_open_secret(key.secret, self.master_nonce, self.suite)
            )

    def open_due(self, now: float) -> bool:
        """Whether an OPEN should leave at ``now``; if so, the next one is due a retry later. At most
        ``open_timeout / open_retry_interval`` (20) OPENs leave in all, COOKIEs or not (PROTOCOL.md
        5.1, rule 6 and 5.3); after the last one the master waits for the open timeout."""
        if now < self.open_next:
            return False
        if self.open_attempt >= self._max_opens:
            self.open_next = self.open_deadline
            return False
        self.open_next = now + self._config.open_retry_interval
        return True

    def next_open(self, seq: int, ack_mode: AckMode) -> bytes | None:
        """The next OPEN datagram (``seq`` in its header), or ``None`` once the attempts ran out."""
        attempt = self.open_attempt
        if attempt > _MAX_OPEN_ATTEMPT:
            return None
        self.open_attempt = attempt + 1
        key = self.key
        flags = self.open_flags(ack_mode)
        if self.keyed and self._config.takeover:
            flags |= OpenFlags.TAKEOVER
        datagram = encode_header(_CONTROL, seq, 0, 0, HOLD_NO_ACK) + encode_open(
            OpenBody(
                PROTOCOL_VERSION,
                flags,
                int(self.suite),
                self._config.max_payload,
                attempt,
                self.master_nonce,
                key.key_id if key is not None else NO_KEY_ID,
                self._cookie,
            )
        )
        tagger = self._open_tagger
        if tagger is not None:
            datagram += tagger.tag(attempt, datagram)
        return datagram

    def on_reply(
        self,
        data: bytes,
        now: float,
        *,
        opening: bool,
        established: bool,
        ack_mode: AckMode,
        opener: PacketOpener | None,
    ) -> Reaction:
        """A COOKIE, OPEN_ACK or REJECT for a master (``opener``: the session's, once keyed)."""
        stats = self._stats
        try:
            body = decode_control(data[HEADER_SIZE:])
        except MalformedPacketError:
            stats.count_drop(DropReason.BAD_CONTROL)
            return Reaction.IGNORED
        if isinstance(
            body,
            OpenBody
            | KeepaliveBody
            | ResetBody
            | PathChallengeBody
            | PathResponseBody
            | MessageBody
            | MessageAckBody
            | TimestampBody
            | TimedDataBody
            | MpReportBody,
        ):
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)  # an OPEN sent to a master
        elif body.nonce != self.master_nonce:
            stats.count_drop(DropReason.NONCE_MISMATCH)
        elif not opening:
            if isinstance(body, OpenAckBody) and established:
                # The slave answered a retransmitted OPEN again; our open is already done. In a
                # keyed session it must still authenticate (through the replay window) to count
                # as a sign of life.
                if opener is not None and not opener.verify_numbered(
                    body.packet_number, data[:-TAG_SIZE], data[-TAG_SIZE:]
                ):
                    stats.count_drop(DropReason(opener.failure))
                    return Reaction.IGNORED
                stats.count_handshake(len(data), self.tag_size)
                return Reaction.HEARD
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)
        elif isinstance(body, CookieBody):
            return self._on_cookie(body, len(data), now)
        elif isinstance(body, OpenAckBody):
            return self._on_open_ack(body, data, ack_mode)
        elif isinstance(body, CloseBody):  # REJECT
            stats.count_handshake(len(data), 0)
            self.detail = self.reject_text(body.reason)
            self.reject_reason = body.reason
            return Reaction.REJECTED
        else:  # pragma: no cover - decode_control returns one of the above for these codes
            stats.count_drop(DropReason.BAD_CONTROL)
        return Reaction.IGNORED

    def _on_cookie(self, body: CookieBody, size: int, now: float) -> Reaction:
        """The slave wants proof that we receive at our address: echo its cookie in the OPEN, at
        once, but at most once per retry interval (COOKIEs cannot make us flood)."""
        if body.version != PROTOCOL_VERSION:
            self._stats.count_drop(DropReason.UNKNOWN_VERSION)
            return Reaction.IGNORED
        self._stats.count_handshake(size, 0)
        self._cookie = body.cookie
        if now >= self._cookie_answered_at + self._config.open_retry_interval:
            self._cookie_answered_at = now
            self.open_next = now
        return Reaction.HEARD

    def _on_open_ack(self, body: OpenAckBody, data: bytes, ack_mode: AckMode) -> Reaction:
        stats = self._stats
        if body.version != PROTOCOL_VERSION:
            stats.count_drop(DropReason.UNKNOWN_VERSION)
            return Reaction.IGNORED
        if (
            body.max_payload == 0
            or body.flags != self.open_flags(ack_mode)
            or body.suite != self.suite
        ):
            stats.count_drop(DropReason.BAD_CONTROL)
            return Reaction.IGNORED
        self.slave_nonce = body.slave_nonce
        if self.keyed:
            keys = self.protection()
            opener = keys[1]
            if not opener.verify_numbered(body.packet_number, data[:-TAG_SIZE], data[-TAG_SIZE:]):
                stats.count_drop(DropReason(opener.failure))
                return Reaction.IGNORED  # not the slave we opened towards
            self.keys = keys
        stats.count_handshake(len(data), self.tag_size)
        self.peer_max_payload = body.max_payload
        return Reaction.OPENED

    def reject_text(self, reason: int) -> str:
        """Why the peer we dialed refused us, in words a user can act on (the roles named as they
        are: a slave that dials a listening master hears of "the master")."""
        try:
            known = CloseReason(reason)
        except ValueError:
            return f"refused (reason code {reason})"
        template = _REJECT_TEXT.get(known)
        if template is None:
            return known.name.lower()
        key = self.key
        return template.format(
            listener="master" if self._slave_dials else "slave",
            dialer="slave" if self._slave_dials else "master",
            key_id=key.key_id.hex() if key is not None else "-",
            max_payload=self._config.max_payload,
            suite=self._config.cipher_suite.name,
        )

    # ------------------------------------------------------------------ slave

    def on_open(
        self, data: bytes, addr: Address, now: float, *, listening: bool, srtt: float
    ) -> AdmittedOpen | Reaction:
        """A message for a slave: an OPEN goes through admission first (cookie, rate, key), then by
        state. Returns the admitted OPEN of a new master for a ``listening`` slave."""
        stats = self._stats
        if data[HEADER_SIZE] != _OPEN:
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)
            return Reaction.IGNORED
        admission = self.admission
        assert admission is not None  # every slave has one
        verdict = admission.admit(data, addr, now)
        if isinstance(verdict, DropReason):
            stats.count_drop(verdict)
            return Reaction.IGNORED
        if isinstance(verdict, Reply):
            stats.count_drop(verdict.reason)
            self._outbox.queue(verdict.datagram, addr, 0, False)
            return Reaction.IGNORED
        if listening:
            return verdict
        if verdict.body.nonce == self.master_nonce:
            # The master did not hear our OPEN_ACK: answer its retransmission again. Not a sign
            # of life: a master sends OPENs only until it is established, so once the session is
            # established this is a delayed duplicate or a replay (PROTOCOL.md 5.2).
            stats.count_handshake(verdict.size, self.tag_size)
            return Reaction.ANSWER_AGAIN
        stats.count_drop(DropReason.NONCE_MISMATCH)
        if self._liveness.silent_longer_than_live(now, srtt):
            # The same address opens anew and this session has been silent longer than a live
            # master ever is (it sends at least a KEEPALIVE per interval): the master restarted.
            # A live session is never replaced, so a replayed OPEN cannot end it.
            return Reaction.REPLACED
        return Reaction.IGNORED

    def session_control(self, data: bytes) -> CloseBody | KeepaliveBody | None:
        """A KEEPALIVE or CLOSE of our session (protection removed), or ``None`` with the drop
        counted: malformed, another code, or another session's nonce. The nonce is what an
        off-path attacker does not know: a forged KEEPALIVE must not pass for a sign of life and
        hide a dead master, nor a forged CLOSE end the session."""
        stats = self._stats
        try:
            body = decode_control(data[HEADER_SIZE:])
        except MalformedPacketError:
            stats.count_drop(DropReason.BAD_CONTROL)
            return None
        if not isinstance(body, CloseBody | KeepaliveBody):
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)
            return None
        if body.nonce != self.master_nonce:
            stats.count_drop(DropReason.NONCE_MISMATCH)
            return None
        return body

    def on_stranger(self, data: bytes, addr: Address, now: float) -> None:
        """A session datagram while we hold no session: a listening slave answers it with a RESET
        within admission's budget (PROTOCOL.md 5.7); a master before connect() drops it."""
        self._stats.count_drop(DropReason.NOT_ESTABLISHED)
        admission = self.admission
        if admission is not None:
            reset = admission.reset(data, now)
            if reset is not None:
                self._outbox.queue(reset, addr, 0, False)

    def adopt(self, admitted: AdmittedOpen) -> None:
        """A listening slave takes the master's choices from its admitted OPEN (and, keyed, derives
        the session's :attr:`keys`)."""
        body = admitted.body
        self.master_nonce = body.nonce
        self.timestamps = bool(body.flags & OpenFlags.TIMESTAMPS)
        self.multipath = bool(body.flags & OpenFlags.MULTIPATH)
        if admitted.key is not None:
            self.key = admitted.key
            self.keyed = True
            self.encrypt = bool(body.flags & OpenFlags.ENCRYPTED)
            self.suite = CipherSuite(body.suite)
            self.keys = self.protection()

    def open_ack(self, seq: int, ack_mode: AckMode, sealer: PacketSealer | None) -> bytes:
        """The OPEN_ACK answering the master's OPEN (tagged with the session's key if keyed)."""
        number = sealer.take_number() if sealer is not None else 0
        datagram = encode_header(_CONTROL, seq, 0, 0, HOLD_NO_ACK) + encode_open_ack(
            OpenAckBody(
                PROTOCOL_VERSION,
                self.open_flags(ack_mode),
                int(self.suite),
                self._config.max_payload,
                number & 0xFFFF,
                self.master_nonce,
                self.slave_nonce,
            )
        )
        if sealer is not None:
            datagram += sealer.tag(number, datagram)
        return datagram

    # ------------------------------------------------------------------ both

    def protection(self) -> tuple[PacketSealer, PacketOpener]:
        """The session's packet protection, ours to send and the peer's to open, derived from the
        pre-shared key and both nonces."""
        key = self.key
        assert key is not None
        suite = self.suite
        secrets = derive_session_secrets(key.secret, self.master_nonce, self.slave_nonce, suite)
        ours, theirs = (
            (secrets.master_to_slave, secrets.slave_to_master)
            if self._master
            else (secrets.slave_to_master, secrets.master_to_slave)
        )
        return (
            PacketSealer(suite, ours, encrypt=self.encrypt),
            PacketOpener(suite, theirs, encrypt=self.encrypt),
        )


_REJECT_TEXT = {
    CloseReason.BUSY: "the {listener} serves as many {dialer}s as it may (max_peers) or its accept "
    "backlog is full; try again later",
    CloseReason.KEY_REQUIRED: "the {listener} accepts keyed sessions only; connect with key= "
    "(--key-file) holding a key the {listener} knows",
    CloseReason.KEY_UNKNOWN: "the {listener} does not hold this key (key id {key_id}), or accepts "
    "unkeyed sessions only",
    CloseReason.VERSION_UNSUPPORTED: "the {listener} does not speak TDTP version "
    f"{PROTOCOL_VERSION}",
    CloseReason.PAYLOAD_TOO_SMALL: "the {listener} sends payloads larger than this {dialer}'s "
    "max_payload ({max_payload}); raise max_payload",
    CloseReason.SUITE_UNSUPPORTED: "the {listener} does not implement the cipher suite {suite}",
    CloseReason.ROLE_CONFLICT: "the peer plays the same role as this end (a master dialed a master, "
    "or a slave a slave); start one end as master and the other as slave",
    CloseReason.IN_USE: "the {listener} is exclusive and another {dialer} commands it; it hands "
    "over once that {dialer} has been silent for its takeover period, or at once to a keyed "
    "{dialer} that connects with takeover=True (--takeover)",
}
