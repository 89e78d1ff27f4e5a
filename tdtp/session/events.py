"""What a connection reports to its application, one frozen dataclass per kind of event."""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, cast

from mypy_extensions import mypyc_attr

from tdtp._extensions import load_extension
from tdtp.wire.address import Address as Address  # noqa: PLC0414 - its old home, re-exported


class CloseCause(enum.Enum):
    """Why a connection ended: the ``cause`` of :class:`ConnectionClosed` and of
    :class:`~tdtp.errors.ConnectionClosedError`."""

    LOCAL_CLOSE = "local_close"
    """This side called :meth:`~tdtp.session.connection.Connection.close`."""
    PEER_CLOSE = "peer_close"
    """The peer sent CLOSE."""
    IDLE_TIMEOUT = "idle_timeout"
    """Nothing arrived from the peer for ``idle_timeout`` (30 s by default): the outage lasted longer
    than the connection is configured to survive, or the peer is gone."""
    OPEN_TIMEOUT = "open_timeout"
    """The master's OPEN was never answered."""
    REJECTED = "rejected"
    """The slave refused the OPEN (busy, unknown key, unsupported version, ...): the detail says why."""
    REPLACED = "replaced"
    """The same master opened a new connection (it restarted): this older one is over."""
    KEY_EXHAUSTED = "key_exhausted"
    """A keyed session protected as many packets as its keys may (or saw too many forgeries)."""
    PEER_RESTARTED = "peer_restarted"
    """The slave answered with a RESET: it holds no session for us (it restarted). Open a new
    connection (``tdtp.connect(..., reconnect=...)`` does)."""
    PEER_RESTARTING = "peer_restarting"
    """The peer closed with CLOSE ``RESTARTING``: it is stopping but expects to be back soon (a
    service restart). A master with ``reconnect=`` opens a new session at once."""
    EVICTED = "evicted"
    """A full server gave this session's slot to another master: its master had been silent for
    the server's reclaim time (``AdmissionConfig.reclaim_after``, 10 s), or the same master (same
    key) opened from another address while it was silent (docs/PROTOCOL.md 5.1, rule 2.7). The
    slave's side ends with this cause, and so does the master's when it hears the CLOSE
    ``EVICTED``; a master with ``reconnect=`` reopens after a back-off."""
    TAKEN_OVER = "taken_over"
    """An exclusive slave handed control to another master (this one was silent, or the other
    asked with ``takeover=True``); the slave's side ends with this cause, the master's with
    ``peer_close`` and the detail ``taken_over``."""


@mypyc_attr(native_class=False)  # a plain frozen dataclass: pickled and copied as one
@dataclass(frozen=True, slots=True)
class ConnectionEstablished:
    """The opening handshake completed: samples may flow to and from :attr:`peer`."""

    peer: Address


@mypyc_attr(native_class=False)  # a plain frozen dataclass in both builds (see _constructor)
@dataclass(frozen=True, slots=True)
class DataReceived:
    """One supermedia sample from the peer.

    **How old is it?** TDTP carries no timestamp (the header is 5 bytes), and the two ends' clocks are
    not synchronised. But a sample whose header acknowledges one of our own packets is timed by it
    (docs/PROTOCOL.md section 3.6): we know when we sent that packet, and HOLD says how long the peer
    held it before this sample left, so the sample and our packet make one round trip ``R`` that
    lies wholly between our send and this arrival. Its send time, on our clock, is
    :attr:`sent_at`: the arrival minus ``R / 2``, wrong by at most ``(R - min_rtt) / 2`` on a path
    whose two directions have the same base delay. :attr:`age` is its age at arrival. A sample
    without a usable acknowledgement (the peer has received nothing of ours, or held it for over
    31.7 ms, or a separate-ACK session) has no :attr:`sent_at`; its :attr:`age` is then the path's
    :attr:`estimated_age`. :meth:`age_at` adds the time the sample has waited since it arrived.
    Where the exact age matters, put a timestamp in the payload and synchronise the clocks (PTP,
    NTP), as the ``tdtp demo`` samples do.
    """

    payload: bytes
    seq: int
    """The sample's full (unwrapped) sequence number on this connection."""
    estimated_age: float | None
    """The path's estimate of a sample's age when it arrived: half the smoothed RTT (the path is
    assumed symmetric), or half the opening handshake's round trip while this side has no RTT
    sample (the receiving end of a one-way stream never gets one). ``None`` before either exists."""
    received_at: float
    """The ``now`` it was delivered at: its arrival, or the end of its reorder wait."""
    sent_at: float | None = None
    """When the peer sent it, on this side's clock (the clock of ``received_at``), from the
    acknowledgement its own header carries; ``None`` when the header carries none that times it."""

    @property
    def age(self) -> float | None:
        """Its age in seconds when it arrived: ``received_at - sent_at`` when the sample is timed,
        else :attr:`estimated_age`."""
        sent_at = self.sent_at
        return self.estimated_age if sent_at is None else self.received_at - sent_at

    def age_at(self, now: float) -> float | None:
        """The estimated age at ``now`` (same clock as ``received_at``, e.g. :func:`tdtp.monotonic`):
        :attr:`age` plus the time since arrival; ``None`` when no estimate exists yet."""
        age = self.age
        return None if age is None else age + (now - self.received_at)


def _constructor() -> Callable[[bytes, int, float | None, float, float | None], DataReceived]:
    """A :class:`DataReceived` without the frozen dataclass's ``__init__``, which sets each field
    through ``object.__setattr__``: the same object (equal, hashed and printed alike) for a fraction
    of the cost. One per sample received, in both builds (the class stays a plain Python class when
    compiled, so that it remains a frozen dataclass).

    Where the C extension ``tdtp/session/_slot_filler.c`` is built (beside the compiled core), it
    stores the five values straight into the slots: about 3,000 instructions less per sample than
    Python can do it, on the path from a datagram to the application's callback. Elsewhere (the
    pure build, no compiler) :func:`python_constructor`. The same object either way
    (tests/test_events_are_values.py checks both)."""
    filler, _why_not = load_extension("tdtp.session._slot_filler", _FILLER_SOURCE)
    if filler is not None:
        return cast(
            "Callable[[bytes, int, float | None, float, float | None], DataReceived]",
            filler.SlotFiller(DataReceived, DATA_RECEIVED_FIELDS),
        )
    return python_constructor()


DATA_RECEIVED_FIELDS: Final = ("payload", "seq", "estimated_age", "received_at", "sent_at")
""":class:`DataReceived`'s fields in the order its constructors take them."""
_FILLER_SOURCE: Final = Path(__file__).with_name("_slot_filler.c")


def python_constructor() -> Callable[[bytes, int, float | None, float, float | None], DataReceived]:
    """:func:`new_data_received` in Python: the fields are stored into an instance of a plain class
    with the same slots (plain attribute stores, which cost less than calling each slot's
    descriptor), whose class is then set to :class:`DataReceived` (allowed: the two layouts are the
    same), so that it is frozen from then on."""
    new = object.__new__
    builder = _builder_class()

    def construct(
        payload: bytes,
        seq: int,
        estimated_age: float | None,
        received_at: float,
        sent_at: float | None,
    ) -> DataReceived:
        event: Any = new(builder)
        event.payload = payload
        event.seq = seq
        event.estimated_age = estimated_age
        event.received_at = received_at
        event.sent_at = sent_at
        event.__class__ = DataReceived
        made: DataReceived = event
        return made

    return construct


def _builder_class() -> type:
    """A plain class laid out as :class:`DataReceived` (its slots, no others), not frozen."""
    return type("_DataReceivedBuilder", (), {"__slots__": DataReceived.__slots__})


new_data_received: Final = _constructor()
"""``DataReceived(payload, seq, estimated_age, received_at, sent_at)``, the connection's per-sample
way."""


@mypyc_attr(native_class=False)  # a plain frozen dataclass: pickled and copied as one
@dataclass(frozen=True, slots=True)
class ConnectionClosed:
    """The connection ended: why (:attr:`cause`) and, in words a user can act on, :attr:`detail`."""

    cause: CloseCause
    detail: str
    reason: int | None = None
    """The CLOSE or REJECT reason code (``tdtp.wire.CloseReason``, or a number this side does not
    know) behind this ending: the one the peer sent, or the one this side sent it; ``None`` when no
    CLOSE or REJECT said anything (a RESET, an open timeout, a process that vanished)."""


@mypyc_attr(native_class=False)  # a plain frozen dataclass: pickled and copied as one
@dataclass(frozen=True, slots=True)
class PeerSilent:
    """The watchdog: nothing has arrived from the peer for ``silence_timeout``.

    The connection is still open and survives the outage up to ``idle_timeout``; a slave would hold or
    stop the machine its master drives until :class:`PeerResumed` follows.
    """

    since: float
    """The ``now`` of the last datagram heard from the peer."""
    detected_at: float
    """The ``now`` the silence was noticed (``since + silence_timeout``, or later if the timer ran
    late)."""


@mypyc_attr(native_class=False)  # a plain frozen dataclass: pickled and copied as one
@dataclass(frozen=True, slots=True)
class PeerResumed:
    """The peer is heard again after a :class:`PeerSilent`."""

    silent_for: float
    """Seconds from the last datagram before the silence to the one that ended it."""
    resumed_at: float
    """The ``now`` the first datagram after the silence arrived."""


@mypyc_attr(native_class=False)  # a plain frozen dataclass: pickled and copied as one
@dataclass(frozen=True, slots=True)
class ControlReceived:
    """One message of the peer's reliable control channel (``send_control`` on its side): each is
    delivered exactly once, in the order it was sent, however the network lost, duplicated or
    reordered it (docs/PROTOCOL.md section 5.10)."""

    payload: bytes
    index: int
    """The message's place in the peer's sequence: 0 for its first control message, then 1, 2, ..."""
    received_at: float
    """The ``now`` it was delivered at (when the messages before it had all arrived)."""


@mypyc_attr(native_class=False)  # a plain frozen dataclass: pickled and copied as one
@dataclass(frozen=True, slots=True)
class ControlExpired:
    """Control messages the peer never acknowledged within ``control_timeout`` were given up: the
    oldest unacknowledged one and every one after it (in-order delivery cannot skip a message).
    The peer may have received some of them (their acknowledgements may be what was lost); the
    channel takes no more messages (``ControlChannelFailedError``)."""

    first_index: int
    """Our index (0 = our first control message) of the oldest message given up."""
    payloads: tuple[bytes, ...]
    """The messages given up, oldest first."""
    detail: str
    expired_at: float


@mypyc_attr(native_class=False)  # a plain frozen dataclass: pickled and copied as one
@dataclass(frozen=True, slots=True)
class PathChanged:
    """Multipath: one of the session's paths came, went or degraded (docs/PROTOCOL.md 5.11).

    The session survives any path's failure as long as one path works; the watchdog
    (:class:`PeerSilent`) still speaks for the whole session. ``ep.paths`` has each path's figures."""

    path_id: int
    """The path's number in the session (0: the path the session opened on)."""
    state: str
    """What it is now: ``"active"`` (validated and carrying traffic), ``"degraded"`` (its recent
    one-way delay or loss is out of bounds), ``"failed"`` (nothing heard on it for the path
    timeout; it is probed until it answers), ``"closed"`` (abandoned by either side or refused)."""
    previous: str
    """What it was before (``"probing"`` for a path just validated)."""
    remote: Address
    """The peer's address on the path."""
    detail: str
    """In words: why it changed."""
    at: float
    """The ``now`` it changed."""


Event = (
    ConnectionEstablished
    | DataReceived
    | ConnectionClosed
    | PeerSilent
    | PeerResumed
    | ControlReceived
    | ControlExpired
    | PathChanged
)
