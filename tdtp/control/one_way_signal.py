"""What the peer's stamps say about our own direction, as the teleop controller reads it (docs/CONTROL.md 9.7).

In a session with timestamps the connection hands the controller one sample per peer stamp that
acknowledged a packet of ours (``RateController.on_one_way_delay``): the packet's one-way delay plus
the clocks' offset, when it was sent, its sequence number and how long it had been the newest of ours
at the peer. :class:`OneWaySignal` turns them into the three things the controller decides on:

* **the queue now**: the smallest delay of the last few samples (``RECENT`` of them, all of packets
  sent after a moment the controller names: what it sent before its last decision says nothing about
  that decision), against the base the controller keeps;
* **what the link delivers**: the peer's clock of arrival (send time plus delay, the offset being
  constant) and the sequence numbers give the rate our packets reached the peer at, over the last
  ``RATE_WINDOW`` at least: measured on the receiver's side of the path, so jitter on the way back
  does not enter it (the rate of acknowledgements would carry it);
* **a link that stopped delivering**: the stamp's hold is how long the peer had heard nothing newer
  from us when the stamp left. Beyond the stall threshold while we were sending, our direction has
  stopped carrying our packets, whatever the way back does.

It also keeps the samples' jitter (RFC 3550's interarrival jitter, on one-way delays) for the
controller's margin, as it keeps the round trip's.
"""

from __future__ import annotations

import math
from typing import Final

RECENT: Final = 3
"""Samples whose smallest is the queue now: one jittery sample is not a queue, three in a row are."""
RATE_WINDOW: Final = 0.1
"""Seconds of the peer's clock, at least, over which the delivered rate is measured: long enough
to span a cellular link's bursts (a scheduler that delivers every few tens of ms)."""
RATE_SAMPLES: Final = 64
"""Samples kept for it (the window is shorter when they come faster)."""
PEAK_WINDOW: Final = 0.5
"""Seconds of the peer's clock over which :attr:`OneWaySignal.peak` keeps the highest rate."""
JITTER_GAIN: Final = 1.0 / 16.0


class OneWaySignal:
    """Recent one-way samples of our direction: the queue now, the delivered rate, the stall."""

    __slots__ = (
        "_arrivals",
        "_count",
        "_last",
        "_peak_at",
        "_peak_now",
        "_peak_prev",
        "_recent",
        "_sent",
        "_seqs",
        "gap",
        "gate_time",
        "hold",
        "jitter",
        "newest_seq",
        "peak",
        "rate",
        "samples",
    )

    def __init__(self) -> None:
        self._arrivals = [0.0] * RATE_SAMPLES  # the peer's clock of arrival (offset), a ring
        self._seqs = [0] * RATE_SAMPLES
        self._sent = [0.0] * RATE_SAMPLES  # our send times of the same packets
        self._count = 0
        self._recent = [math.inf] * RECENT
        self.gate_time = -math.inf
        """Only packets sent at or after it judge the queue (see :meth:`gate`)."""
        self._last = math.nan
        self.jitter = 0.0
        """Moving average of the difference between consecutive samples (s)."""
        self.gap = 0.0
        """Moving average of the time between arrivals that named a newer packet of ours, on the
        peer's clock (s): how bursty the link delivers."""
        self.rate = 0.0
        """Our packets' rate of arrival at the peer, packets/s (0 until measured)."""
        self.peak = 0.0
        """The highest :attr:`rate` of the last ``PEAK_WINDOW`` or so (two half-windows)."""
        self._peak_now = 0.0
        self._peak_prev = 0.0
        self._peak_at = -math.inf
        self.hold = 0.0
        """The last sample's hold: how long the peer had heard nothing newer from us (s)."""
        self.newest_seq = -1
        """The newest of our packets a sample named."""
        self.samples = 0

    def gate(self, since: float) -> None:
        """From now on the queue is judged on packets sent at or after ``since`` only."""
        self.gate_time = since
        recent = self._recent
        for i in range(RECENT):
            recent[i] = math.inf

    def add(self, delay: float, sent_at: float, seq: int, hold: float) -> None:
        self.samples += 1
        self.hold = hold
        last = self._last
        if not math.isnan(last):
            self.jitter += JITTER_GAIN * (abs(delay - last) - self.jitter)
        self._last = delay
        if sent_at >= self.gate_time:
            recent = self._recent
            for i in range(RECENT - 1):
                recent[i] = recent[i + 1]
            recent[RECENT - 1] = delay
        if seq <= self.newest_seq:
            return  # the same packet again (the peer heard nothing newer), or an older one
        self.newest_seq = seq
        arrival = sent_at + delay
        count = self._count
        if count:
            step = arrival - self._arrivals[(count - 1) % RATE_SAMPLES]
            self.gap += JITTER_GAIN * (step - self.gap)
        index = count % RATE_SAMPLES
        self._arrivals[index] = arrival
        self._seqs[index] = seq
        self._sent[index] = sent_at
        self._count = count + 1
        # The oldest sample at least RATE_WINDOW back on the peer's clock (or the oldest kept).
        back = 1
        limit = min(count, RATE_SAMPLES - 1)
        while back < limit:
            j = (count - back) % RATE_SAMPLES
            if arrival - self._arrivals[j] >= RATE_WINDOW:
                break
            back += 1
        if back <= limit and count >= 1:
            j = (count - back) % RATE_SAMPLES
            span = arrival - self._arrivals[j]
            if span > 0.0:
                rate = self.rate = (seq - self._seqs[j]) / span
                if arrival - self._peak_at >= 0.5 * PEAK_WINDOW:
                    self._peak_prev = self._peak_now
                    self._peak_now = 0.0
                    self._peak_at = arrival
                if rate > self._peak_now:
                    self._peak_now = rate
                self.peak = max(self._peak_now, self._peak_prev)

    def slope(self, window: float) -> float:
        """How fast the one-way delay grows with send time (s per s: GCC's trendline, a least
        squares fit) over the packets sent in the last ``window`` seconds before the newest one,
        past the gate; 0 with fewer than four. A link that delivers ``C`` while we send ``r > C``
        shows ``r / C - 1``."""
        count = self._count
        if count < 4:
            return 0.0
        newest = (count - 1) % RATE_SAMPLES
        last = self._sent[newest]
        since = last - window
        if since < self.gate_time:
            since = self.gate_time
        n = 0
        sx = sy = sxx = sxy = 0.0
        back = 0
        limit = count if count < RATE_SAMPLES else RATE_SAMPLES
        while back < limit:
            j = (count - 1 - back) % RATE_SAMPLES
            sent = self._sent[j]
            if sent < since:
                break
            x = sent - last
            y = self._arrivals[j] - sent
            n += 1
            sx += x
            sy += y
            sxx += x * x
            sxy += x * y
            back += 1
        if n < 4:
            return 0.0
        spread = n * sxx - sx * sx
        if spread <= 0.0:
            return 0.0
        return (n * sxy - sx * sy) / spread

    def queue_floor(self) -> float:
        """The smallest of the last ``RECENT`` samples past the gate (``inf`` until there are as
        many)."""
        recent = self._recent
        low = recent[0]
        for i in range(1, RECENT):
            if recent[i] < low:
                low = recent[i]
        return low if recent[0] != math.inf else math.inf
