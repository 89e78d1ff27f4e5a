"""Connection configuration: one validated, immutable dataclass."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from tdtp.wire.header import HEADER_SIZE
from tdtp.wire.hold import HOLD_MAX

MAX_UDP_PAYLOAD = 65507
"""Largest UDP payload over IPv4; the TDTP payload limit is this minus the 5-byte header."""


class Role(enum.Enum):
    MASTER = "master"
    """Opens the connection (the operator's side: joystick, haptic device)."""
    SLAVE = "slave"
    """Accepts it (the remote robot or crane)."""


class AckMode(enum.Enum):
    BIDIRECTIONAL = "bidirectional"
    """TDTP: acknowledgements ride in the reverse data packets."""
    SEPARATE = "separate"
    """Trinomial: one stand-alone ACK packet per received data packet (the paper's comparison)."""


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _positive_finite(name: str, value: float) -> None:
    _require(
        isinstance(value, int | float) and math.isfinite(value) and value > 0,
        f"{name} must be a positive number of seconds, got {value!r}",
    )


@dataclass(frozen=True, slots=True)
class ConnectionConfig:
    """Everything a :class:`~tdtp.connection.Connection` can be told. Times are in seconds."""

    max_payload: int = 1200
    """Largest payload this endpoint sends or accepts (bytes, header excluded). The peer's value,
    learned at the open, also caps what is sent."""
    ack_mode: AckMode = AckMode.BIDIRECTIONAL
    """Chosen by the master; a slave adopts whatever the master's OPEN asks for."""
    ack_size: int = HEADER_SIZE
    """Bytes of a stand-alone ACK datagram, header included (padding is zeros). The paper's Trinomial
    simulation used 40-byte ACK packets at the IP layer, i.e. ``ack_size`` 20 over raw IP."""
    plain_acks: bool = False
    """Separate-ACK mode only: each stand-alone ACK reports its own packet and nothing else (SACK bits
    zero), the paper's one-ACK-per-packet Trinomial, so a lost ACK reads as a lost packet. ``False``
    repeats the receiver's knowledge of the 6 packets below it, so a lost ACK costs nothing."""
    ack_delay: float = 0.020
    """Longest a received packet waits for a reverse packet to carry its ACK before a stand-alone ACK
    goes out (bidirectional mode). At most 31.232 ms, so every ACK can report its hold time."""
    keepalive_interval: float = 0.25
    """Send a KEEPALIVE after this long with nothing else sent."""
    idle_timeout: float = 2.0
    """The connection is lost after this long without any datagram from the peer."""
    open_retry_interval: float = 0.25
    """The master repeats its OPEN this often until it is answered."""
    open_timeout: float = 5.0
    """The master gives up opening after this long."""
    initial_rtt: float = 0.1
    """RTT assumed until the first sample (loss timeout, controllers)."""
    reorder_threshold: int = 3
    """A packet is lost once a packet this many sequence numbers later is acknowledged."""
    deliver_late: bool = False
    """Deliver packets that arrive after a newer one (reordered). Stale samples are dropped by default."""
    deliver_duplicates: bool = False
    """Deliver a second copy of a packet. Dropped by default."""
    max_pending_events: int = 4096
    """Events held for the application; when full the oldest data event is discarded and counted."""
    max_tracked_packets: int = 16384
    """Sent packets remembered while awaiting acknowledgement; the oldest is declared lost past this."""
    controller: str = "trinomial"
    """Rate controller by registry name: ``trinomial``, ``tfrc`` or ``fixed``."""
    controller_config: object | None = None
    """The chosen controller's own config dataclass (``None`` = its defaults)."""

    def __post_init__(self) -> None:
        _require(
            isinstance(self.max_payload, int)
            and 0 < self.max_payload <= MAX_UDP_PAYLOAD - HEADER_SIZE,
            f"max_payload must be an integer in 1..{MAX_UDP_PAYLOAD - HEADER_SIZE}, "
            f"got {self.max_payload!r}",
        )
        _require(
            isinstance(self.ack_mode, AckMode),
            f"ack_mode must be an AckMode, got {self.ack_mode!r}",
        )
        _require(
            isinstance(self.ack_size, int)
            and HEADER_SIZE <= self.ack_size <= HEADER_SIZE + self.max_payload,
            f"ack_size must be an integer in {HEADER_SIZE}..{HEADER_SIZE + self.max_payload} "
            f"(header plus at most max_payload of padding), got {self.ack_size!r}",
        )
        _require(
            isinstance(self.plain_acks, bool),
            f"plain_acks must be True or False, got {self.plain_acks!r}",
        )
        _positive_finite("ack_delay", self.ack_delay)
        _require(
            self.ack_delay <= HOLD_MAX,
            f"ack_delay must be at most {HOLD_MAX * 1000:.3f} ms so that every ACK can carry its "
            f"hold time, got {self.ack_delay * 1000:.3f} ms",
        )
        for name in ("keepalive_interval", "idle_timeout", "open_retry_interval", "open_timeout"):
            _positive_finite(name, getattr(self, name))
        _positive_finite("initial_rtt", self.initial_rtt)
        _require(
            self.keepalive_interval < self.idle_timeout,
            f"keepalive_interval ({self.keepalive_interval} s) must be shorter than idle_timeout "
            f"({self.idle_timeout} s), or a quiet but healthy peer would time out",
        )
        _require(
            isinstance(self.reorder_threshold, int) and 1 <= self.reorder_threshold <= 6,
            f"reorder_threshold must be an integer in 1..6 (the SACK field covers 6 packets), "
            f"got {self.reorder_threshold!r}",
        )
        _require(
            isinstance(self.max_pending_events, int) and self.max_pending_events >= 1,
            f"max_pending_events must be a positive integer, got {self.max_pending_events!r}",
        )
        _require(
            isinstance(self.max_tracked_packets, int) and self.max_tracked_packets >= 64,
            f"max_tracked_packets must be an integer >= 64, got {self.max_tracked_packets!r}",
        )
        _require(
            isinstance(self.controller, str) and bool(self.controller),
            f"controller must be a registry name such as 'trinomial', got {self.controller!r}",
        )
