"""Smoothed RTT and RTT variation, RFC 6298 style, fed with hold-corrected samples."""

from __future__ import annotations

from typing import Final

MIN_RTT_SAMPLE: Final = 1e-6
"""Samples are clamped to at least one microsecond (a hold time can only make a sample shorter)."""


class RttEstimator:
    """``srtt``/``rttvar`` with gains 1/8 and 1/4; the first sample sets srtt and rttvar = sample/2."""

    __slots__ = ("has_sample", "latest", "min_rtt", "rttvar", "srtt")

    def __init__(self, initial_rtt: float) -> None:
        self.srtt = initial_rtt
        self.rttvar = initial_rtt / 2
        self.latest = initial_rtt
        self.min_rtt = float("inf")
        self.has_sample = False

    def on_sample(self, sample: float) -> None:
        # (max, min and abs written out: this runs for nearly every acknowledgement)
        if sample < MIN_RTT_SAMPLE:
            sample = MIN_RTT_SAMPLE
        self.latest = sample
        if sample < self.min_rtt:
            self.min_rtt = sample
        if not self.has_sample:
            self.srtt = sample
            self.rttvar = sample / 2
            self.has_sample = True
            return
        srtt = self.srtt
        deviation = srtt - sample if srtt >= sample else sample - srtt
        self.rttvar += 0.25 * (deviation - self.rttvar)
        self.srtt = srtt + 0.125 * (sample - srtt)
