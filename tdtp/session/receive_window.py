"""The receiver's view of the peer's data: sequence expansion, duplicate/late detection, ACK fields.

A ring of 64 slots remembers which of the last 64 sequence numbers arrived: slot ``seq % 64`` holds
the full sequence number that last arrived there, so a number arrived exactly when its slot holds it
(one within the window can only have been overwritten by a number 64 above it, which would have
pushed it out of the window). Nothing is cleared when the window moves. The ACK a packet carries is
the highest sequence number received; its SACK bits describe the six below it, kept in a small mask
of the seven newest (``_recent``, bit 0 = the highest). Both stay within machine-word integers: a
64-bit mask does not, in the compiled build (mypyc's tagged integers hold 62 bits and spill to a
Python ``int``, about 1,900 instructions per packet on the way from arrival to the answer).

In bidirectional mode the window also keeps the promise of docs/PROTOCOL.md section 3.2: every
sequence number after the last one reported is described by some ACK (received, or absent) as long as
an ACK can still reach it. Two rules do that. *Full*: once the highest received is 6 above the oldest
sequence number still to be described, the next ACK must go out now (:meth:`coverage_exhausted`).
*Jump*: a new packet more than 6 above that oldest number would push it out of every later ACK, so
the ACK of the highest *before* the jump is held for sending first (:meth:`take_held`).

In an unkeyed session (``guard_jumps``) a new packet may not move the window further ahead than the
peer can have sent since the highest arrived (docs/PROTOCOL.md 5.5, ``far_ahead``): more than
:data:`JUMP_FREE` ahead needs a silence of the peer's data that long at twice its fastest recent rate
(:data:`JUMP_MIN_RATE` at least), or a silence of ``silence_guard``. A blind forgery numbered ahead
of a live flow would otherwise make us acknowledge numbers the peer never sent and take the real
packets that follow for late ones; a loss burst of the real flow passes, because its silence is as
long as the burst.
"""

from __future__ import annotations

import enum
from collections import deque
from typing import Final, NamedTuple

from tdtp.wire.header import SACK_BITS, SACK_MASK, SEQ_MASK
from tdtp.wire.hold import encode_hold
from tdtp.wire.seqnum import SEQ_HALF, SEQ_MODULUS

WINDOW: Final = 64
_SLOT: Final = WINDOW - 1
"""``seq & _SLOT``: a sequence number's slot in the ring (WINDOW is a power of two)."""
SACK_SPAN: Final = SACK_BITS
"""Sequence numbers below ACK that the SACK bits describe."""
_RECENT_BITS: Final = SACK_SPAN + 1
_RECENT_MASK: Final = (1 << _RECENT_BITS) - 1
_NEVER: Final = -(1 << 40)
"""What an empty slot holds: no full sequence number is ever that low (they start at the 12-bit
initial number, and the window never looks more than 2048 below the highest)."""
RESYNC_RUN: Final = 3
"""Consecutive sequence numbers that all look older than the window: the peer's numbering has moved on by
more than half the 12-bit space (a loss burst of over 2047 packets), so the window re-anchors one wrap
ahead instead of discarding a live flow as stale. After a silence the same rule covers numbers that look
like duplicates or late packets within the window (an outage just short of a multiple of 4096)."""
DEFAULT_SILENCE_GUARD: Final = 0.1
"""Seconds without a new packet after which in-window "old" numbers may be a wrapped live flow."""
JUMP_FREE: Final = 32
"""Sequence numbers a new packet may lie ahead of the highest received without a silence to match:
half the window, more than any reordering a reorder wait can still put in order at 1 kHz."""
JUMP_MIN_RATE: Final = 1000.0
"""The least rate (packets/s) the jump check assumes for the peer (its fastest rate measured over a
second, doubled, when higher)."""
RATE_WINDOW: Final = 1.0
"""Seconds over which the peer's data rate is measured for the jump check."""
MAX_HELD: Final = 8
"""Jump ACKs kept for the next flush. The caller flushes after every input, so one is the most ever
waiting; the bound only protects against a caller that does not (the oldest is then forgotten)."""


class HeldAck(NamedTuple):
    """An acknowledgement the jump rule decided must go out, frozen as it was before the jump."""

    ack: int
    sack: int
    arrival: float
    """When the packet named by ``ack`` arrived (its hold is measured from here)."""


class Arrival(enum.Enum):
    NEW = "new"
    """Newer than anything before it (possibly after a gap)."""
    LATE = "late"
    """Older than the highest received, not seen before: reordered."""
    DUPLICATE = "duplicate"
    STALE = "stale"
    """Older than the window: its fate cannot be checked, so it is not trusted."""
    FAR_AHEAD = "far_ahead"
    """Unkeyed: further ahead than the peer can have sent since the highest arrived; the window
    does not move (it is dropped)."""


# Enum members as module constants for the per-packet paths: reading one off its class goes through
# the enum metaclass (about 0.1 us in either build on Python 3.11), a module constant does not.
NEW: Final = Arrival.NEW
LATE: Final = Arrival.LATE
DUPLICATE: Final = Arrival.DUPLICATE
STALE: Final = Arrival.STALE
FAR_AHEAD: Final = Arrival.FAR_AHEAD


class ReceiveWindow:
    __slots__ = (
        "_anchored",
        "_coverage",
        "_rate_base",
        "_rate_end",
        "_rate_previous",
        "_rate_start",
        "_recent",
        "_seen",
        "_stale_next",
        "_stale_run",
        "guard_jumps",
        "has_data",
        "held",
        "highest",
        "highest_arrival",
        "last_gap",
        "last_reported",
        "last_seq",
        "peak_rate",
        "pending_low",
        "silence_guard",
        "unreported_since",
    )

    def __init__(
        self,
        initial_seq: int,
        *,
        coverage: bool = True,
        silence_guard: float = DEFAULT_SILENCE_GUARD,
        guard_jumps: bool = False,
    ) -> None:
        """``coverage`` enables the reporting rules of bidirectional mode (separate-ACK mode answers
        every packet with its own ACK and needs none); ``guard_jumps`` the jump check of an
        unkeyed session (:data:`FAR_AHEAD`)."""
        self.highest = initial_seq - 1
        """Full sequence number of the newest data received (initial - 1 before any)."""
        self.highest_arrival = 0.0
        self._seen = [_NEVER] * WINDOW
        """Slot ``seq % WINDOW``: the full sequence number that arrived there last."""
        self._recent = 0
        """Bit i: ``highest - i`` arrived (i = 0..6, what the SACK bits of the highest need)."""
        self.has_data = False
        """Whether any data arrived (the mask is not empty; a plain attribute, read per packet)."""
        self.last_reported = initial_seq - 1
        """The highest ACK value already sent to the peer."""
        self.unreported_since: float | None = None
        """Arrival time of the oldest packet not yet reported in an outgoing ACK."""
        self.pending_low: int | None = None
        """The oldest sequence number no ACK has described yet (received or absent), if any."""
        self.held: deque[HeldAck] = deque(maxlen=MAX_HELD)
        """ACKs the jump rule requires, oldest first, for the next flush."""
        self._coverage = coverage
        self._stale_next = 0
        self._stale_run = 0
        self.last_seq = self.highest
        """The full sequence number of the packet :meth:`classify` saw last."""
        self.last_gap = 0
        """Sequence numbers it skipped (a new packet after a gap), else 0."""
        self.silence_guard = silence_guard
        """After this long without a new packet, a run of consecutive numbers that look like
        duplicates or late packets re-anchors the window like a stale run (the connection passes
        its ``silence_timeout``); and a packet any distance ahead is taken."""
        self.guard_jumps = guard_jumps
        self.peak_rate = 0.0
        """The peer's faster data rate (new packets a second) of the last two measurements."""
        self._rate_previous = 0.0
        self._rate_start = 0.0
        self._rate_end = 0.0  # the first new packet starts the measurement
        self._rate_base = self.highest
        self._anchored = False  # the packet being classified was re-anchored one wrap ahead

    def on_data(self, truncated_seq: int, now: float) -> tuple[Arrival, int, int]:
        """Classify an arriving data packet; returns (arrival kind, full sequence number, gap)."""
        arrival = self.classify(truncated_seq, now)
        return arrival, self.last_seq, self.last_gap

    def classify(self, truncated_seq: int, now: float) -> Arrival:
        """:meth:`on_data` without the result tuple (the connection's per-packet path): the full
        sequence number and the gap are left in :attr:`last_seq` and :attr:`last_gap`."""
        highest = self.highest
        self.last_gap = 0
        # expand_seq(truncated_seq, highest + 1), inline: the one call per packet it would cost.
        diff = (truncated_seq - highest - 1) & SEQ_MASK
        if diff >= SEQ_HALF:
            diff -= SEQ_MODULUS
        seq = highest + 1 + diff
        distance = seq - highest
        # (new packets skip all of this)
        if distance <= 0 and (
            distance <= -WINDOW or now - self.highest_arrival >= self.silence_guard
        ):
            # Older than the window, or inside it after a silence: a late or replayed copy, or the
            # live flow after a loss burst of over 2047 packets, or after an outage that lasted just
            # under a multiple of 4096 packets (in-window numbers would be dropped as duplicates for
            # up to 63 packets). A run of consecutive numbers decides.
            self._stale_run = self._stale_run + 1 if seq == self._stale_next else 1
            self._stale_next = seq + 1
            if self._stale_run >= RESYNC_RUN:
                self._stale_run = 0
                seq += SEQ_MODULUS  # now ahead of highest: expand_seq put it at most 2048 behind
                distance = seq - highest
                self._anchored = True  # (at least 2048 ahead now: the jump check lets it through)
            elif distance <= -WINDOW:
                self.last_seq = seq
                return STALE
        else:
            # Any other arrival ends a run: only numbers that arrive one after the other re-anchor
            # the window (three stale numbers spread between live packets once did).
            self._stale_run = 0
        if distance > 0:
            if distance > JUMP_FREE and self.guard_jumps and not self._plausible(distance, now):
                self.last_seq = seq
                return FAR_AHEAD
            if self._coverage:
                reach = seq - SACK_SPAN  # the lowest sequence number an ACK of ``seq`` describes
                low = self.pending_low
                if low is None:
                    # What the next ACK must describe: all after the last report that it reaches.
                    low = self.last_reported + 1
                    self.pending_low = low if low > reach else reach
                elif reach > low:
                    # Jump rule: an ACK of ``seq`` would no longer reach ``low``; report the
                    # highest as it stands first (it reaches ``low``: the full rule saw to it).
                    self.held.append(
                        HeldAck(highest, self.sack_below(highest), self.highest_arrival)
                    )
                    self.last_reported = highest
                    self.unreported_since = None
                    low = highest + 1
                    self.pending_low = low if low > reach else reach
            self._seen[seq & _SLOT] = seq
            self._recent = (
                ((self._recent << distance) | 1) & _RECENT_MASK if distance < _RECENT_BITS else 1
            )
            self.highest = seq
            self.highest_arrival = now
            if now >= self._rate_end:
                self._measure_rate(now)
            self.has_data = True
            if self.unreported_since is None:
                self.unreported_since = now
            self.last_seq = seq
            self.last_gap = distance - 1
            return NEW
        self.last_seq = seq
        behind = -distance
        seen = self._seen
        slot = seq & _SLOT
        if seen[slot] == seq:
            return DUPLICATE
        seen[slot] = seq
        if behind < _RECENT_BITS:
            self._recent |= 1 << behind
        self.has_data = True
        if self._coverage:
            if behind <= SACK_SPAN:
                # Within reach of an ACK of the highest: the next one must report it.
                low = self.pending_low
                if low is None or seq < low:
                    self.pending_low = seq
            else:
                # Reordered further than an ACK of the highest reaches: report it in an ACK of its
                # own, so that the sender counts it received, not lost (docs/PROTOCOL.md 3.2).
                self.held.append(HeldAck(seq, self.sack_below(seq), now))
        if self.unreported_since is None:
            self.unreported_since = now
        return LATE

    def arrived(self, seq: int) -> bool:
        """Whether the full sequence number ``seq`` arrived and is still within the window."""
        return 0 <= self.highest - seq < WINDOW and self._seen[seq & _SLOT] == seq

    def _plausible(self, distance: int, now: float) -> bool:
        """Whether the peer can have sent ``distance`` packets since the highest arrived (the jump
        check of an unkeyed session; a re-anchored packet always passes)."""
        if self._anchored:
            self._anchored = False
            return True
        silence = now - self.highest_arrival
        if not self.has_data or silence >= self.silence_guard:
            return True
        rate = 2.0 * self.peak_rate
        if rate < JUMP_MIN_RATE:
            rate = JUMP_MIN_RATE
        return distance - JUMP_FREE <= silence * rate

    def _measure_rate(self, now: float) -> None:
        """Close a measurement of the peer's data rate (new packets a second, over
        :data:`RATE_WINDOW`) and start the next."""
        elapsed = now - self._rate_start
        if self._rate_end > 0.0 and elapsed > 0.0:
            rate = (self.highest - self._rate_base) / elapsed
            previous = self._rate_previous
            self.peak_rate = rate if rate > previous else previous
            self._rate_previous = rate
        self._rate_start = now
        self._rate_end = now + RATE_WINDOW
        self._rate_base = self.highest

    def sack_below(self, seq: int) -> int:
        """SACK bits for the six sequence numbers below ``seq`` (which must be within the window):
        bit k says whether ``seq - 1 - k`` arrived (numbers below the window count as absent)."""
        highest = self.highest
        if seq == highest:
            return (self._recent >> 1) & SACK_MASK
        seen = self._seen
        oldest = highest - WINDOW  # above it: within the window
        bits = 0
        for k in range(SACK_SPAN):
            below = seq - 1 - k
            if below > oldest and seen[below & _SLOT] == below:
                bits |= 1 << k
        return bits

    def coverage_exhausted(self) -> bool:
        """Full rule: an ACK of the highest just reaches the oldest sequence number not described
        yet, so it must go out before another packet arrives."""
        low = self.pending_low
        return low is not None and self.highest - low >= SACK_SPAN

    def take_held(self) -> list[HeldAck]:
        """The ACKs the jump rule requires (oldest first), now owed to the caller."""
        held = list(self.held)
        self.held.clear()
        return held

    def report(self, now: float) -> tuple[int, int, int]:
        """The ACK fields of a packet that reports the highest received at ``now``: its full
        sequence number, the SACK bits below it and the HOLD code. From then on it counts as
        reported (:meth:`mark_reported`)."""
        highest = self.highest
        self.last_reported = highest
        self.pending_low = None
        self.unreported_since = None
        # sack_below(highest), inline
        return highest, (self._recent >> 1) & SACK_MASK, encode_hold(now - self.highest_arrival)

    def mark_reported(self) -> None:
        self.last_reported = self.highest
        self.pending_low = None
        self.unreported_since = None
