"""Endpoints: a master, and a stand-alone slave (one master, LISTENING until an OPEN is admitted)."""

from __future__ import annotations

from . import crypto, wire
from .admission import Admission
from .bucket import TokenBucket
from .config import Addr, Config
from .connection import LISTENING, Connection, Sent, Sink

RESET_MIN = 22


def is_session_datagram(data: bytes) -> bool:
    """What a RESET answers (section 5.7): DATA, ACK, or a CONTROL whose code byte is KEEPALIVE,
    TIMESTAMP or TIMED_DATA."""
    t = data[0] >> 6
    return t in (wire.DATA, wire.ACK) or (
        t == wire.CONTROL
        and len(data) >= 6
        and data[5] in (wire.KEEPALIVE, wire.TIMESTAMP, wire.TIMED_DATA)
    )


def make_reset(data: bytes, ring: list[bytes]) -> bytes | None:
    """The stateless RESET for a datagram no session can claim (section 5.7), or None when it
    would be larger than the datagram (unkeyed: under 22 bytes; keyed: no room for a tag)."""
    if len(data) < RESET_MIN or not is_session_datagram(data):
        return None
    echo = data[:16]
    tags: list[bytes] = []
    if ring:
        room = (len(data) - RESET_MIN) // 16
        if room == 0:
            return None
        tags = [crypto.reset_tag(crypto.reset_key(k), echo) for k in ring[:room]]
    return wire.control_datagram(wire.Reset(echo, tags), wire.plain_header())


def is_open(data: bytes) -> bool:
    return len(data) >= 6 and data[0] >> 6 == wire.CONTROL and data[5] == wire.OPEN


class Master:
    def __init__(self, cfg: Config, nonce: bytes, initial_seq: int, now: float = 0.0) -> None:
        self.sink = Sink()
        self.conn = Connection("master", cfg, self.sink, nonce, initial_seq, now)

    @property
    def state(self) -> str:
        return self.conn.state

    def connect(self, slave: Addr, now: float) -> None:
        self.conn.connect(slave, now)

    def receive(self, data: bytes, addr: Addr, now: float) -> None:
        self.conn.receive(data, addr, now)

    def tick(self, now: float) -> None:
        self.conn.tick(now)


class StandaloneSlave:
    """A slave serving one master (section 5.1's state machine, row 7 of section 5.5)."""

    def __init__(self, cfg: Config, nonce: bytes, initial_seq: int, now: float = 0.0) -> None:
        self.cfg = cfg
        self.sink = Sink()
        self.admission = Admission(cfg, now)
        self.resets = TokenBucket(cfg.resets_per_second, cfg.resets_per_second, now)
        self.nonce = nonce
        self.isn = initial_seq
        self.conn: Connection | None = None

    @property
    def state(self) -> str:
        return self.conn.state if self.conn is not None else LISTENING

    def _drop(self, reason: str) -> None:
        self.sink.drops.append((self, reason))

    def receive(self, data: bytes, addr: Addr, now: float) -> None:
        if self.conn is not None:
            return self.conn.receive(data, addr, now)
        if len(data) < wire.HEADER_SIZE:
            return self._drop("truncated")
        if len(data) > self.cfg.largest_datagram:
            return self._drop("oversized")
        t = data[0] >> 6
        if t == wire.CONTROL and len(data) >= 6:
            code = data[5]
            if code == wire.OPEN:
                v = self.admission.judge(data, addr, now)
                if v.reply is not None:
                    self.sink.sent.append(Sent(v.reply, addr, v.reply_label))
                if v.drop is not None:
                    return self._drop(v.drop)
                self.conn = Connection(
                    "slave",
                    self.cfg,
                    self.sink,
                    self.nonce,
                    self.isn,
                    now,
                    admission=self.admission,
                )
                self.conn.accept_open(v, addr, wire.Header.decode(data).seq, now)
                return None
            if code in wire.HANDSHAKE_CODES or code == wire.RESET:
                return self._drop("unexpected_control")
            if code in wire.PATH_CODES:
                try:
                    wire.decode_control(data[5:])
                except wire.BadControlError:
                    return self._drop("bad_control")
                return self._drop("unexpected_control")
        if t == wire.RESERVED:
            return self._drop("unknown_type")
        self._drop("not_established")
        reset = make_reset(data, self.cfg.psks)
        if reset is not None and self.resets.take(now):
            self.sink.sent.append(Sent(reset, addr, "RESET"))
        return None

    def tick(self, now: float) -> None:
        if self.conn is not None:
            self.conn.tick(now)
