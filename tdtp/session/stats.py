"""Counters a connection keeps: live, cheap to update, and plain data to print or serialise."""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import Any

from tdtp.wire.drop_reason import DropReason as DropReason  # noqa: PLC0414 - its old home, re-exported
from tdtp.wire.header import HEADER_SIZE

_logger = logging.getLogger("tdtp")


@dataclass(slots=True)
class DirectionStats:
    """Traffic one way. Byte counts are TDTP datagram bytes: the 5-byte header included, IP/UDP not."""

    datagrams: int = 0
    bytes: int = 0
    header_bytes: int = 0
    payload_bytes: int = 0
    data_packets: int = 0
    ack_packets: int = 0
    control_packets: int = 0
    protection_bytes: int = 0
    """Keyed sessions: bytes of packet numbers and authentication tags (18 per protected datagram)."""


@dataclass(slots=True)
class ConnectionStats:
    """A connection's live counters: both directions' bytes and packets, samples offered, superseded
    and delivered, losses, RTT, the allowed rate, and every dropped datagram by reason."""

    sent: DirectionStats = field(default_factory=DirectionStats)
    received: DirectionStats = field(default_factory=DirectionStats)
    """Datagrams taken in (dropped ones are in ``drops`` only)."""
    datagrams_in: int = 0
    """Every datagram handed to ``receive_datagram``; equals ``received.datagrams + dropped``."""
    drops: dict[str, int] = field(default_factory=dict)
    """Dropped datagrams by :class:`DropReason` value."""
    samples_offered: int = 0
    """Payloads the application passed to ``send``."""
    samples_superseded: int = 0
    """Payloads replaced by a newer one before they left (latest-value semantics): the pacer held
    them, or the socket's send buffer was full (those are in ``samples_blocked`` too)."""
    samples_blocked: int = 0
    """Of ``samples_superseded``: replaced while the socket's send buffer was backed up (the pacer
    would have let them go; the operating system could not take them)."""
    send_pauses: int = 0
    """Times the socket's send buffer backed up and data was held back until it drained."""
    samples_delivered: int = 0
    """Payloads handed to the application as :class:`~tdtp.session.events.DataReceived`."""
    samples_timed: int = 0
    """Of ``samples_delivered``: samples whose own header timed them (an acknowledgement of one of
    our packets held under 31.7 ms): their ``DataReceived.sent_at`` is set (PROTOCOL.md 3.6)."""
    sample_age_p50: float = 0.0
    """Median age at arrival of the samples delivered, in seconds (``DataReceived.age``: timed ones
    from their own header, the others half the RTT); 0 before any. Refreshed on access."""
    sample_age_p99: float = 0.0
    """99th percentile of the same ages (from a fixed histogram: within 1 %)."""
    samples_skipped: int = 0
    """Delivered samples a latest-value reader never saw: a newer one had arrived by the time it
    read (``ep.latest()``, ``async for sample in ep``). Superseded at the receiver."""
    events_discarded: int = 0
    """Data events dropped because the application did not drain them fast enough (the bounded
    queue of ``max_pending_events`` was full)."""
    peer_silences: int = 0
    """Times the watchdog found the peer silent for ``silence_timeout`` (outages, a stalled peer)."""
    longest_silence: float = 0.0
    """The longest silence from the peer that ended, in seconds (one still going is not included)."""
    packets_acked: int = 0
    """Own data packets the peer reported received."""
    packets_lost: int = 0
    """Own data packets declared lost: an ACK reported them absent and ``srtt + max(reorder window,
    4 rttvar, 1 ms) + ack_delay`` has passed since they were sent while a later one is acknowledged,
    or, until reordering has been seen, the largest ACK field is 3 or more above them
    (docs/PROTOCOL.md section 5.4)."""
    packets_unreported: int = 0
    """Own data packets whose fate is unknown: every ACK that could have reported them was lost on the
    way back. Counted neither as acknowledged nor as lost (they are no evidence of congestion)."""
    spurious_losses: int = 0
    """Packets declared lost and later reported received after all (deep reordering)."""
    packets_reordered: int = 0
    """Own data packets an ACK reported absent that a later ACK reported received: reordered on the
    way, not lost (counted apart from ``packets_lost``; the rate controller never sees them)."""
    loss_events: int = 0
    reordered: int = 0
    """Peer data packets that arrived after a newer one (delivered in order if they came within the
    reorder wait, else dropped as ``late``)."""
    reorder_held: int = 0
    """Samples delivered after a reorder wait: they arrived after a gap and were held, in order,
    until it filled or its wait ran out (``ConnectionConfig.max_reorder_wait``)."""
    reorder_wait: float = 0.0
    """The reorder wait in force, seconds: adapted to the reordering measured, 0 while there is none."""
    peer_gaps: int = 0
    """Peer sequence numbers skipped at arrival (lost or not yet arrived), as this side saw them."""
    ecn_ce: int = 0
    """Datagrams from the peer that arrived marked ECN Congestion Experienced (RFC 3168 / 9331), as
    the driver read the IP header's ECN field (``receive_datagram(..., ecn=3)``)."""
    migrations: int = 0
    """Times a slave's session followed its master to a new address (path migration, PROTOCOL.md
    5.8): a keyed datagram that authenticated from there, an unkeyed PATH_RESPONSE, or (unkeyed)
    its old address speaking again before the new one was proven."""
    paths_validated: int = 0
    """New paths validated (unkeyed: its old address stayed silent for ``silence_timeout`` after
    the PATH_RESPONSE moved it; keyed: by an authenticated datagram from there that acknowledges a
    packet sent on it)."""
    optimistic_acks: int = 0
    """Acknowledgements in accepted DATA or KEEPALIVE datagrams that named a packet we never sent:
    ignored, the rest of the datagram taken (a stand-alone ACK is dropped as ``optimistic_ack``)."""
    path_limited: int = 0
    """Times the amplification limit of a path not validated yet held back what was due."""
    unvalidated_bytes_in: int = 0
    """Bytes received from a new address before it was validated (the amplification budget's base)."""
    unvalidated_bytes_out: int = 0
    """Bytes sent to a new address before it was validated: at most 3 x ``unvalidated_bytes_in``."""
    control_sent: int = 0
    """Control messages the application passed to ``send_control`` (docs/PROTOCOL.md 5.10)."""
    control_transmissions: int = 0
    """MESSAGE datagrams sent: first transmissions and retransmissions."""
    control_retransmits: int = 0
    """Of ``control_transmissions``: a message sent again (its acknowledgement did not come in time)."""
    control_acked: int = 0
    """Own control messages the peer acknowledged."""
    control_given_up: int = 0
    """Own control messages given up after ``control_timeout`` (reported by ``ControlExpired``)."""
    control_delivered: int = 0
    """The peer's control messages delivered to the application (``ControlReceived``), in order."""
    control_dropped: dict[str, int] = field(default_factory=dict)
    """Peer control messages not delivered, by reason: ``duplicate`` (delivered or held already),
    ``control_window``, ``control_backlog``, ``oversized``, ``bad_control``, ``nonce_mismatch``
    and ``optimistic_ack`` (each datagram is also in ``drops`` under the same reason)."""
    closed: bool = False
    """The connection has ended: ``srtt`` and ``rttvar`` read NaN, ``rate`` 0 and ``rate_limit``
    ``"closed"`` (refreshed on access); the counters keep what the session did."""
    rtt_samples: int = 0
    srtt: float = 0.0
    rttvar: float = 0.0
    min_rtt: float = 0.0
    loss_event_rate: float = 0.0
    rate: float = 0.0
    """The rate controller's allowed rate, packets per second."""
    rate_limit: str = ""
    """What limits the rate now, as the controller says (``"application"``, ``"queue delay 7.2
    ms one way"``, ``"loss"``, ``"tcp-friendly ceiling"``, ``"floor"``; empty if it does not say)."""
    timestamps: bool = False
    """The session stamps send times (the TIMESTAMPS flag, docs/PROTOCOL.md 5.13): each end
    measures the queue of each direction apart (``queue_delay_out``, ``queue_delay_in``)."""
    queue_delay_out: float = 0.0
    """Our packets' queueing delay on their way to the peer, seconds, as the peer's send times
    measure it (a moving average; 0 in a session without timestamps, docs/PROTOCOL.md 5.13)."""
    queue_delay_in: float = 0.0
    """The peer's packets' queueing delay on their way here, seconds (likewise)."""
    stamps_rejected: int = 0
    """Peer send times outside the bounds a real one respects (forged, corrupted, a clock jump):
    not used."""

    @property
    def dropped(self) -> int:
        """Datagrams dropped, all reasons together (``drops`` has them by reason)."""
        return sum(self.drops.values())

    def count_handshake(self, size: int, tag: int) -> None:
        """A handshake message taken in: ``size`` bytes, the last ``tag`` of them its tag (a keyed
        OPEN or OPEN_ACK), counted as protection."""
        received = self.received
        received.datagrams += 1
        received.bytes += size
        received.header_bytes += HEADER_SIZE
        received.payload_bytes += size - HEADER_SIZE - tag
        received.protection_bytes += tag
        received.control_packets += 1

    def count_drop(self, reason: DropReason) -> None:
        """Count one datagram dropped for ``reason``."""
        key = reason.value
        self.drops[key] = self.drops.get(key, 0) + 1
        if _logger.isEnabledFor(logging.DEBUG):
            _logger.debug("dropped a datagram: %s", key)

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready copy (``math.inf`` rates become ``None``)."""
        data = asdict(self)
        data["dropped"] = self.dropped
        for name in ("rate", "srtt", "rttvar"):
            if not math.isfinite(data[name]):  # NaN once closed, inf when unlimited
                data[name] = None
        return data
