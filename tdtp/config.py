"""Connection configuration: one validated, immutable dataclass."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Literal

from tdtp.control.registry import available_controllers, controller_config_type
from tdtp.errors import InvalidArgumentError
from tdtp.wire.control import CipherSuite
from tdtp.wire.header import HEADER_SIZE
from tdtp.wire.hold import HOLD_MAX
from tdtp.wire.protected import PROTECTION_OVERHEAD

MAX_UDP_PAYLOAD = 65507
"""Largest UDP payload over IPv4."""
MAX_PAYLOAD = MAX_UDP_PAYLOAD - HEADER_SIZE - PROTECTION_OVERHEAD
"""The largest TDTP payload: what fits in one UDP/IPv4 datagram with the header and, in a keyed
session, the packet protection (65484 bytes)."""

ControllerName = Literal["teleop", "trinomial", "tfrc", "fixed"]
"""The built-in rate controllers. A controller added with
:func:`tdtp.control.register_controller` is accepted too (type checkers then need a ``cast``)."""

MAX_CONTROL_MESSAGE = 4096
"""The largest ``control_max_message``: the control channel carries small messages (commands, mode
changes), not bulk data; a message travels in one datagram, retransmitted whole."""
MAX_CONTROL_WINDOW = 4096
"""The largest ``control_window``: far below the 32768 that 16-bit message numbers can tell apart."""

KEEPALIVE_PER_SILENCE = 3
"""With ``keepalive_interval`` left to its default, a quiet peer sends this many keep-alives per
``silence_timeout``: one lost keep-alive never makes a healthy peer look silent."""
MAX_REORDER_WAIT = 1.0
"""The longest reorder wait a connection accepts (s): beyond it a sample is no longer real-time."""
RECLAIM_SILENCES = 10
"""``AdmissionConfig.reclaim_after`` is at least this many watchdog periods (``silence_timeout``):
a slot is reclaimed from a master that is gone, never from one the watchdog saw hiccup."""


class Role(enum.Enum):
    """Which end of a session a connection is: the master commands, the slave obeys. By default the
    master dials (sends the OPEN) and the slave listens; either may dial (``dials=``,
    ``tdtp.connect(role=...)``, ``tdtp.listen(role=...)``)."""

    MASTER = "master"
    """The operator's side (joystick, haptic device)."""
    SLAVE = "slave"
    """The remote robot or crane."""


class AckMode(enum.Enum):
    """How acknowledgements travel: piggybacked on reverse samples (TDTP), or one ACK per packet."""

    BIDIRECTIONAL = "bidirectional"
    """TDTP: acknowledgements ride in the reverse data packets."""
    SEPARATE = "separate"
    """Trinomial: one stand-alone ACK packet per received data packet (the paper's comparison)."""


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise InvalidArgumentError(message)


def _positive_finite(name: str, value: float, unit: str = "of seconds") -> None:
    _require(
        isinstance(value, int | float) and math.isfinite(value) and value > 0,
        f"{name} must be a positive number {unit}, got {value!r}",
    )


@dataclass(frozen=True, slots=True)
class AdmissionConfig:
    """How a slave treats OPENs before any session exists (``tdtp.admission``)."""

    cookie_lifetime: float = 5.0
    """Seconds an address-validation cookie stays valid: longer than any RTT a master may have,
    short enough to bound how long a captured OPEN can be replayed from the master's address."""
    opens_per_source: float = 20.0
    """OPENs without a valid cookie per second one source address (host and port) may send (a master
    retries every 0.25 s); an OPEN with a valid cookie is not counted."""
    open_burst: int = 40
    """OPENs a source may send at once before its rate applies."""
    max_sources: int = 4096
    """Source addresses whose OPEN rate is tracked (least recently seen forgotten first)."""
    replies_per_second: float = 20_000.0
    """COOKIE and version-REJECT replies per second to unvalidated sources, all together: bounds the
    CPU a flood of OPENs from forged addresses costs (each reply is never larger than its OPEN).
    PATH_CHALLENGEs (path migration) draw from the same budget."""
    resets_per_second: float = 1000.0
    """RESETs per second, all sources together, answering session datagrams from addresses without a
    session (a restarted slave hearing its old masters): a budget of its own, so that a flood of them
    cannot starve the COOKIEs a reconnecting master needs, and bounded so that it caps the CPU (one
    HMAC per key that fits, keyed) and the bytes (never more than what arrived) a flood can cost."""
    migration_trials_per_second: float = 2_000.0
    """Keyed path migration: trial authentications per second, all together, of datagrams from
    unknown addresses against sessions whose master is quiet. Bounds the CPU a flood from unknown
    addresses costs (one AEAD check each; past the budget they are dropped and counted)."""
    migration_quiet: float = 0.005
    """A session is a candidate for path migration once nothing has come from its master's address
    for this long (a master sends at least once per keep-alive interval)."""
    reclaim_after: float = 10.0
    """A full slave gives a session's slot to a new master only once nothing has been heard from
    that session's master for this long: its master is gone, not hiccuping (docs/PROTOCOL.md 5.1,
    rule 2.7). Far longer than any Wi-Fi hiccup, GC pause or handover the watchdog reports (it must
    be at least ``RECLAIM_SILENCES`` x ``silence_timeout``), shorter than ``idle_timeout`` (30 s)
    so that a vanished master's slot frees sooner when another master needs it."""
    source_share: float = 0.5
    """The share of ``max_peers`` one source may hold (``floor(share x max_peers)``, at least one
    slot): an IPv4 address, the /64 of a global IPv6 address; loopback is exempt
    (:mod:`tdtp.admission.slots`). 0.5: no source ever holds most of a slave's slots; 1.0: no
    bound."""

    def __post_init__(self) -> None:
        _positive_finite("cookie_lifetime", self.cookie_lifetime)
        _positive_finite("migration_quiet", self.migration_quiet)
        _positive_finite("reclaim_after", self.reclaim_after)
        _require(
            isinstance(self.source_share, int | float)
            and not isinstance(self.source_share, bool)
            and 0.0 < self.source_share <= 1.0,
            f"source_share must be a fraction of max_peers in (0, 1], got {self.source_share!r}",
        )
        for name in (
            "opens_per_source",
            "replies_per_second",
            "resets_per_second",
            "migration_trials_per_second",
        ):
            _positive_finite(name, getattr(self, name), "per second")
        for name in ("open_burst", "max_sources"):
            value = getattr(self, name)
            _require(
                isinstance(value, int) and value >= 1,
                f"{name} must be a positive integer, got {value!r}",
            )


MultipathScheduler = Literal["redundant", "adaptive"]
"""How a multipath session spreads its samples over its paths (docs/PROTOCOL.md 5.11)."""
MAX_PATHS = 16
"""The most paths ``MultipathConfig.max_paths`` may allow one session (path ids are one byte)."""


@dataclass(frozen=True, slots=True)
class MultipathConfig:
    """One session over several paths at once (docs/PROTOCOL.md 5.11, docs/CONTROL.md 11).

    A master with this in its config opens a multipath session (the OPEN's MULTIPATH flag) and may
    add paths from further local addresses; a slave follows the master's choice with its own
    ``multipath`` config, or these defaults when it has none."""

    scheduler: MultipathScheduler = "redundant"
    """``"redundant"``: every sample on every live path, the first copy wins. ``"adaptive"``: the
    best path alone while its recent one-way delay and loss stay within ``delay_bound`` and
    ``loss_bound`` (and its samples are acknowledged in time), every live path while they do not."""
    max_paths: int = 4
    """Paths one session may have at once, the one it opened on included (1 refuses every further
    path: ``MP_ABANDON`` with PATH_LIMIT). A peer cannot make the table grow beyond it."""
    new_paths_per_second: float = 10.0
    """New paths a session takes per second from its peer (a burst of ``max_paths``): a flood of
    challenges from new addresses costs no more."""
    probe_interval: float = 0.02
    """A validated path that carried nothing of ours for this long gets an MP_CHALLENGE: its
    keep-alive and round-trip probe."""
    failed_probe_interval: float = 0.2
    """A failed path (or one not validated yet) is challenged this often until it answers."""
    path_timeout: float = 0.06
    """A path is failed once nothing has arrived on it for this long (or for two probe intervals
    and three of its round trips, if that is longer)."""
    validation_timeout: float = 3.0
    """A path the peer opened that does not answer our challenge within this long is forgotten."""
    report_interval: float = 0.01
    """A path on which the peer's data arrives gets an MP_REPORT this often (its RTT, loss and
    first copies, for the peer's scheduler and congestion control)."""
    delay_bound: float = 0.015
    """Adaptive: the best path carries the samples alone while its recent one-way delay stays
    within this of the lowest it has shown (seconds)."""
    loss_bound: float = 0.01
    """Adaptive: ... and its recent loss stays at or below this fraction."""
    adaptive_hold: float = 0.05
    """Adaptive: once the best path broke a bound (or its acknowledgements have been overdue this
    much longer than usual), every live path carries the samples until it has kept within them
    this long (seconds)."""

    def __post_init__(self) -> None:
        _require(
            self.scheduler in ("redundant", "adaptive"),
            f"scheduler must be 'redundant' or 'adaptive', got {self.scheduler!r}",
        )
        _require(
            isinstance(self.max_paths, int)
            and not isinstance(self.max_paths, bool)
            and 1 <= self.max_paths <= MAX_PATHS,
            f"max_paths must be an integer in 1..{MAX_PATHS}, got {self.max_paths!r}",
        )
        _positive_finite("new_paths_per_second", self.new_paths_per_second, "per second")
        for name in (
            "probe_interval",
            "failed_probe_interval",
            "path_timeout",
            "validation_timeout",
            "report_interval",
            "delay_bound",
            "adaptive_hold",
        ):
            _positive_finite(name, getattr(self, name))
        _require(
            isinstance(self.loss_bound, int | float)
            and not isinstance(self.loss_bound, bool)
            and 0.0 <= self.loss_bound < 1.0,
            f"loss_bound must be a fraction in 0..1 (0.01 = 1 %), got {self.loss_bound!r}",
        )
        _require(
            self.probe_interval < self.path_timeout,
            f"probe_interval ({self.probe_interval} s) must be shorter than path_timeout "
            f"({self.path_timeout} s), or an idle but healthy path would look failed",
        )


@dataclass(frozen=True, slots=True)
class ConnectionConfig:
    """Everything a :class:`~tdtp.session.connection.Connection` can be told. Times are in seconds."""

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
    silence_timeout: float = 0.1
    """The watchdog: after this long without any datagram from the peer the connection reports
    :class:`~tdtp.session.events.PeerSilent` (and :class:`~tdtp.session.events.PeerResumed` when the peer is heard
    again). 100 ms is five times a 1 kHz loop's worst normal gap and short enough for a slave to stop
    a machine safely; it must be shorter than ``idle_timeout``."""
    keepalive_interval: float | None = None
    """Send a KEEPALIVE after this long with nothing else sent. ``None`` (the default): a third of
    ``silence_timeout``, so that a healthy but quiet peer is never taken for a silent one. Set it
    explicitly below the *peer's* ``silence_timeout``; it is not negotiated."""
    idle_timeout: float = 30.0
    """The outage limit: the connection is given up after this long without any datagram from the
    peer. Until then it survives the outage and recovers by itself (roaming, handovers and route
    changes last seconds); the watchdog (``silence_timeout``) is what tells the application early."""
    open_retry_interval: float = 0.25
    """The master repeats its OPEN this often until it is answered."""
    open_timeout: float = 5.0
    """The master gives up opening after this long."""
    initial_rtt: float = 0.1
    """RTT assumed until the first sample (loss timeout, controllers)."""
    reorder_threshold: int = 3
    """A packet is lost once a packet this many sequence numbers later is acknowledged, until the
    connection has seen reordering; from then on only the time-based reorder window declares losses
    (RFC 8985, docs/PROTOCOL.md section 5.4)."""
    max_reorder_wait: float = 0.02
    """Samples reach the application in sequence order: one that arrives after a gap waits, at most
    this long (seconds), for the gap to fill by reordering before the gap is given up as lost. The
    wait in force adapts to the reordering measured on the path and is zero while there is none, so
    a path that does not reorder adds no delay (docs/PROTOCOL.md section 5.5). ``0``: no wait; a sample
    that arrives after a newer one is dropped as late (the newest value only, the least delay)."""
    deliver_late: bool = False
    """Deliver every sample as it arrives, including those that arrive after a newer one, with no
    reorder wait (``max_reorder_wait`` is then unused). Off by default: the application would see its
    signal step backwards."""
    deliver_duplicates: bool = False
    """Deliver a second copy of a packet. Dropped by default."""
    max_pending_events: int = 4096
    """Events held for the application; when full the oldest data event is discarded and counted."""
    max_tracked_packets: int = 16384
    """Sent packets remembered while awaiting acknowledgement; the oldest is declared lost past this."""
    control_max_message: int = 256
    """The reliable control channel (``Connection.send_control``, docs/PROTOCOL.md 5.10): the
    largest message, in bytes, this side sends or accepts (a longer one arriving is dropped as
    ``oversized``). Not negotiated: set the same on both ends."""
    control_window: int = 64
    """Control messages not yet acknowledged by the peer that this side holds (queued or in
    flight): one more raises :class:`~tdtp.errors.ControlQueueFullError`. Also the receive bound:
    messages that arrived out of order plus those delivered but not yet read by the application."""
    control_max_rate: float = 200.0
    """Control MESSAGE datagrams per second this side may send, retransmissions included (a token
    bucket with a burst of 8): the channel's own cap beside the rate controller's."""
    control_timeout: float = 20.0
    """A control message the peer has not acknowledged this many seconds after ``send_control``
    is given up, with every message after it: a ``ControlExpired`` event, and the channel refuses
    further messages. Longer than the outages a session rides out (10 s), shorter than
    ``idle_timeout``'s default."""
    controller: ControllerName = "teleop"
    """Rate controller by registry name: ``teleop`` (the default: queue delay and loss, docs/CONTROL.md
    section 9), ``trinomial`` (the paper's), ``tfrc`` or ``fixed`` (or one registered with
    :func:`tdtp.control.register_controller`)."""
    controller_config: object | None = None
    """The chosen controller's own config dataclass (``None`` = its defaults), e.g.
    ``tdtp.control.FixedConfig(rate=500.0)`` for ``controller="fixed"``."""
    min_peer_payload: int = 1
    """The largest payload this side will send: a peer whose ``max_payload`` is smaller is refused at
    the open (REJECT ``PAYLOAD_TOO_SMALL``) instead of failing on the first ``send``."""
    cipher_suite: CipherSuite = CipherSuite.AES_128_GCM
    """Keyed sessions: the AEAD the master asks for (the slave accepts any suite it implements)."""
    encrypt: bool = True
    """Keyed sessions: encrypt payloads (otherwise they are authenticated but readable). The master
    chooses; the slave adopts its choice."""
    takeover: bool = False
    """Keyed master: ask an exclusive slave (``listen(exclusive=True)``) to hand control to this
    master at once, ending the session of the master that has it (the OPEN's TAKEOVER flag;
    docs/PROTOCOL.md 5.9). Ignored by an unkeyed master: anyone could send it."""
    timestamp_interval: float = 0.004
    """A master whose rate controller judges one-way delays (``teleop``) opens its sessions with
    the TIMESTAMPS flag: both ends then stamp their send time on a packet at most this often, so
    that each measures the queue of its own direction and the true one-way age of a sample on an
    asymmetric path (docs/PROTOCOL.md 5.13; 5 bytes on about one packet in four at 1 kHz). ``0``:
    no stamps (controllers judge by round trips, ages are half of one). A slave follows its master
    (with 0 of its own it stamps every 4 ms); a multipath session never stamps."""
    admission: AdmissionConfig = field(default_factory=AdmissionConfig)
    """A slave's policy for OPENs: cookies and rate limits."""
    multipath: MultipathConfig | None = None
    """A master: open a multipath session (docs/PROTOCOL.md 5.11) with this scheduling and these
    limits; ``None``: one path. A slave follows its master's choice, with this config (or the
    defaults of :class:`MultipathConfig` when ``None``). ``tdtp.connect(...,
    local_addresses=[...])`` sets it."""

    @property
    def effective_keepalive_interval(self) -> float:
        """``keepalive_interval``, or a third of ``silence_timeout`` when it is left to ``None``."""
        if self.keepalive_interval is not None:
            return self.keepalive_interval
        return self.silence_timeout / KEEPALIVE_PER_SILENCE

    def __post_init__(self) -> None:
        _require(
            isinstance(self.max_payload, int) and 0 < self.max_payload <= MAX_PAYLOAD,
            f"max_payload must be an integer in 1..{MAX_PAYLOAD}, got {self.max_payload!r}",
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
        for name in ("silence_timeout", "idle_timeout", "open_retry_interval", "open_timeout"):
            _positive_finite(name, getattr(self, name))
        if self.keepalive_interval is not None:
            _positive_finite("keepalive_interval", self.keepalive_interval)
        _positive_finite("initial_rtt", self.initial_rtt)
        _require(
            isinstance(self.max_reorder_wait, int | float)
            and not isinstance(self.max_reorder_wait, bool)
            and 0.0 <= self.max_reorder_wait <= MAX_REORDER_WAIT,
            f"max_reorder_wait must be a number of seconds in 0..{MAX_REORDER_WAIT:g} (0 = drop "
            f"samples that arrive after a newer one), got {self.max_reorder_wait!r}",
        )
        _require(
            self.silence_timeout < self.idle_timeout,
            f"silence_timeout ({self.silence_timeout} s) must be shorter than idle_timeout "
            f"({self.idle_timeout} s): the watchdog warns of a silence, the idle timeout ends it",
        )
        _require(
            self.effective_keepalive_interval < self.silence_timeout,
            f"keepalive_interval ({self.keepalive_interval} s) must be shorter than "
            f"silence_timeout ({self.silence_timeout} s), or a quiet but healthy peer would look "
            "silent; leave it to None for a third of silence_timeout",
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
            isinstance(self.control_max_message, int)
            and 1 <= self.control_max_message <= MAX_CONTROL_MESSAGE,
            f"control_max_message must be an integer in 1..{MAX_CONTROL_MESSAGE} (bytes), "
            f"got {self.control_max_message!r}",
        )
        _require(
            isinstance(self.control_window, int) and 1 <= self.control_window <= MAX_CONTROL_WINDOW,
            f"control_window must be an integer in 1..{MAX_CONTROL_WINDOW} (messages), "
            f"got {self.control_window!r}",
        )
        _require(
            isinstance(self.timestamp_interval, int | float)
            and not isinstance(self.timestamp_interval, bool)
            and 0.0 <= self.timestamp_interval <= 1.0,
            f"timestamp_interval must be a number of seconds in 0..1 (0 = no timestamps), "
            f"got {self.timestamp_interval!r}",
        )
        _positive_finite("control_max_rate", self.control_max_rate, "per second")
        _positive_finite("control_timeout", self.control_timeout)
        config_type = controller_config_type(self.controller)
        if config_type is None:
            raise InvalidArgumentError(
                f"unknown controller {self.controller!r}; known controllers: "
                f"{', '.join(available_controllers())}"
            )
        _require(
            isinstance(self.min_peer_payload, int)
            and 1 <= self.min_peer_payload <= self.max_payload,
            f"min_peer_payload must be an integer in 1..max_payload ({self.max_payload}), "
            f"got {self.min_peer_payload!r}",
        )
        _require(
            isinstance(self.cipher_suite, CipherSuite)
            and self.cipher_suite is not CipherSuite.NONE,
            f"cipher_suite must be CipherSuite.AES_128_GCM or CHACHA20_POLY1305, "
            f"got {self.cipher_suite!r}",
        )
        _require(isinstance(self.encrypt, bool), f"encrypt must be a bool, got {self.encrypt!r}")
        _require(isinstance(self.takeover, bool), f"takeover must be a bool, got {self.takeover!r}")
        _require(
            isinstance(self.admission, AdmissionConfig),
            f"admission must be an AdmissionConfig, got {self.admission!r}",
        )
        _require(
            self.admission.reclaim_after >= RECLAIM_SILENCES * self.silence_timeout,
            f"admission.reclaim_after ({self.admission.reclaim_after:g} s) must be at least "
            f"{RECLAIM_SILENCES} x silence_timeout ({self.silence_timeout:g} s): a slot goes to "
            "another master only once its master is gone, never after a hiccup the watchdog "
            "reports; raise reclaim_after (AdmissionConfig(reclaim_after=...))",
        )
        _require(
            self.multipath is None or isinstance(self.multipath, MultipathConfig),
            f"multipath must be a MultipathConfig or None, got {self.multipath!r}",
        )
        _require(
            self.controller_config is None or isinstance(self.controller_config, config_type),
            f"controller {self.controller!r} is configured by {config_type.__name__}, got "
            f"{type(self.controller_config).__name__}; pass None for its defaults",
        )
