"""One-way delays: each direction's own queue, from send times the two ends stamp on a share of packets.

A round trip is the sum of two one-way delays, and a queue in either direction lifts it: judged from the
round trip alone, a bottleneck on the way back slows the way out, and half the round trip is the wrong
age for a sample that crossed an asymmetric path. In a session opened with the TIMESTAMPS flag both
ends therefore stamp their clock on a share of their packets (TIMED_DATA carries a sample, TIMESTAMP
a stand-alone acknowledgement: docs/PROTOCOL.md 5.13), at most one per ``timestamp_interval``.

**What one stamp tells.** Let the peer stamp ``T`` (its clock) on a packet that left it when our packet
``s``, sent at ``t_s`` on our clock, had waited ``h`` there (the header's HOLD), and let it arrive here
at ``rx``. Then, with ``theta`` the unknown offset between the clocks,

* ``rx - T = d_in + theta``: the one-way delay of the peer's packet (the *inbound* direction);
* ``T - h - t_s = d_out - theta``: the one-way delay of our packet ``s`` (the *outbound* direction),
  which the round trip ``echo = now - t_s - h`` gives as ``echo - (now - T)``.

Each is the delay plus a constant, so its minimum over a window (``base_window``, two half-windows as
the controller's base RTT) is the path's base plus that constant, and the difference is the queue in
that direction alone: LEDBAT's base delay (RFC 6817), without synchronised clocks. A drift between the
clocks moves the base by the drift times the window (1 ms over 10 s at 100 ppm), which bounds the
error. The sum of the two bases is the smallest round trip, and without synchronised clocks nothing
tells how it splits: we take half of it as each direction's base, as NTP does.

**Who uses it.** The rate controller gets every outbound sample (``on_one_way_delay``): the queue of
its own direction, and the peer's clock of arrival, which times what the link delivered. The sample
age takes the inbound delay: exact for a stamped sample (its base half plus its own queue), and for
the others the round trip less the outbound delay estimated now (docs/PROTOCOL.md 3.6).

**Bad input.** A forged or corrupted stamp could set a base far below the truth and make every later
sample read as a queue. For any real stamp ``d_in`` and ``d_out`` are at least zero and at most the
round trip, which bounds how far from the bases a sample can be; a stamp outside those bounds is
not used (counted in ``stamps_rejected``), and after ``RESET_AFTER`` such stamps in a row the bases
start over (the peer's clock, not the stamps, changed).
"""

from __future__ import annotations

import math
from typing import Final

from tdtp.config import ConnectionConfig
from tdtp.control.base import RateController
from tdtp.control.registry import judges_one_way_delay
from tdtp.session.recovery import LossRecovery
from tdtp.session.stats import ConnectionStats, DropReason
from tdtp.wire.control import STAMP_CODES, STAMP_MODULUS, STAMP_SIZE, ControlCode
from tdtp.wire.header import HEADER_SIZE
from tdtp.wire.hold import HOLD_SATURATED

_WRAP_HALF: Final = STAMP_MODULUS // 2
_TIMESTAMP: Final = int(ControlCode.TIMESTAMP)
TIMED: Final = int(ControlCode.TIMED_DATA)
__all__ = [
    "STAMP_CODES",
    "STAMP_SIZE",
    "TIMED",
    "OneWayDelay",
    "PeerClock",
    "WindowMin",
    "wants_timestamps",
]
DEFAULT_INTERVAL: Final = 0.004
"""Seconds between stamps of an end whose ``timestamp_interval`` is 0 in a session with stamps."""
BASE_WINDOW: Final = 10.0
"""Seconds over which each direction's smallest delay is its base (the teleop controller's
``base_window``)."""
TOLERANCE: Final = 0.002
"""Seconds a sample may lie beyond the bounds a real stamp respects (HOLD's rounding, drift)."""
RESET_AFTER: Final = 64
"""Stamps rejected in a row after which the bases start over."""
QUEUE_GAIN: Final = 0.125
"""Gain of the moving averages of each direction's queue (what ``stats`` shows)."""


def wants_timestamps(config: ConnectionConfig) -> bool:
    """Whether a master with this config opens with the TIMESTAMPS flag: its controller reads
    one-way delays and ``timestamp_interval`` is not 0."""
    return config.timestamp_interval > 0.0 and judges_one_way_delay(config.controller)


class WindowMin:
    """The smallest value of the last ``window`` seconds, roughly: the minimum of two half-windows,
    the older of which expires as a whole."""

    __slots__ = ("_half", "_new", "_old", "_since")

    def __init__(self, window: float) -> None:
        self._half = 0.5 * window
        self._new = math.inf
        self._old = math.inf
        self._since = -math.inf

    @property
    def value(self) -> float:
        new = self._new
        old = self._old
        return new if new < old else old

    def add(self, now: float, value: float) -> None:
        if now - self._since >= self._half:
            self._old = self._new
            self._new = math.inf
            self._since = now
        if value < self._new:
            self._new = value

    def reset(self) -> None:
        self._new = self._old = math.inf
        self._since = -math.inf


class PeerClock:
    """The peer's clock as its stamps carry it (microseconds, low 32 bits) on one scale: seconds
    since its first stamp, each stamp read against the newest before it as a step of less than half
    the wrap, forward or (a stamp overtaken on the way, or on a faster path) back. Send timestamps
    (section 5.13) and multipath reports (section 5.11) read it alike."""

    __slots__ = ("_last_raw", "_seconds")

    def __init__(self) -> None:
        self._last_raw = -1
        self._seconds = 0.0

    def read(self, raw: int) -> float:
        """The stamp ``raw`` on the unwrapped scale."""
        last = self._last_raw
        if last < 0:
            self._last_raw = raw
            return 0.0
        step = (raw - last) & (STAMP_MODULUS - 1)
        if step >= _WRAP_HALF:
            step -= STAMP_MODULUS  # an older stamp, overtaken on the way
        seconds = self._seconds + step * 1e-6
        if step > 0:
            self._last_raw = raw
            self._seconds = seconds
        return seconds


class OneWayDelay:
    """Our stamps' schedule, and the peer's stamps read into each direction's base and queue."""

    __slots__ = (
        "_base_in",
        "_base_out",
        "_controller",
        "_interval",
        "_on_data",
        "_optimistic",
        "_peer_clock",
        "_recovery",
        "_rejected_run",
        "_rx",
        "_stamp_clock",
        "_stats",
        "_taken_with",
        "_timed",
        "data_due",
        "due",
        "enabled",
        "pending",
        "queue_in",
        "queue_out",
        "samples",
        "stamps_rejected",
    )

    def __init__(
        self,
        config: ConnectionConfig,
        controller: RateController,
        recovery: LossRecovery,
        stats: ConnectionStats,
    ) -> None:
        # A slave follows its master's choice; with 0 of its own it stamps at the default pace.
        self._interval = config.timestamp_interval or DEFAULT_INTERVAL
        self._controller = controller
        # A controller that reads one-way delays holds its rate through a silence of the peer
        # (the way back may be what failed): it waits for the watchdog's verdict first.
        controller.silence_timeout = config.silence_timeout
        self._recovery = recovery
        self._stats = stats
        self._taken_with = -1  # stats.datagrams_in when the pending stamp arrived
        self._timed = False  # the pending stamp came on a TIMED_DATA
        self._optimistic = 0  # stats.optimistic_acks when it arrived
        self.enabled = False
        """The session was opened with the TIMESTAMPS flag: both ends stamp."""
        self.due = math.inf
        """Our next stamp may leave from this time on (``inf`` while stamps are off)."""
        self.data_due = math.inf
        """...on a DATA (a TIMED_DATA): ``due``, or ``inf`` where only ACKs are stamped."""
        self._on_data = True
        self.pending = False
        """A peer stamp taken (:meth:`take`) and not yet read (:meth:`sent_at`, :meth:`settle`)."""
        self._peer_clock = PeerClock()
        self._stamp_clock = 0.0  # the pending stamp's, on the same scale
        self._rx = 0.0
        self._base_in = WindowMin(BASE_WINDOW)
        self._base_out = WindowMin(BASE_WINDOW)
        self._rejected_run = 0
        self.queue_in = 0.0
        """The peer's packets' queue on their way here, seconds (moving average)."""
        self.queue_out = 0.0
        """Our packets' queue on their way to the peer, seconds (moving average)."""
        self.samples = 0
        """Outbound samples taken (each a stamp that acknowledged one of our packets)."""
        self.stamps_rejected = 0
        """Peer stamps outside the bounds a real one respects (forged, corrupted, a clock jump)."""

    def start(self, now: float, flagged: bool, separate_acks: bool) -> None:
        """The session opened, with the TIMESTAMPS flag if ``flagged``: then stamps are on, and
        our first one may leave at once. With ``separate_acks`` only our ACKs carry them: a DATA
        there acknowledges nothing, and a stamp that times none of the peer's packets leaves its
        controller without news of its own direction (docs/PROTOCOL.md 5.13)."""
        if flagged:
            self.enabled = True
            self.due = now
            self._on_data = not separate_acks
            self.data_due = now if self._on_data else math.inf

    # ------------------------------------------------------------------ ours

    def stamp(self, now: float) -> int:
        """Our clock for a stamp leaving at ``now`` (microseconds, low 32 bits); the next one is
        due an interval later."""
        due = self.due = now + self._interval
        if self._on_data:
            self.data_due = due
        return int(now * 1e6) & (STAMP_MODULUS - 1)

    # ------------------------------------------------------------------ the peer's

    def take(self, data: bytes, rx: float | None, now: float) -> int:
        """A TIMESTAMP or TIMED_DATA arrived (at ``rx`` by the kernel's clock, if the driver read
        it, else ``now``): take its stamp, to be read once the datagram's acknowledgement has been
        taken (:meth:`sent_at`, :meth:`settle`; a datagram dropped before that leaves it unread).
        Returns its code, or 0, counting the drop, if the session has no stamps or a TIMESTAMP is
        of the wrong size."""
        stats = self._stats
        kind = data[HEADER_SIZE]
        if not self.enabled:
            stats.count_drop(DropReason.UNEXPECTED_CONTROL)
            return 0
        if kind == _TIMESTAMP and len(data) != HEADER_SIZE + STAMP_SIZE:
            stats.count_drop(DropReason.BAD_CONTROL)
            return 0
        raw = int.from_bytes(data[HEADER_SIZE + 1 : HEADER_SIZE + STAMP_SIZE], "big")
        self._stamp_clock = self._peer_clock.read(raw)
        self._rx = now if rx is None else rx
        self.pending = True
        self._taken_with = stats.datagrams_in
        self._timed = kind == TIMED
        self._optimistic = stats.optimistic_acks
        return kind

    def sent_at(self, echo: float | None, hold: int, now: float) -> float | None:
        """When the peer sent the sample that just arrived, on our clock: read from its own stamp
        when it had one, else from the round trip ``echo`` its header timed (``None`` if none);
        ``hold`` is the header's HOLD code."""
        if self.pending and self._taken_with == self._stats.datagrams_in:
            if self._timed:
                # The sample was taken in, counted without its stamp (the connection strips it).
                self._stats.received.bytes += STAMP_SIZE
            inbound = self._read(echo, hold, now)
            if inbound is not None:
                return now - inbound
        if echo is None:
            return None
        return now - self.inbound(echo)

    def settle(self, echo: float | None, hold: int, now: float) -> None:
        """Read a stamp taken with a datagram that carried no sample (TIMESTAMP)."""
        if self.pending and self._taken_with == self._stats.datagrams_in:
            self._read(echo, hold, now)

    def inbound(self, echo: float) -> float:
        """The inbound one-way delay of a sample whose header timed the round trip ``echo``: the
        round trip less our outbound delay as now estimated, never below either base half; half
        the round trip while the bases are unknown."""
        base_in = self._base_in.value
        base_out = self._base_out.value
        if base_in + base_out == math.inf:  # (either unknown)
            return 0.5 * echo
        half = 0.5 * (base_in + base_out)
        inbound = echo - half - self.queue_out
        if inbound < half:
            inbound = half
        if inbound > echo - half:
            inbound = echo - half if echo > 2.0 * half else 0.5 * echo
        return inbound

    def estimate(self) -> float | None:
        """The inbound one-way delay now (base half plus the inbound queue), or ``None``."""
        base_in = self._base_in.value
        base_out = self._base_out.value
        if base_in + base_out == math.inf:  # (either unknown)
            return None
        return 0.5 * (base_in + base_out) + self.queue_in

    def _read(self, echo: float | None, hold: int, now: float) -> float | None:
        """Read the pending stamp: the inbound sample, and the outbound one if ``echo`` timed one
        of our packets. Returns the stamped packet's inbound delay (its base half plus its queue)."""
        self.pending = False
        if echo is None and self._stats.optimistic_acks != self._optimistic:
            # Its acknowledgement named a packet we never sent (a forgery moved the peer's window
            # past what we sent): what is in flight is unknown until a real one, so the window
            # must not hold our packets back meanwhile (a forgery costs no more than itself).
            self._controller.on_one_way_delay(
                now=now, delay=math.nan, sent_at=now, seq=-1, hold=0.0, unacked=0
            )
        elif echo is None and hold == HOLD_SATURATED and self._recovery.echo_seq >= 0:
            # The peer had held our newest packet longer than HOLD can say: nothing new from us
            # reached it for over 31.7 ms. No delay to read, but news for the controller.
            recovery = self._recovery
            seq = recovery.echo_seq
            self._controller.on_one_way_delay(
                now=now,
                delay=math.nan,
                sent_at=recovery.echo_sent,
                seq=seq,
                hold=math.inf,
                unacked=recovery.sent.next_seq - 1 - seq,
            )
        clock = self._stamp_clock
        rev = self._rx - clock
        fwd = math.nan if echo is None else echo - (now - clock)
        base_in = self._base_in.value
        base_out = self._base_out.value
        if base_in + base_out < math.inf:  # (both known)
            span = base_in + base_out  # the smallest round trip, as the bases see it
            margin = (span if span > 0.0 else 0.0) + TOLERANCE
            bad = rev < base_in - margin or (
                echo is not None
                and (
                    # No real round trip is shorter than the smallest (a forged DATA numbered
                    # ahead makes the peer's HOLD start before we sent the packet it names).
                    echo < span - TOLERANCE
                    or fwd < base_out - margin
                    or rev - base_in > echo + TOLERANCE
                    or fwd - base_out > echo + TOLERANCE
                )
            )
            if bad:
                self.stamps_rejected += 1
                self._rejected_run += 1
                if self._rejected_run >= RESET_AFTER:
                    self._rejected_run = 0
                    self._base_in.reset()
                    self._base_out.reset()
                return None
        self._rejected_run = 0
        self._base_in.add(now, rev)
        base_in = self._base_in.value
        self.queue_in += QUEUE_GAIN * (rev - base_in - self.queue_in)
        if echo is not None:
            self._base_out.add(now, fwd)
            base_out = self._base_out.value
            self.queue_out += QUEUE_GAIN * (fwd - base_out - self.queue_out)
            self.samples += 1
            recovery = self._recovery
            sent = recovery.echo_sent
            seq = recovery.echo_seq
            self._controller.on_one_way_delay(
                now=now,
                delay=fwd,
                sent_at=sent,
                seq=seq,
                hold=now - echo - sent,
                unacked=recovery.sent.next_seq - 1 - seq,
            )
        if base_out == math.inf:
            return None
        return 0.5 * (base_in + base_out) + rev - base_in
