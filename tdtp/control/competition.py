"""Whose queue is it? The teleop controller's switch to a TCP-competitive mode and back (docs/CONTROL.md 9.9).

A delay-based flow keeps the queue short by slowing down whenever it grows. That works when the
queue is its own doing, or that of flows that slow down too. A loss-based flow (cubic, Reno) or BBR
fills the buffer whatever the others do: a delay-based flow beside it keeps slowing down and is left
with a trickle, while the queue stays full (measured against the Linux kernel before this mode: 10 %
of a 1 Mbit/s link beside bbr, 18 % beside cubic). Copa answers with a competitive mode that it enters
when the queue has not been nearly empty for five round trips; Nimbus by pulsing its rate and watching
whether the cross traffic moves with it. Here:

* **Entering.** In the default (delay) mode every control interval reports its standing queue. When
  it has stayed above the target for ``ENTER_AFTER`` seconds (at least ``ENTER_RTTS`` round trips)
  although the controller cut its rate meanwhile (its drains empty a queue of its own within a few
  round trips), someone else keeps the queue: the flow turns competitive, resuming at half the rate
  it had when the episode began (what a TCP keeps after a loss).
* **Competing.** The rate follows TCP's congestion avoidance counted in bytes: ``INCREASE`` of a
  ``tcp_segment`` more per round trip, ``OVERFLOW_DECREASE`` per buffer overflow and
  ``LOSS_DECREASE`` per loss event of its own (the controller's loss rule, with every loss counted as
  congestion), under the byte-based TCP-friendly ceiling; the queue is the competitor's. Where
  losses are the only signal the lighter loss cut makes it somewhat more aggressive than Reno;
  beside the kernel's cubic through a byte-counted buffer it takes more than TCP (docs/CONTROL.md
  9.9 has the figures and the lock-out check).
* **Leaving.** Every ``PROBE_EVERY`` seconds the flow drops to ``PROBE_SHARE`` of its rate for two
  round trips. A queue of its own empties (the interval's standing queue falls to the target): back
  to the delay mode. A queue a window-based competitor keeps does not, since its packets in flight
  stay where they are (the flow's own leave): the flow returns to its rate and keeps competing.
  The check compares with the base RTT from before the competitor came: while competing, the base
  window's halves last ``BASE_HOLD`` seconds, or a queue kept standing for longer than the base
  window (BBR's, cubic's above its troughs) would become the base and read as no queue at all.
"""

from __future__ import annotations

import math
from typing import Final

ENTER_AFTER: Final = 1.0
"""Seconds of a standing queue above the target, despite the flow's cuts, before it competes."""
ENTER_RTTS: Final = 8.0
"""...and at least this many round trips (a long path's drains take longer to show)."""
INCREASE: Final = 0.35
"""Segments per round trip the competitive mode adds (Reno adds one, CUBIC's TCP-friendly region
0.53 with a decrease of 0.7). 0.5 took 62 % of a 1 Mbit/s tbf beside the kernel's cubic and left
TCP 36 % (median of three runs); 0.35 left it 44 %, and 41 % with the base held and the two
decreases below (docs/CONTROL.md 9.9)."""
LOSS_DECREASE: Final = 0.85
"""The competitive mode's decrease per loss event of its own. Beside a loss-based competitor in a
drop-tail buffer these are rare (our small packets mostly find room where its full-size segments do
not: the overflow below answers those); beside one that ignores loss (BBR) they come every round
trip, and a TCP-sized cut for each hands it the link: 0.7 took 33 % of a 1 Mbit/s tbf beside the
kernel's bbr, 0.85 takes 40 % (medians of eight runs; docs/CONTROL.md 9.9)."""
OVERFLOW_DECREASE: Final = 0.6
"""The competitive mode's decrease per buffer overflow (a standing queue near the highest seen):
where a loss-based competitor loses its segments and backs off, this flow backs off with it, a
little more than CUBIC's 0.7 since it loses fewer of its own there."""
FULL: Final = 0.8
"""Competitive mode: a standing queue this share of the highest seen counts as a full buffer."""
PROBE_EVERY: Final = 10.0
"""Seconds between the competitive mode's checks that the competitor is still there."""
PROBE_SHARE: Final = 0.25
"""The rate during such a check, as a share of the rate in use."""
PROBE_RTTS: Final = 2.0
"""Round trips a check lasts."""
BASE_HOLD: Final = 60.0
"""Competing, the base RTT's half-windows last this long, not half of ``base_window``: a queue the
competitor keeps standing for longer would become the base, read as no queue, and the next check
would take it for the flow's own (docs/CONTROL.md 9.9)."""


class Competition:
    """The congestion episode under way, the mode, and the competitive mode's checks."""

    __slots__ = (
        "_armed",
        "_cleared",
        "_episode_rate",
        "_next_probe",
        "_probe_until",
        "_restore",
        "_since",
        "_top",
        "active",
        "entries",
        "last_loss",
    )

    def __init__(self) -> None:
        self.active = False
        """The flow competes (TCP's additive increase and halving, no queue-delay cuts)."""
        self.entries = 0
        """Times the flow turned competitive."""
        self.last_loss = -math.inf
        """When the flow last saw a loss event (the controller keeps it up to date)."""
        self._since = math.inf  # the standing queue above the target since then
        self._episode_rate = 0.0  # the rate when that began
        self._next_probe = math.inf
        self._probe_until = -math.inf
        self._restore = 0.0
        self._cleared = False
        self._armed = True
        self._top = 0.0  # the highest standing queue seen while competing

    @property
    def probing(self) -> bool:
        return self._probe_until > -math.inf

    def observe(self, now: float, queue: float, target: float, rate: float, srtt: float) -> float:
        """Delay mode, at the end of a control interval with standing ``queue``: 0.0, or the rate
        to compete from when the flow turns competitive now."""
        if queue <= target:
            self._since = math.inf
            return 0.0
        if self._since == math.inf:
            self._since = now
            self._episode_rate = rate
            return 0.0
        wait = ENTER_RTTS * srtt
        if wait < ENTER_AFTER:
            wait = ENTER_AFTER
        if now - self._since < wait:
            return 0.0
        self.active = True
        self.entries += 1
        self._since = math.inf
        self._next_probe = now + PROBE_EVERY
        self._top = queue
        return 0.5 * self._episode_rate

    def full(self, now: float, queue: float) -> bool:
        """Competitive mode, at the end of an interval: whether the standing ``queue`` is near the
        highest seen while competing, where a drop-tail buffer overflows: there a loss-based
        competitor loses its segments and decreases, while this flow's small paced packets mostly
        find room (a byte-counted buffer drops a full segment first); it decreases with the
        competitor instead of taking its share. Once per overflow: a competitor that keeps the
        buffer full (BBR) takes one decrease, not one per round trip."""
        if queue > self._top:
            self._top = queue
        if queue < FULL * self._top:
            self._armed = True  # the queue fell back: the next overflow is a new one
            return False
        armed = self._armed
        self._armed = False  # (one decrease per overflow, as a TCP takes one per loss event)
        return armed

    def step(self, srtt: float, duration: float, packet_bytes: float, segment: int) -> float:
        """TCP's additive increase over ``duration`` seconds, in packets/s: one ``segment`` per
        round trip, in our packets of ``packet_bytes`` on the wire."""
        return INCREASE * (segment / packet_bytes) * duration / (srtt * srtt)

    def probe_due(self, now: float, rate: float, srtt: float) -> float:
        """Competitive mode: 0.0, or the rate of a check that starts now."""
        if self.probing or now < self._next_probe:
            return 0.0
        self._probe_until = now + PROBE_RTTS * srtt
        self._restore = rate
        self._cleared = False
        return PROBE_SHARE * rate

    def during_probe(self, now: float, queue: float, target: float) -> float:
        """At the end of an interval of a check: -1.0 while it goes on; else 0.0 (the queue was
        ours: back to the delay mode, at the current rate) or the rate to compete on at."""
        # (The queue as the check ends: a competitor that keeps a queue of its own without filling
        # the buffer, BBR, refills it while this flow holds back; one that left does not.)
        self._cleared = queue <= target
        if now < self._probe_until:
            return -1.0
        self._probe_until = -math.inf
        self._next_probe = now + PROBE_EVERY
        if self._cleared:
            self.active = False
            return 0.0
        return self._restore

    def leave(self) -> None:
        """Back to the delay mode (an outage, a reset of the path's state)."""
        self.active = False
        self._since = math.inf
        self._probe_until = -math.inf
