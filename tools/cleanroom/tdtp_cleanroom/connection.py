"""One session, master or slave side (sections 5.1 to 5.11): the table of section 5.5, the
handshake, keep-alives, silences, closing, RESET, PATH_CHALLENGE, the control channel, the
multipath rows (the path table itself is multipath.py)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace

from . import crypto, wire
from .admission import Admission, Verdict
from .bucket import TokenBucket
from .config import Addr, Config
from .control_channel import ControlChannel
from .multipath import NO_TOKEN, Multipath, Path
from .receiver import OwedAck, ReceiveWindow
from .sender import SentLog

IDLE, LISTENING, OPENING, ESTABLISHED, CLOSED = (
    "idle",
    "listening",
    "opening",
    "established",
    "closed",
)
RESET_ECHOES = 256
INF = float("inf")


@dataclass
class Sent:
    data: bytes
    addr: Addr | None  # None: the session's peer at the moment it leaves (it may move, 5.8)
    label: str  # "DATA", "ACK" or the control code, with a REJECT's or unkeyed CLOSE's reason


@dataclass
class Sink:
    """Where connections report what they send and what their application hears."""

    sent: list[Sent] = field(default_factory=list)
    drops: list[tuple[object, str]] = field(default_factory=list)
    delivered: list[tuple[object, bytes]] = field(default_factory=list)
    control_delivered: list[tuple[object, bytes]] = field(default_factory=list)
    closed: list[tuple[object, str, int | None]] = field(default_factory=list)

    def clear(self) -> None:
        self.sent.clear()
        self.drops.clear()
        self.delivered.clear()
        self.control_delivered.clear()
        self.closed.clear()


CLOSE_CAUSE = {wire.RESTARTING: "peer_restarting", wire.EVICTED: "evicted"}  # else peer_close


class Connection:
    def __init__(
        self,
        role: str,
        cfg: Config,
        sink: Sink,
        nonce: bytes,
        initial_seq: int,
        now: float,
        peer: Addr | None = None,
        admission: Admission | None = None,
    ) -> None:
        self.role = role
        self.cfg = cfg
        self.sink = sink
        self.isn = initial_seq
        self.peer = peer
        self.admission = admission
        self.state = IDLE
        self.own_nonce = nonce  # a master's connection nonce, or a slave's nonce for OPEN_ACK
        self.nonce = nonce if role == "master" else b""  # the session nonce: always the master's
        self.keyed = False
        self.flags = 0
        self.suite = 0
        self.psk: bytes | None = None
        self.sealer: crypto.Sealer | None = None
        self.opener: crypto.Opener | None = None
        self.log = SentLog(initial_seq, cfg.initial_rtt, cfg.ack_delay, cfg.reorder_threshold)
        self.window: ReceiveWindow | None = None
        self.channel: ControlChannel | None = None
        self.peer_max_payload = cfg.max_payload
        self.last_life = now  # the last sign of life from the peer (section 5.2)
        self.last_traffic: float | None = None  # the last session traffic we sent
        self.queue: list[Sent] = []  # control datagrams queued for this instant's flush
        self.owed_acks: list[OwedAck] = []  # jump-rule, late-rule and full-rule ACKs
        # master
        self.attempts = 0
        self.last_open_at = -INF
        self.last_cookie_open_at = -INF
        self.cookie = bytes(16)
        self.opened_at = now
        self.echoes: deque[bytes] = deque(maxlen=RESET_ECHOES)
        self.last_path_response = -INF
        # slave
        self.replacing: bytes | None = None  # the OPEN that replaced this session (rule 5)
        # path migration (section 5.8; a server's sessions only)
        self.validated = True
        self.bytes_in = 0
        self.bytes_out = 0
        self.moved_from: Addr | None = None
        self.moved_at = 0.0
        self.moved_by_response = False
        self.path_first_seq = 0
        self.challenges = TokenBucket(cfg.challenges_per_second, cfg.challenge_burst, now)
        # multipath (section 5.11): the session's paths, when it was opened with MULTIPATH
        self.mp: Multipath | None = None
        self.rx_path: Path | None = None  # the path the datagram being read came on
        self.mp_queue: list[Sent] = []  # MP_RESPONSEs and refusals, for the next flush
        self.mp_traffic = False  # a multipath packet of ours since the last KEEPALIVE check
        # send timestamps (section 5.13): the interval when the session stamps, the last stamp
        self.stamp_interval: float | None = None
        self.last_stamp = -INF

    # -- helpers --------------------------------------------------------------------------------
    def drop(self, reason: str) -> None:
        self.sink.drops.append((self, reason))

    def life(self, now: float) -> None:
        self.last_life = now

    def silence(self, now: float) -> float:
        return now - self.last_life

    def live_silence(self) -> float:
        """Longer than a live master is ever silent: keepalive_interval + 2 srtt (rule 5)."""
        return self.cfg.keepalive + 2 * self.log.srtt

    def _close(self, cause: str, reason: int | None) -> None:
        if self.state != CLOSED:
            self.state = CLOSED
            self.sink.closed.append((self, cause, reason))

    def _queue(self, data: bytes, label: str, traffic: bool, now: float) -> None:
        self.queue.append(Sent(data, None, label))
        if traffic:
            self.last_traffic = now

    def _emit(self, s: Sent, now: float) -> None:
        if s.addr is None and self.mp is not None and s.label.startswith("CLOSE"):
            for p in self.mp.usable()[1:]:  # CLOSE goes on every usable path (section 5.11)
                self._emit(Sent(s.data, p.addr, s.label), now)
            usable = self.mp.usable()
            s.addr = usable[0].addr if usable else self.peer
        if s.addr is None:
            best = self.mp.best(now) if self.mp is not None else None
            s.addr = best.addr if best is not None else self.peer
        if self.mp is not None and s.addr is not None:
            path = self.mp.path_at(s.addr)
            if path is not None:
                if not self.mp.may_send(path, len(s.data)):
                    return  # the 3x limit of a path not validated yet (section 5.11)
                self.mp.sent(path, len(s.data), now)
        if not self.validated:
            self.bytes_out += len(s.data)
        self.sink.sent.append(s)

    @property
    def separate_acks(self) -> bool:
        """The session's ack mode: the master's choice, adopted by the slave from its OPEN."""
        return bool(self.flags & wire.FLAG_SEPARATE_ACKS)

    @property
    def max_send_payload(self) -> int:
        return min(self.cfg.max_payload, self.peer_max_payload)

    def _header_ack(self, now: float) -> wire.Header:
        """A DATA/KEEPALIVE header's acknowledgement (section 5.3): H, its SACK, its hold."""
        seq = self.log.next_seq & 0xFFF
        owed = self.window.piggyback() if (self.window and not self.separate_acks) else None
        if owed is None:
            return wire.Header(wire.CONTROL, seq, 0, 0, wire.HOLD_NO_ACK)
        return wire.Header(
            wire.CONTROL,
            seq,
            owed.ack & 0xFFF,
            owed.sack,
            wire.hold_encode_seconds(now - owed.since),
        )

    def _session_control(self, msg: wire.ControlBody, header: wire.Header) -> bytes:
        """A session CONTROL datagram, sealed in a keyed session (section 4.4)."""
        body = wire.encode_control(msg)
        if self.sealer is None:
            return header.encode() + body
        return self.sealer.seal(header.encode() + body[:1], body[1:])

    def _plain_header(self) -> wire.Header:
        return wire.plain_header(wire.CONTROL, self.log.next_seq)

    # -- building what we send ------------------------------------------------------------------
    def _send_open(self, now: float) -> None:
        assert self.peer is not None
        key_id = crypto.key_id(self.psk) if self.psk else bytes(8)
        op = wire.Open(
            wire.PROTOCOL_VERSION,
            self.flags,
            self.suite,
            self.cfg.max_payload,
            self.attempts,
            self.nonce,
            key_id,
            self.cookie,
        )
        dg = wire.control_datagram(op, wire.plain_header(wire.CONTROL, self.isn))
        if self.psk:
            key, iv = crypto.open_key_iv(self.psk, self.suite, self.nonce)
            dg += crypto.handshake_tag(crypto.make_aead(self.suite, key), iv, self.attempts, dg)
        self.attempts += 1
        self.last_open_at = now
        self._queue(dg, "OPEN", False, now)

    def _send_open_ack(self, now: float) -> None:
        pn = self.sealer.take_pn() if self.sealer else 0
        oa = wire.OpenAck(
            wire.PROTOCOL_VERSION,
            self.flags & wire.MODE_FLAGS,
            self.suite,
            self.cfg.max_payload,
            pn & 0xFFFF,
            self.nonce,
            self.own_nonce,
        )
        dg = wire.control_datagram(oa, wire.plain_header(wire.CONTROL, self.isn))
        if self.sealer:
            dg += crypto.handshake_tag(self.sealer.aead, self.sealer.iv, pn, dg)
        self._queue(dg, "OPEN_ACK", True, now)

    def close_datagram(self, reason: int) -> tuple[bytes, str]:
        dg = self._session_control(wire.Close(self.nonce, reason), self._plain_header())
        return dg, ("CLOSE" if self.keyed else f"CLOSE {wire.reason_name(reason)}")

    def _send_close(self, reason: int, now: float) -> bytes:
        dg, label = self.close_datagram(reason)
        self._queue(dg, label, True, now)
        return dg

    # -- the application's side -----------------------------------------------------------------
    def connect(self, peer: Addr, now: float) -> None:
        """A master starts opening (rule 1)."""
        self.peer = peer
        self.psk = self.cfg.psk
        self.keyed = self.psk is not None
        self.suite = self.cfg.suite if self.keyed else 0
        self.flags = wire.FLAG_SEPARATE_ACKS if self.cfg.separate_acks else 0
        if self.keyed:
            self.flags |= wire.FLAG_KEYED | (wire.FLAG_ENCRYPTED if self.cfg.encrypt else 0)
            self.flags |= wire.FLAG_TAKEOVER if self.cfg.takeover else 0
        if self.cfg.multipath:
            self.flags |= wire.FLAG_MULTIPATH
        elif self.cfg.timestamp_interval > 0:  # never together with MULTIPATH (5.13)
            self.flags |= wire.FLAG_TIMESTAMPS
        self.state = OPENING
        self.opened_at = now
        self.last_life = now
        self._send_open(now)

    def close(self, now: float, restarting: bool = False) -> None:
        if self.state in (OPENING, ESTABLISHED):
            reason = wire.RESTARTING if restarting else wire.NORMAL
            self._send_close(reason, now)
            self._close("local_close", reason)

    def end(self, now: float, reason: int, cause: str) -> bytes:
        """A server ends this session (EVICTED, TAKEN_OVER): the CLOSE, for its repeats."""
        dg = self._send_close(reason, now)
        self._close(cause, reason)
        return dg

    def send_control(self, message: bytes, now: float) -> None:
        if self.channel is None or self.state != ESTABLISHED:
            raise RuntimeError("no session")
        self.channel.send(message, now)

    def hold_control(self, count: int) -> None:
        if self.channel is not None:
            self.channel.unread = count

    # -- a slave's session is created by an admitted OPEN (rule 3) -------------------------------
    def accept_open(self, verdict: Verdict, peer: Addr, peer_isn: int, now: float) -> None:
        op = verdict.open
        assert op is not None
        self.peer = peer
        self.nonce = op.nonce
        self.flags = op.flags & wire.MODE_FLAGS
        self.keyed = bool(op.flags & wire.FLAG_KEYED)
        self.suite = op.suite
        self.peer_max_payload = op.max_payload
        self.psk = verdict.psk
        if self.keyed and self.psk is not None:
            keys = crypto.session_keys(self.psk, op.suite, op.nonce, self.own_nonce)
            enc = bool(op.flags & wire.FLAG_ENCRYPTED)
            self.sealer = crypto.Sealer(op.suite, keys.s2m_key, keys.s2m_iv, enc)
            self.opener = crypto.Opener(op.suite, keys.m2s_key, keys.m2s_iv, enc, now)
        self.state = OPENING
        self.opened_at = now
        self.life(now)  # the admitted OPEN that creates the session is a sign of life (5.2)
        self._start_session(peer_isn, now)
        self._send_open_ack(now)

    def _start_session(self, peer_isn: int, now: float) -> None:
        if self.flags & wire.FLAG_TIMESTAMPS and not self.flags & wire.FLAG_MULTIPATH:
            self.stamp_interval = self.cfg.timestamp_interval or 0.004  # a slave's 0: 4 ms
        self.window = ReceiveWindow(
            peer_isn, self.cfg.silence_timeout, far_ahead_check=not self.keyed
        )
        self.channel = ControlChannel(self.cfg, self.isn, peer_isn, now)
        if self.flags & wire.FLAG_MULTIPATH and self.opener is not None:
            self.opener.window = crypto.MULTIPATH_REPLAY_WINDOW

    def _establish(self, now: float) -> None:
        """The session becomes ESTABLISHED (a master on its OPEN_ACK, a slave on the master's first
        packet). A multipath session's paths exist only from now (section 5.11, Negotiation):
        before, an MP code is any session CONTROL and a new address is `wrong_address`."""
        self.state = ESTABLISHED
        if self.flags & wire.FLAG_MULTIPATH and self.peer is not None:
            self.mp = Multipath(self.cfg, self.role, self.nonce, self.peer, now)

    # -- receiving: the table of section 5.5 ----------------------------------------------------
    def receive(self, data: bytes, addr: Addr, now: float) -> None:
        if self.state == CLOSED:
            return self.drop("closed")
        path: Path | None = None
        if self.mp is not None:
            # Row 2 in a multipath session: from one of its paths, or an MP_CHALLENGE carrying
            # the session's nonce (a new path, section 5.11).
            path = self.mp.path_at(addr)
            if path is None and not self._new_path_claim(data):
                return self.drop("wrong_address")
        elif self.peer is not None and addr != self.peer:
            return self.drop("wrong_address")
        if len(data) < wire.HEADER_SIZE:
            return self.drop("truncated")
        if len(data) > self.cfg.largest_datagram:
            return self.drop("oversized")
        if self.mp is not None and path is not None:
            self.mp.arrived(path, len(data), now)
        if not self.validated:
            self.bytes_in += len(data)  # section 5.8: past rows 3 and 4, taken in or not
        hdr = wire.Header.decode(data)
        if hdr.type == wire.CONTROL and len(data) >= 6:
            code = data[5]
            if code in wire.HANDSHAKE_CODES:
                return self._handshake(data, hdr, addr, now)
            if code == wire.RESET:
                return self._reset(data, now)
            if code in wire.PATH_CODES:
                return self._path(data, now)
        if hdr.type == wire.RESERVED:
            return self.drop("unknown_type")
        if self.mp is not None:  # row 6a
            if hdr.type == wire.CONTROL and len(data) >= 6 and data[5] in wire.MP_CODES:
                return self._multipath(data, addr, path, now)
            if hdr.type == wire.DATA and path is not None and self.window is not None:
                reason = self._copy_drop(hdr.seq, path, now)
                if reason is not None:
                    return self.drop(reason)
        self.rx_path = path
        if self.state == IDLE or (self.keyed and self.opener is None):
            return self.drop("not_established")  # row 7
        plain = data
        if self.keyed:
            assert self.opener is not None
            prefix = 6 if hdr.type == wire.CONTROL else 5
            if hdr.type == wire.CONTROL and data[5] in (wire.MP_CHALLENGE, wire.MP_RESPONSE):
                prefix = 22  # their own layout (section 4.4), in any session (FINDINGS.md: open)
            if len(data) < prefix + 18:
                return self.drop("truncated")  # row 8
            verdict, body, _ = self.opener.open(data, prefix, now)
            if body is None:
                return self.drop(verdict)  # rows 9, 10
            plain = data[:prefix] + body
        if self.role == "slave" and self.state == OPENING:
            # Rule 3: the master's first packet of the session establishes the slave before the
            # row that judges it, whatever it decides; it is a sign of life.
            self._establish(now)
            self.life(now)
            # section 5.2: the keep-alive interval runs from here (the OPEN_ACK went before)
            self.last_traffic = now
            if self.mp is not None:
                self.rx_path = self.mp.paths[0]  # the first packet arrived on path 0
        if hdr.type == wire.DATA:
            return self._data(plain, hdr, now)
        if hdr.type == wire.ACK:
            return self._ack(hdr, now)
        return self._control(plain, hdr, now)

    def _read_ack(self, hdr: wire.Header, now: float) -> bool:
        """The acknowledgement in an accepted DATA, ACK or KEEPALIVE; False if optimistic."""
        if hdr.hold == wire.HOLD_NO_ACK or (self.separate_acks and hdr.type != wire.ACK):
            return True
        res = self.log.on_ack(hdr.ack, hdr.sack, hdr.hold, now)
        if (
            not self.validated
            and self.keyed
            and self.log.largest_acked is not None
            and self.log.largest_acked >= self.path_first_seq
        ):
            self.validated = True  # a DATA packet sent on the new path acknowledged (5.8)
        return not res.optimistic

    def _data(self, plain: bytes, hdr: wire.Header, now: float, skip: int = 5) -> None:
        if self.state != ESTABLISHED:
            return self.drop("not_established")
        payload = plain[skip:]  # after the header (a TIMED_DATA's: its code and time too)
        if len(payload) > self.cfg.max_payload:
            return self.drop("oversized")
        if not payload:
            return self.drop("empty_data")
        assert self.window is not None
        arr = self.window.arrive(hdr.seq, now)
        if arr.kind == "far_ahead":
            return self.drop("far_ahead")  # no sign of life, its acknowledgement not read
        self.life(now)
        if self.mp is not None and self.rx_path is not None and arr.kind in ("new", "late"):
            self.mp.on_data(self.rx_path, arr.full, now, first=True)  # a sample taken in
        self.owed_acks.extend(arr.acks)
        self._read_ack(hdr, now)  # an optimistic acknowledgement is ignored, not a drop (3.1)
        if arr.kind == "new":
            self.sink.delivered.append((self, payload))
        else:
            # no reorder wait: a gap is given up at once, so a late sample is not delivered
            self.drop(arr.kind)

    def _ack(self, hdr: wire.Header, now: float) -> None:
        if self.state != ESTABLISHED:
            return self.drop("not_established")
        if not self._read_ack(hdr, now):
            return self.drop("optimistic_ack")
        self.life(now)

    def _control(self, plain: bytes, hdr: wire.Header, now: float) -> None:
        code = plain[5] if len(plain) > 5 else None
        if code in (wire.MESSAGE, wire.MESSAGE_ACK):
            return self._message(plain, now)
        if code in wire.STAMP_CODES:  # section 5.13, then as the ACK or DATA they stand for
            if self.stamp_interval is None:
                return self.drop("unexpected_control")
            try:
                wire.decode_control(plain[5:])
            except wire.BadControlError:
                return self.drop("bad_control")
            if code == wire.TIMESTAMP:
                return self._ack(replace(hdr, type=wire.ACK), now)
            return self._data(plain, replace(hdr, type=wire.DATA), now, skip=10)
        try:
            msg = wire.decode_control(plain[5:])
        except wire.BadControlError:
            return self.drop("bad_control")
        if isinstance(msg, (wire.MpChallenge, wire.MpResponse, wire.MpReport, wire.MpAbandon)):
            # row 13: well formed, but row 6a did not take it (no MULTIPATH, or not established)
            return self.drop("unexpected_control")
        if not isinstance(msg, (wire.Close, wire.Keepalive)):
            return self.drop("bad_control")
        if msg.nonce != self.nonce:
            return self.drop("nonce_mismatch")
        if isinstance(msg, wire.Close):
            self.life(now)
            return self._close(CLOSE_CAUSE.get(msg.reason, "peer_close"), msg.reason)
        if self.state != ESTABLISHED:
            return self.drop("not_established")
        self._read_ack(hdr, now)  # an optimistic acknowledgement in it is ignored
        self.life(now)

    def _message(self, plain: bytes, now: float) -> None:
        """Section 5.10's receiver rules, in their order."""
        if self.state != ESTABLISHED:
            return self.drop("not_established")
        try:
            msg = wire.decode_control(plain[5:])
        except wire.BadControlError:
            return self.drop("bad_control")
        assert isinstance(msg, (wire.Message, wire.MessageAck)) and self.channel is not None
        if isinstance(msg, wire.Message) and len(msg.data) > self.cfg.control_max_message:
            return self.drop("oversized")
        if msg.nonce != self.nonce:
            return self.drop("nonce_mismatch")
        self.life(now)  # well formed, the session's nonce (keyed: authentic): a sign of life
        if not self.channel.on_ack(msg.ack):
            return self.drop("optimistic_ack")
        if isinstance(msg, wire.Message):
            reason, delivered = self.channel.on_message(msg.seq, msg.data)
            for m in delivered:
                self.sink.control_delivered.append((self, m))
            if reason:
                self.drop(reason)

    # -- row 5: the handshake -------------------------------------------------------------------
    def _handshake(self, data: bytes, hdr: wire.Header, addr: Addr, now: float) -> None:
        code = data[5]
        if self.role == "slave":
            if code != wire.OPEN:
                return self.drop("unexpected_control")
            return self._slave_open(data, addr, now)
        try:
            msg = wire.decode_control(data[5:])
        except wire.BadControlError:
            return self.drop("bad_control")
        if not isinstance(msg, (wire.OpenAck, wire.Cookie, wire.Reject)):
            return self.drop("unexpected_control")  # an OPEN sent to a master
        if msg.nonce != self.nonce:
            return self.drop("nonce_mismatch")
        if isinstance(msg, wire.Cookie):
            if self.state != OPENING:
                return self.drop("unexpected_control")
            if msg.version != wire.PROTOCOL_VERSION:
                return self.drop("unknown_version")
            self.life(now)
            self.cookie = msg.cookie
            # Rule 6: the next OPEN at once, at most once per retry interval, within the total.
            if (
                now - self.last_cookie_open_at >= self.cfg.open_retry_interval
                and self.attempts < self.cfg.max_opens
            ):
                self.last_cookie_open_at = now
                self._send_open(now)
            return None
        if isinstance(msg, wire.Reject):
            if self.state != OPENING:
                return self.drop("unexpected_control")
            self.life(now)
            return self._close("rejected", msg.reason)
        assert isinstance(msg, wire.OpenAck)
        return self._open_ack(data, hdr, msg, now)

    def _open_ack(self, data: bytes, hdr: wire.Header, msg: wire.OpenAck, now: float) -> None:
        if self.state not in (OPENING, ESTABLISHED):
            return self.drop("unexpected_control")
        if msg.version != wire.PROTOCOL_VERSION:
            return self.drop("unknown_version")
        if (
            msg.max_payload < 1
            or msg.flags != self.flags & wire.MODE_FLAGS
            or msg.suite != self.suite
        ):
            return self.drop("bad_control")
        if self.keyed:
            assert self.psk is not None and msg.tag is not None
            opener, sealer = self.opener, self.sealer
            if opener is None:
                # the session keys exist only once an OPEN_ACK brings the slave's nonce
                keys = crypto.session_keys(self.psk, self.suite, self.nonce, msg.slave_nonce)
                enc = bool(self.flags & wire.FLAG_ENCRYPTED)
                opener = crypto.Opener(self.suite, keys.s2m_key, keys.s2m_iv, enc, now)
                sealer = crypto.Sealer(self.suite, keys.m2s_key, keys.m2s_iv, enc)
            pn = opener.nearest(msg.packet_number)
            if opener.seen(pn):
                return self.drop("replayed")
            if not crypto.handshake_tag_ok(opener.aead, opener.iv, pn, data[:-16], msg.tag):
                return self.drop("unauthenticated")
            opener.accept(pn, now)
            self.opener, self.sealer = opener, sealer
        self.life(now)
        if self.state == ESTABLISHED:
            return None  # a duplicate: absorbed, a sign of life
        if msg.max_payload < self.cfg.min_peer_payload:
            self._send_close(wire.PAYLOAD_TOO_SMALL, now)
            return self._close("rejected", wire.PAYLOAD_TOO_SMALL)
        self.peer_max_payload = msg.max_payload
        self._start_session(peer_isn=hdr.seq, now=now)
        self._establish(now)
        self.last_traffic = None  # its first packet leaves at once (rule 6): a KEEPALIVE at least

    def _slave_open(self, data: bytes, addr: Addr, now: float) -> None:
        assert self.admission is not None
        v = self.admission.judge(data, addr, now)
        if v.reply is not None:
            self.queue.append(Sent(v.reply, addr, v.reply_label))  # not session traffic
        if v.drop is not None:
            return self.drop(v.drop)
        assert v.open is not None
        if v.open.nonce == self.nonce:
            # Rule 4: a new OPEN_ACK, in OPENING and ESTABLISHED alike; no sign of life.
            self._send_open_ack(now)
            return None
        # Rule 5: another nonce. A restarted master if the session has been silent longer than a
        # live master ever is; else a replay. Never a sign of life.
        self.drop("nonce_mismatch")
        if self.silence(now) > self.live_silence():
            self.replacing = data
            self._close("replaced", None)
        return None

    # -- path migration (section 5.8) ------------------------------------------------------------
    def quiet(self, now: float) -> bool:
        if self.state != ESTABLISHED:
            return False
        if self.keyed:
            return self.silence(now) >= self.cfg.migration_quiet
        return self.silence(now) > self.live_silence()

    def trial(self, data: bytes) -> str:
        """'ahead', 'replayed' or 'failed': may this datagram move this keyed session?"""
        assert self.opener is not None
        prefix = 6 if data[0] >> 6 == wire.CONTROL else 5
        if len(data) < prefix + 18:
            return "failed"
        return self.opener.trial(data, prefix)

    def move(self, addr: Addr, now: float, by_response: bool) -> None:
        self.moved_from = self.peer
        self.peer = addr
        self.validated = False
        self.bytes_in = self.bytes_out = 0
        self.moved_at = now
        self.moved_by_response = by_response
        self.path_first_seq = self.log.next_seq

    def move_back(self) -> None:
        assert self.moved_from is not None
        self.peer, self.moved_from = self.moved_from, None
        self.validated = True

    # -- row 6a: multipath (section 5.11) ---------------------------------------------------------
    def _new_path_claim(self, data: bytes) -> bool:
        """An MP_CHALLENGE (long enough for its nonce) carrying the session's nonce."""
        return (
            len(data) >= 22
            and data[0] >> 6 == wire.CONTROL
            and data[5] == wire.MP_CHALLENGE
            and data[6:22] == self.nonce
        )

    def _copy_drop(self, seq12: int, path: Path, now: float) -> str | None:
        """A DATA copy of a sample taken in (`duplicate`), or one far below a live flow (`stale`),
        before the packet protection; the copy still counts in its path's report."""
        assert self.mp is not None and self.window is not None
        full = self.window.decode(seq12)
        h = self.window.highest
        h_at = self.window.arrivals[h] if h is not None else 0.0
        reason = self.mp.copy_drop(full, h, h_at, now)
        if reason is not None:  # both count in the path's `received` (4.3)
            self.mp.on_data(path, full, now, first=False)
        return reason

    def _mp_datagram(self, msg: wire.ControlBody) -> bytes:
        """A multipath CONTROL datagram; keyed, MP_CHALLENGE and MP_RESPONSE keep the nonce in
        the clear before the packet number (section 4.4)."""
        body = wire.encode_control(msg)
        head = self._plain_header().encode()
        if self.sealer is None:
            return head + body
        clear = 17 if msg.code in (wire.MP_CHALLENGE, wire.MP_RESPONSE) else 1
        return self.sealer.seal(head + body[:clear], body[clear:])

    def _send_mp(self, msg: wire.ControlBody, addr: Addr, now: float, queue: bool) -> None:
        s = Sent(self._mp_datagram(msg), addr, wire.CODE_NAMES[msg.code])
        if queue:
            self.mp_queue.append(s)  # an answer: it leaves first in the next flush
        else:
            self._emit(s, now)
        # Session traffic, but unseen by this instant's KEEPALIVE check (section 5.2): it holds
        # back the next KEEPALIVE, not this one (the flush applies it after the check).
        self.mp_traffic = True

    def _multipath(self, data: bytes, addr: Addr, path: Path | None, now: float) -> None:
        """Row 6a for the four multipath codes, in its order."""
        mp = self.mp
        assert mp is not None
        code = data[5]
        plain = data
        if self.keyed:
            if self.opener is None:
                return self.drop("not_established")
            prefix = 22 if code in (wire.MP_CHALLENGE, wire.MP_RESPONSE) else 6
            if len(data) < prefix + 18:
                return self.drop("truncated")
            verdict, body, _ = self.opener.open(data, prefix, now)
            if body is None:
                return self.drop(verdict)
            plain = data[:prefix] + body
        try:
            msg = wire.decode_control(plain[5:])
        except wire.BadControlError:
            return self.drop("bad_control")
        assert isinstance(msg, (wire.MpChallenge, wire.MpResponse, wire.MpReport, wire.MpAbandon))
        if msg.nonce != self.nonce:
            return self.drop("nonce_mismatch")
        if isinstance(msg, wire.MpAbandon):
            # sent on the path it names and on the best other one: it may come on any path
            if not mp.abandon(msg.path_id):
                return self.drop("unknown_path")
            return self.life(now)
        if path is None:  # row 2 lets only an MP_CHALLENGE with our nonce come from elsewhere
            assert isinstance(msg, wire.MpChallenge)
            if self.state != ESTABLISHED:
                return self.drop("not_established")
            path, reason, answer = mp.learn(msg.path_id, addr, now)
            if path is None:
                if answer:  # a full table: MP_ABANDON PATH_LIMIT, so that the opener stops asking
                    refusal = wire.MpAbandon(self.nonce, msg.path_id, wire.PATH_LIMIT)
                    self._send_mp(refusal, addr, now, queue=True)
                assert reason is not None
                return self.drop(reason)
            mp.arrived(path, len(data), now)
        elif msg.path_id != path.path_id:
            return self.drop("unknown_path")
        if isinstance(msg, wire.MpChallenge):
            token = NO_TOKEN if path.validated else mp.new_token(path, now)
            answer_ = wire.MpResponse(self.nonce, path.path_id, msg.token, token)
            self._send_mp(answer_, path.addr, now, queue=True)
        elif isinstance(msg, wire.MpResponse):
            if not mp.validated_by(path, msg.echo, now):
                return self.drop("bad_token")
            if msg.token != NO_TOKEN:  # the peer's own challenge: echo it, with no token
                echo = wire.MpResponse(self.nonce, path.path_id, msg.token, NO_TOKEN)
                self._send_mp(echo, path.addr, now, queue=True)
        elif isinstance(msg, wire.MpReport):
            mp.on_report(path, msg, now)  # its lag, for the best path; no scheduler to feed
        self.life(now)  # a sign of life (FINDINGS.md: open)
        return None

    def _flush_multipath(self, now: float) -> None:
        """The reports due and the probes (section 5.11), after the control channel."""
        mp = self.mp
        assert mp is not None
        for path, report in mp.reports_due(now):
            self._send_mp(report, path.addr, now, queue=False)
        for path in mp.probes_due(now):
            probe = wire.MpChallenge(self.nonce, path.path_id, mp.new_token(path, now))
            self._send_mp(probe, path.addr, now, queue=False)

    # -- row 5a: RESET (section 5.7) --------------------------------------------------------------
    def _reset(self, data: bytes, now: float) -> None:
        if self.role == "slave" or self.state != ESTABLISHED:
            return self.drop("unexpected_control")
        try:
            msg = wire.decode_control(data[5:])
        except wire.BadControlError:
            return self.drop("bad_control")
        assert isinstance(msg, wire.Reset)
        matched = msg.echo in self.echoes
        if matched and self.keyed:
            assert self.psk is not None
            want = crypto.reset_tag(crypto.reset_key(self.psk), msg.echo)
            matched = want in msg.tags
        if not matched:
            return self.drop("unmatched_reset")
        if self.silence(now) < self.cfg.silence_timeout:
            return self.drop("peer_alive")
        return self._close("peer_restarted", None)

    # -- row 5b: PATH_CHALLENGE / PATH_RESPONSE (section 5.8) ---------------------------------------
    def _path(self, data: bytes, now: float) -> None:
        try:
            msg = wire.decode_control(data[5:])
        except wire.BadControlError:
            return self.drop("bad_control")
        if (
            isinstance(msg, wire.PathResponse)
            or self.role == "slave"
            or self.keyed
            or self.state != ESTABLISHED
        ):
            return self.drop("unexpected_control")
        assert isinstance(msg, wire.PathChallenge)
        if now - self.last_path_response < self.cfg.path_response_interval:
            return self.drop("rate_limited")
        self.last_path_response = now
        dg = wire.control_datagram(wire.PathResponse(msg.token, self.nonce), wire.plain_header())
        self._queue(dg, "PATH_RESPONSE", False, now)  # not session traffic, not a sign of life
        return None

    # -- timers and the flush (section 5.2's order) ----------------------------------------------
    def tick(self, now: float) -> None:
        """Act on every timer due at this instant, then send what leaves now."""
        self._timers(now)
        self._flush(now)

    def _timers(self, now: float) -> None:
        if self.state == OPENING:
            if self.role == "master":
                if now >= self.opened_at + self.cfg.open_timeout:
                    self._close("open_timeout", None)
                elif (
                    self.attempts < self.cfg.max_opens
                    and now >= self.last_open_at + self.cfg.open_retry_interval
                ):
                    self._send_open(now)
            elif now >= self.opened_at + self.cfg.open_timeout:
                self._close("open_timeout", None)
        elif self.state == ESTABLISHED:
            if self.silence(now) >= self.cfg.idle_timeout:
                self._send_close(wire.IDLE_TIMEOUT, now)
                self._close("idle_timeout", wire.IDLE_TIMEOUT)
                return
            due = self.log.loss_timer()
            if due is not None and now >= due:
                self.log.on_timer(now)
            if self.channel is not None:
                self.channel.expire(now)
            if self.mp is not None:
                self.mp.expire(now)
            if (
                self.role == "slave"
                and not self.validated
                and self.moved_by_response
                and now >= self.moved_at + self.cfg.silence_timeout
            ):
                self.validated = True  # the old address stayed silent (section 5.8)

    def _flush_need(self) -> int:
        """Section 5.8: the queued control datagrams plus the most the rest of one flush could emit
        (a full-size sample, two ACKs and a KEEPALIVE)."""
        prot = 18 if self.keyed else 0
        sample = 5 + self.max_send_payload + prot
        ack = self.cfg.ack_size + prot
        keepalive = 22 + prot
        return sum(len(s.data) for s in self.queue) + sample + 2 * ack + keepalive

    def _flush(self, now: float) -> None:
        if not self.validated and 3 * self.bytes_in - self.bytes_out < self._flush_need():
            return  # the amplification limit delays everything (section 5.8)
        # 0. a multipath session's own packets first (section 5.2): the answers queued, then
        #    the reports due and the probes
        for s in self.mp_queue:
            self._emit(s, now)
        self.mp_queue.clear()
        if self.mp is not None and self.state == ESTABLISHED:
            self._flush_multipath(now)
        # 1. the control datagrams queued
        for s in self.queue:
            self._emit(s, now)
        self.queue.clear()
        if self.state != ESTABLISHED:
            self.owed_acks.clear()
            self.mp_traffic = False
            return
        # 2. jump-rule and late-rule ACKs, then full-rule ACKs (section 3.2), in order owed
        for owed in self.owed_acks:
            self._send_ack(owed, now)
        self.owed_acks.clear()
        # 3. the sample: this implementation's application sends none in the vectors
        # 4. the ACK due (section 5.3 (a))
        assert self.window is not None
        if self.window.ack_delay_due(now, self.cfg.ack_delay):
            owed_ack = self.window.ack_delay_ack()
            if owed_ack is not None:
                self._send_ack(owed_ack, now)
        # 5. the control channel
        if self.validated:
            self._flush_channel(now)
        # 6. the KEEPALIVE check comes last, blind to step 0's multipath packets
        if self.last_traffic is None or now >= self.last_traffic + self.cfg.keepalive:
            self._send_keepalive(now)
        if self.mp_traffic:
            self.mp_traffic = False
            self.last_traffic = now

    def _send_ack(self, owed: OwedAck, now: float) -> None:
        hdr = wire.Header(
            wire.ACK,
            self.log.next_seq & 0xFFF,
            owed.ack & 0xFFF,
            owed.sack,
            wire.hold_encode_seconds(now - owed.since),
        )
        if self.stamp_interval is not None and now - self.last_stamp >= self.stamp_interval:
            # a stamp is due: the ACK leaves as a TIMESTAMP, unpadded (section 5.13)
            self.last_stamp = now
            stamp = wire.Timestamp(wire.clock_us(now))
            dg = self._session_control(stamp, replace(hdr, type=wire.CONTROL))
            return self._send_traffic(dg, "TIMESTAMP", now)
        pad = bytes(self.cfg.ack_size - 5)
        dg = self.sealer.seal(hdr.encode(), pad) if self.sealer else hdr.encode() + pad
        self._send_traffic(dg, "ACK", now)

    def _send_keepalive(self, now: float) -> None:
        dg = self._session_control(wire.Keepalive(self.nonce), self._header_ack(now))
        self._send_traffic(dg, "KEEPALIVE", now)

    def _send_traffic(self, dg: bytes, label: str, now: float) -> None:
        assert self.peer is not None
        self.last_traffic = now
        if self.role == "master" and label in ("DATA", "ACK", "KEEPALIVE", "TIMESTAMP"):
            self.echoes.append(dg[:16])  # what a RESET may echo (section 5.7)
        self._emit(Sent(dg, None, label), now)

    def _flush_channel(self, now: float) -> None:
        ch = self.channel
        assert ch is not None
        sent_message = False
        for m in ch.due(now, self.log.loss_delay):
            msg = wire.Message(self.nonce, m.number, ch.ack_field, m.data)
            self._send_traffic(self._session_control(msg, self._plain_header()), "MESSAGE", now)
            ch.transmitted(m, now)
            sent_message = True
        if ch.owe_ack:
            ch.owe_ack = False
            if not sent_message:  # a MESSAGE of our own carries the acknowledgement
                msg_ack = wire.MessageAck(self.nonce, ch.ack_field)
                self._send_traffic(
                    self._session_control(msg_ack, self._plain_header()), "MESSAGE_ACK", now
                )
