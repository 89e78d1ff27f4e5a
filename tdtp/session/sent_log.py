"""The sender's memory of its data packets: ACK expansion, acknowledgement marking and loss detection.

Every data packet takes the next sequence number, so a packet's record sits at ``seq - base`` in two
parallel deques (its send time, and its state: acknowledged, reported missing) that start at the oldest
packet whose fate is still open. Records leave from the front once acknowledged or declared lost, so the
work per packet is constant on average. (Two deques of numbers rather than one of record objects: a
record is made for every packet sent, and an object costs several times more to make.)
"""

from __future__ import annotations

from collections import deque
from typing import Final, NamedTuple

from tdtp.wire.header import SACK_BITS, SEQ_MASK
from tdtp.wire.seqnum import SEQ_MODULUS

ACK_WINDOW_BEHIND: Final = 1024
"""An ACK may be this far below the largest acknowledged value (reordered feedback) and still decode."""
SACK_SPAN: Final = SACK_BITS
MAX_REORDER_SCALE: Final = 4
"""The reorder window grows to at most this many times its start (it is also capped at srtt)."""
RECENTLY_LOST: Final = 256
"""How many declared losses are remembered to recognise a spurious one (the packet arrived after all)."""


ACKED: Final = 1
"""A record's state bit: the packet was reported received."""
MISSING: Final = 2
"""A record's state bit: a received ACK covered the packet and reported it absent (evidence it may be
lost)."""


class LostPacket(NamedTuple):
    seq: int
    send_time: float


class AckOutcome(NamedTuple):
    newly_acked: int
    rtt_sample: float | None
    spurious: int


class SentPacketLog:
    """Records of sent data packets, from the oldest unresolved one to the newest."""

    __slots__ = (
        "_base",
        "_largest_send_time",
        "_last_ack",
        "_last_sack",
        "_max_tracked",
        "_recently_lost",
        "_recently_lost_order",
        "_reorder_threshold",
        "_states",
        "_times",
        "first_seq",
        "largest_acked",
        "marked_missing",
        "next_seq",
        "reorder_window_scale",
        "reordered",
        "reordering_seen",
        "rtt_sample",
        "spurious",
        "unknown",
    )

    def __init__(self, first_seq: int, *, reorder_threshold: int, max_tracked: int) -> None:
        self.first_seq = first_seq
        self.next_seq = first_seq
        self.largest_acked = first_seq - 1
        self._largest_send_time = 0.0
        self._base = first_seq
        self._times: deque[float] = deque()  # send times, from the packet at _base on
        self._states: deque[int] = deque()  # ACKED and MISSING bits, parallel to _times
        self._reorder_threshold = reorder_threshold
        self._max_tracked = max_tracked
        self._recently_lost: set[int] = set()
        self._recently_lost_order: deque[int] = deque()
        self.unknown = 0
        """Packets retired with no verdict: every ACK that could have reported them was lost."""
        self.rtt_sample: float | None = None
        """The RTT sample of the last :meth:`acknowledge` (``None``: it gave none)."""
        self.spurious = 0
        """Declared losses the last :meth:`acknowledge` found received after all."""
        self.marked_missing = False
        """Set when an ACK reports a packet absent for the first time (a loss deadline may now be
        due); the connection clears it."""
        self.reordered = 0
        """Packets an ACK reported absent that a later ACK reported received: reordered on the way
        (or their report was), not lost."""
        self.reordering_seen = False
        """Once reordering has been seen, only the time threshold declares losses (RFC 8985): the
        packet-count threshold would take every reordered packet for a lost one."""
        self.reorder_window_scale = 1
        self._last_ack = -1  # the last acknowledge()'s ACK and SACK fields (-1: none yet)
        self._last_sack = -1
        """RFC 8985's reorder window multiplier: grows by one for each declared loss found received
        after all (a spurious loss: the window was too short), up to ``MAX_REORDER_SCALE``."""

    @property
    def in_flight(self) -> int:
        """Packets sent whose fate is still open."""
        return sum(1 for state in self._states if not state & ACKED)

    def on_sent(self, send_time: float, size: int, lost: list[LostPacket]) -> int:
        """Record a departure; returns its sequence number. Past the table bound the oldest record is
        retired: lost (appended to ``lost``) if an ACK reported it absent, else unknown."""
        seq = self.next_seq
        self.next_seq = seq + 1
        times = self._times
        times.append(send_time)
        self._states.append(0)
        if len(times) > self._max_tracked:
            oldest_time = times.popleft()
            state = self._states.popleft()
            if state == MISSING:  # missing and not acknowledged
                self._declare_lost(self._base, oldest_time, lost)
            elif not state & ACKED:
                self.unknown += 1
            self._base += 1
        return seq

    def expand_ack(self, truncated: int, hold: float | None, now: float, srtt: float) -> int | None:
        """The full sequence number a 12-bit ACK refers to, or ``None`` if it names a packet never sent.

        The ACK is read in ``[largest_acked - 1024, largest_acked + 3071]``. When more than 4096 packets
        are in flight several values fit; the one whose RTT best matches ``srtt`` wins, and a repeat of
        the largest acknowledged value is taken as that repeat (the peer received nothing newer).
        """
        highest_sent = self.next_seq - 1
        largest = self.largest_acked
        if truncated == largest & SEQ_MASK and largest >= self.first_seq:
            return largest
        low = largest - ACK_WINDOW_BEHIND
        full = low + ((truncated - low) & SEQ_MASK)
        if full < self.first_seq:
            full += SEQ_MODULUS
        if full > highest_sent:
            return None
        if full + SEQ_MODULUS > highest_sent:
            return full
        best, best_error = full, float("inf")
        elapsed_hold = hold if hold is not None else 0.0
        candidate = full
        while candidate <= highest_sent:
            send_time = self.send_time(candidate)
            if send_time is not None:
                error = abs(now - send_time - elapsed_hold - srtt)
                if error < best_error:
                    best, best_error = candidate, error
            candidate += SEQ_MODULUS
        return best

    def send_time(self, seq: int) -> float | None:
        """When packet ``seq`` was sent, if it is still on record (or is the largest acknowledged)."""
        index = seq - self._base
        if 0 <= index < len(self._times):
            return self._times[index]
        if seq == self.largest_acked:
            return self._largest_send_time
        return None

    def on_ack(self, ack: int, sack: int, hold: float | None, now: float) -> AckOutcome:
        """Mark ``ack`` and the SACK-reported packets below it as received."""
        newly = self.acknowledge(ack, sack, hold, now)
        return AckOutcome(newly, self.rtt_sample, self.spurious)

    def acknowledge(self, ack: int, sack: int, hold: float | None, now: float) -> int:
        """:meth:`on_ack` without the result tuple (the connection's per-packet path): returns the
        packets newly acknowledged and leaves the RTT sample and the spurious-loss count in
        :attr:`rtt_sample` and :attr:`spurious`."""
        if ack == self._last_ack and sack == self._last_sack:
            # The same fields as the last call (every datagram of a batch the peer sent before
            # hearing from us carries them): it found every packet they name acknowledged, or
            # marked missing, and forgot their spurious losses; only packets above the ACK were
            # logged since, and records left the front only as acknowledged or with their SACK
            # bit clear. It has nothing new to say.
            self.rtt_sample = None
            self.spurious = 0
            return 0
        self._last_ack = ack
        self._last_sack = sack
        states = self._states
        base = self._base
        count = len(states)
        newly = 0
        spurious = 0
        rtt_sample: float | None = None
        index = ack - base
        if 0 <= index < count:
            state = states[index]
            if not state & ACKED:
                states[index] = state | ACKED
                newly = 1
                if state & MISSING:
                    self._on_reordered()
                if ack > self.largest_acked:
                    send_time = self._times[index]
                    if hold is not None:
                        rtt_sample = now - send_time - hold
                    self.largest_acked = ack
                    self._largest_send_time = send_time
        elif index < 0 and ack in self._recently_lost:
            spurious += self._forget_loss(ack)
        recently_lost = self._recently_lost
        bit = 1
        for distance in range(1, SACK_SPAN + 1):
            below = index - distance
            if below < 0:
                # Resolved already (acknowledged or declared lost): only a spurious loss to find.
                if not recently_lost:
                    break
                if sack & bit and (ack - distance) in recently_lost:
                    spurious += self._forget_loss(ack - distance)
            elif below < count:
                state = states[below]
                if sack & bit:
                    if not state & ACKED:
                        states[below] = state | ACKED
                        newly += 1
                        if state & MISSING:
                            self._on_reordered()
                elif not state & MISSING:
                    states[below] = state | MISSING
                    self.marked_missing = True
            bit <<= 1
        self.rtt_sample = rtt_sample
        self.spurious = spurious
        if spurious:
            self.reordering_seen = True
            self.reordered += spurious
            if self.reorder_window_scale < MAX_REORDER_SCALE:
                self.reorder_window_scale += 1
        return newly

    def _on_reordered(self) -> None:
        self.reordered += 1
        self.reordering_seen = True

    def detect_losses(self, now: float, loss_delay: float, lost: list[LostPacket]) -> None:
        """Retire resolved records from the front of the log.

        Only a packet that a received ACK reported absent can be declared lost: once it has waited
        ``loss_delay`` while a later packet was acknowledged (RACK's time threshold, RFC 8985: the
        caller's ``loss_delay`` holds the reorder window), or, until reordering has been seen, once a
        packet ``reorder_threshold`` or more later is acknowledged. A packet that no received ACK ever
        covered is not evidence of loss (the reverse path lost its reports); once no future ACK can
        cover it, it is retired as *unknown*. A gap in feedback alone declares nothing: that is a
        blackout, which the rate controller's no-feedback timer handles.
        """
        times = self._times
        states = self._states
        largest = self.largest_acked
        threshold_seq = largest - self._reorder_threshold
        if self.reordering_seen:
            threshold_seq = -1  # no sequence number is that low: the time threshold alone decides
        uncoverable_seq = largest - SACK_SPAN
        while states:
            state = states[0]
            seq = self._base
            if state & ACKED:
                pass
            elif state & MISSING:
                send_time = times[0]
                if not (seq <= threshold_seq or (seq < largest and send_time + loss_delay <= now)):
                    # (The same sum as loss_deadline(): a timer set from it must find it due.)
                    break
                self._declare_lost(seq, send_time, lost)
            elif seq < uncoverable_seq:
                self.unknown += 1
            else:
                break
            times.popleft()
            states.popleft()
            self._base = seq + 1

    def loss_deadline(self, loss_delay: float) -> float | None:
        """When the time threshold next declares a loss, or ``None``."""
        # Asked after most ACKs: usually every record left is above the largest acknowledged
        # (nothing to look at), and no zip() (compiled, a call with a keyword and a tuple a record).
        below = self.largest_acked - self._base  # records that may be reported missing
        if below <= 0:
            return None
        for index, state in enumerate(self._states):
            if index >= below:
                return None
            if state == MISSING:  # missing and not acknowledged
                return self._times[index] + loss_delay
        return None

    def _declare_lost(self, seq: int, send_time: float, lost: list[LostPacket]) -> None:
        lost.append(LostPacket(seq, send_time))
        self._recently_lost.add(seq)
        order = self._recently_lost_order
        order.append(seq)
        if len(order) > RECENTLY_LOST:
            self._recently_lost.discard(order.popleft())

    def _forget_loss(self, seq: int) -> int:
        self._recently_lost.discard(seq)
        return 1
