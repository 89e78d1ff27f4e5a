"""The receiver's view of the peer's data: sequence expansion, duplicate/late detection, ACK fields.

A 64-bit mask remembers which of the last 64 sequence numbers arrived (bit 0 = the highest). The
ACK a packet carries is the highest sequence number received; its SACK bits are mask bits 1..6.
"""

from __future__ import annotations

import enum

from tdtp.wire.seqnum import SEQ_MODULUS, expand_seq

WINDOW = 64
_WINDOW_MASK = (1 << WINDOW) - 1
SACK_COVERAGE = 7
"""One ACK reports the ACK value and the 6 below it; a stand-alone ACK is due before a packet would
be left unreported."""
RESYNC_RUN = 3
"""Consecutive sequence numbers that all look older than the window: the peer's numbering has moved on by
more than half the 12-bit space (a loss burst of over 2047 packets), so the window re-anchors one wrap
ahead instead of discarding a live flow as stale. After a silence the same rule covers numbers that look
like duplicates or late packets within the window (an outage just short of a multiple of 4096)."""
DEFAULT_SILENCE_GUARD = 0.1
"""Seconds without a new packet after which in-window "old" numbers may be a wrapped live flow."""


class Arrival(enum.Enum):
    NEW = "new"
    """Newer than anything before it (possibly after a gap)."""
    LATE = "late"
    """Older than the highest received, not seen before: reordered."""
    DUPLICATE = "duplicate"
    STALE = "stale"
    """Older than the window: its fate cannot be checked, so it is not trusted."""


class ReceiveWindow:
    __slots__ = (
        "_mask",
        "_stale_next",
        "_stale_run",
        "highest",
        "highest_arrival",
        "last_reported",
        "silence_guard",
        "unreported_since",
    )

    def __init__(self, initial_seq: int) -> None:
        self.highest = initial_seq - 1
        """Full sequence number of the newest data received (initial - 1 before any)."""
        self.highest_arrival = 0.0
        self._mask = 0
        self.last_reported = initial_seq - 1
        """The highest ACK value already sent to the peer."""
        self.unreported_since: float | None = None
        """Arrival time of the oldest packet not yet reported in an outgoing ACK."""
        self._stale_next = 0
        self._stale_run = 0
        self.silence_guard = DEFAULT_SILENCE_GUARD
        """After this long without a new packet, a run of consecutive numbers that look like
        duplicates or late packets re-anchors the window like a stale run (the connection sets it to
        its ``silence_timeout``)."""

    @property
    def has_data(self) -> bool:
        return self._mask != 0

    def on_data(self, truncated_seq: int, now: float) -> tuple[Arrival, int, int]:
        """Classify an arriving data packet; returns (arrival kind, full sequence number, gap)."""
        highest = self.highest
        seq = expand_seq(truncated_seq, highest + 1)
        distance = seq - highest
        if distance <= 0:  # (new packets skip all of this)
            if distance <= -WINDOW:
                self._stale_run = self._stale_run + 1 if seq == self._stale_next else 1
                self._stale_next = seq + 1
                if self._stale_run < RESYNC_RUN:
                    return Arrival.STALE, seq, 0
                self._stale_run = 0
                seq += SEQ_MODULUS  # now ahead of highest: expand_seq put it at most 2048 behind
                distance = seq - highest
            elif now - self.highest_arrival >= self.silence_guard:
                # Older than the newest but inside the window, after a silence: a late or replayed
                # copy, or the live flow after an outage that lasted just under a multiple of 4096
                # packets (it would be dropped as duplicates for up to 63 packets). A consecutive run
                # decides, as for stale numbers.
                self._stale_run = self._stale_run + 1 if seq == self._stale_next else 1
                self._stale_next = seq + 1
                if self._stale_run >= RESYNC_RUN:
                    self._stale_run = 0
                    seq += SEQ_MODULUS
                    distance = seq - highest
        if distance > 0:
            self._mask = ((self._mask << distance) | 1) & _WINDOW_MASK if distance < WINDOW else 1
            self.highest = seq
            self.highest_arrival = now
            if self.unreported_since is None:
                self.unreported_since = now
            return Arrival.NEW, seq, distance - 1
        behind = -distance
        bit = 1 << behind
        if self._mask & bit:
            return Arrival.DUPLICATE, seq, 0
        self._mask |= bit
        if self.unreported_since is None:
            self.unreported_since = now
        return Arrival.LATE, seq, 0

    def sack_below(self, seq: int) -> int:
        """SACK bits for the six sequence numbers below ``seq`` (which must be within the window)."""
        return (self._mask >> (self.highest - seq + 1)) & 0x3F

    def coverage_exhausted(self) -> bool:
        """True when the next ACK could no longer report every packet since the last one sent."""
        return self.highest - self.last_reported >= SACK_COVERAGE

    def mark_reported(self) -> None:
        self.last_reported = self.highest
        self.unreported_since = None
