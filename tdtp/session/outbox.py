"""What a connection sends: control datagrams waiting for the next flush, the framing and protection of
ACK, KEEPALIVE and CLOSE datagrams, and the send-side counters.

:class:`Outbox` is the send path's helper, like aioquic's packet builder: the connection decides *what*
is due (a sample the pacer lets go, an ACK the delay rule owes, a KEEPALIVE), the outbox turns it into a
datagram, seals it in a keyed session, counts it in ``stats.sent`` and records that the peer heard from
us (which holds back the next KEEPALIVE). The hottest path, a sample sent straight through
``Connection.send_direct``, inlines the same steps.
"""

from __future__ import annotations

from tdtp.config import ConnectionConfig
from tdtp.protection.packet_protection import PacketSealer
from tdtp.session.events import Address
from tdtp.session.liveness import Liveness
from tdtp.session.one_way import OneWayDelay
from tdtp.session.reset_guard import ResetGuard
from tdtp.session.stats import ConnectionStats
from tdtp.wire.control import ControlCode, encode_close, encode_timestamp
from tdtp.wire.header import HEADER_SIZE, SEQ_MASK, PacketType, encode_header, pack_header_words
from tdtp.wire.hold import HOLD_NO_ACK

_ACK = int(PacketType.ACK)
_CONTROL = int(PacketType.CONTROL)
_CLOSE_PREFIX = bytes((ControlCode.CLOSE,))
_KEEPALIVE_PREFIX = bytes((ControlCode.KEEPALIVE,))
_TIMESTAMP = ControlCode.TIMESTAMP

Datagrams = list[tuple[bytes, Address]]


class Outbox:
    """The session's sealer once keyed, the control queue, and the counting of what leaves."""

    def __init__(
        self, config: ConnectionConfig, stats: ConnectionStats, liveness: Liveness
    ) -> None:
        self.sealer: PacketSealer | None = None
        """Our packet protection in a keyed session (installed at the open)."""
        self.overhead = 0
        """Bytes our packet protection adds to each session datagram, once keyed."""
        self.control: list[tuple[bytes, Address, int, bool]] = []
        """Control datagrams queued for the next flush: datagram, destination, protection bytes,
        and whether it is session traffic (not: admission's COOKIE or REJECT answering an OPEN)."""
        self.reset_guard: ResetGuard | None = None
        """A master's memory of its recent datagrams, which a RESET must echo (set at connect)."""
        self.one_way: OneWayDelay | None = None
        """Our stamps' schedule (the sender's): a stand-alone ACK goes as a TIMESTAMP when one is
        due."""
        self._ack_padding = bytes(config.ack_size - HEADER_SIZE)
        self._stats = stats
        self._liveness = liveness

    def protect(self, prefix: bytes, body: bytes) -> bytes:
        """Seal a session datagram in a keyed session; plain ``prefix + body`` otherwise."""
        sealer = self.sealer
        return prefix + body if sealer is None else sealer.seal(prefix, body)

    def queue(self, datagram: bytes, addr: Address, protection: int, session: bool) -> None:
        """A control datagram for the next flush (:meth:`flush`)."""
        self.control.append((datagram, addr, protection, session))

    def queue_close(self, seq: int, nonce: bytes, reason: int, addr: Address) -> None:
        datagram = self.protect(
            encode_header(_CONTROL, seq, 0, 0, HOLD_NO_ACK) + _CLOSE_PREFIX,
            encode_close(ControlCode.CLOSE, nonce, reason)[1:],
        )
        self.control.append((datagram, addr, self.overhead, True))

    def flush(self, out: Datagrams, now: float) -> None:
        """Move the queued control datagrams to ``out``."""
        control = self.control
        for datagram, addr, protection, session in control:
            self.emit_control(out, datagram, addr, now, protection, session)
        control.clear()

    def emit_data(
        self, out: Datagrams, datagram: bytes, payload_size: int, peer: Address, now: float
    ) -> None:
        sent = self._stats.sent
        sent.data_packets += 1
        sent.payload_bytes += payload_size
        self._count(len(datagram), now, self.overhead, True)
        guard = self.reset_guard
        if guard is not None:
            guard.record(datagram)
        out.append((datagram, peer))

    def emit_ack(
        self, out: Datagrams, seq: int, ack: int, sack: int, hold: int, peer: Address, now: float
    ) -> None:
        # self.protect(encode_header(_ACK, seq, ack, sack, hold), padding), inline
        seq &= SEQ_MASK
        word = ((seq & 0x3F) << 26) | ((ack & SEQ_MASK) << 14) | (sack << 8) | hold
        one_way = self.one_way
        if one_way is not None and now >= one_way.due:
            # A TIMESTAMP in its place (PROTOCOL.md 5.13): the same fields, and our clock.
            stamp = encode_timestamp(_TIMESTAMP, one_way.stamp(now))
            header = pack_header_words((_CONTROL << 6) | (seq >> 6), word) + stamp[:1]
            body = stamp[1:]
        else:
            header = pack_header_words((_ACK << 6) | (seq >> 6), word)
            body = self._ack_padding
        sealer = self.sealer
        datagram = header + body if sealer is None else sealer.seal(header, body)
        self._stats.sent.ack_packets += 1
        self._count(len(datagram), now, self.overhead, True)
        guard = self.reset_guard
        if guard is not None:
            guard.record(datagram)
        out.append((datagram, peer))

    def emit_keepalive(
        self,
        out: Datagrams,
        seq: int,
        ack: int,
        sack: int,
        hold: int,
        nonce: bytes,
        peer: Address,
        now: float,
    ) -> None:
        """A KEEPALIVE carrying the master's ``nonce`` (sealed with the rest in a keyed session)."""
        datagram = self.protect(
            encode_header(_CONTROL, seq, ack, sack, hold) + _KEEPALIVE_PREFIX, nonce
        )
        self.emit_control(out, datagram, peer, now, self.overhead, True)
        guard = self.reset_guard
        if guard is not None:
            guard.record(datagram)

    def emit_control(
        self,
        out: Datagrams,
        datagram: bytes,
        addr: Address,
        now: float,
        protection: int,
        session: bool,
    ) -> None:
        sent = self._stats.sent
        sent.control_packets += 1
        sent.payload_bytes += len(datagram) - HEADER_SIZE - protection
        self._count(len(datagram), now, protection, session)
        out.append((datagram, addr))

    def _count(self, size: int, now: float, protection: int, session: bool) -> None:
        sent = self._stats.sent
        sent.datagrams += 1
        sent.bytes += size
        sent.header_bytes += HEADER_SIZE
        sent.protection_bytes += protection
        if session:
            # The peer hears from us: no KEEPALIVE needed for a while. A COOKIE or REJECT to
            # whoever sent an OPEN says nothing to the peer (it may be a forgery or a replay),
            # so it must not hold back our KEEPALIVEs (PROTOCOL.md 5.2).
            self._liveness.last_send = now
