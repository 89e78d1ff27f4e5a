"""How the application sends: the measurements behind a controller's application-limited guard.

A rate controller must not grow an allowance the application never uses (a flow that sends 1 kHz under
a 100 kHz allowance would burst into the path the moment it sent more), and must cut from what is sent,
not from an allowance nobody uses. Both need two figures, kept here for the trinomial and teleop
controllers alike (docs/CONTROL.md 3.4):

* the rate packets actually leave at: the inverse of a moving average of departure gaps. The gain
  (1/8, about the last eight gaps) smooths the jitter of a real event loop, where a periodic 1 kHz
  application's packets leave 0.2 ms or 1.8 ms apart as often as 1 ms: a measurement over one short
  interval would read that as 5000 packets/s. A periodic application reads as its own rate, a sender
  held back by the pacer as the allowed rate, and an idle period, one long gap, pulls it down;
* the share of departures the pacer held back (the application offered them before they were
  allowed to leave): below one half, the application sets the pace.
"""

from __future__ import annotations

import math
from typing import Final

GAP_GAIN: Final = 0.125
"""Gain of both moving averages (about the last eight packets)."""


class SendMeter:
    """Departure gaps and paced departures, as moving averages."""

    __slots__ = ("gap_avg", "last_send", "paced_avg")

    def __init__(self) -> None:
        self.last_send: float | None = None
        self.gap_avg: float | None = None
        """Moving average of the gaps between departures, seconds (``None`` before two)."""
        self.paced_avg = 0.0
        """Moving share of departures the pacer held back."""

    def on_departure(self, now: float, paced: bool) -> None:
        last = self.last_send
        if last is not None:
            gap = now - last
            avg = self.gap_avg
            self.gap_avg = gap if avg is None else avg + GAP_GAIN * (gap - avg)
        self.paced_avg += GAP_GAIN * ((1.0 if paced else 0.0) - self.paced_avg)
        self.last_send = now

    @property
    def app_limited(self) -> bool:
        """The application, not the pacer, sets the pace (most departures left when offered)."""
        return self.paced_avg < 0.5

    def send_rate(self) -> float:
        """Packets/s actually sent: 0 before two departures, ``math.inf`` for back-to-back ones."""
        gap = self.gap_avg
        if gap is None:
            return 0.0
        return 1.0 / gap if gap > 0.0 else math.inf
