"""The age of delivered samples: a fixed-size log histogram for the median and the 99th percentile.

A connection delivers a thousand samples a second or more for hours, so it cannot keep their ages in a
list. :class:`SampleAgeHistogram` counts them in :data:`BINS` logarithmic bins instead: bin ``i``
holds ages in ``[FLOOR * GROWTH**i, FLOOR * GROWTH**(i + 1))``, 10 µs to about 90 s in steps of 2 %,
the first bin also everything shorter and the last everything longer. A quantile is read as the
geometric middle of the bin it falls in, so it is within 1 % of the nearest-rank quantile of the exact
ages (over the whole covered range). Memory is one list of ``BINS`` integers whatever the run length;
adding an age costs at most one logarithm.

Where the ages come from is :mod:`tdtp.session.connection`'s business (docs/PROTOCOL.md section 3.6).
"""

from __future__ import annotations

import math
import sys
from typing import Final

FLOOR: Final = 1e-5
"""Seconds: the lower edge of the first bin (ages below it are counted there)."""
GROWTH: Final = 1.02
"""Each bin is 2 % wider than the one before it."""
BINS: Final = 810
"""Bins: ``FLOOR * GROWTH**BINS`` is about 90 s, beyond any age a live session sees."""
_LOG_GROWTH: Final = math.log(GROWTH)
_LOG_FLOOR: Final = math.log(FLOOR)
_MIDDLE: Final = math.sqrt(GROWTH)
_MARGIN: Final = 1e-9
"""Relative: how far inside its true edges a bin's fast-path range stays. The logarithm's rounding
moves an index by some 1e-13 at most, the margin by 5e-8: an age inside the range is in the bin."""
_LOWS: Final = [-math.inf] + [
    FLOOR * math.exp(i * _LOG_GROWTH) * (1 + _MARGIN) for i in range(1, BINS)
]
_HIGHS: Final = [
    FLOOR * math.exp((i + 1) * _LOG_GROWTH) * (1 - _MARGIN) for i in range(BINS - 1)
] + [sys.float_info.max]
"""Each bin's fast-path range (the first bin also takes everything below it, the last everything
finite above it)."""


class SampleAgeHistogram:
    """Counts of sample ages in logarithmic bins; :meth:`quantile` reads them back."""

    __slots__ = ("_bins", "_counted", "_high", "_last", "_low", "run", "run_high", "run_low")

    def __init__(self) -> None:
        self._bins = [0] * BINS
        self._low = BINS  # the lowest and highest bins in use: a quantile walks only those
        self._high = -1
        self._counted = 0  # ages in the bins
        self._last = -1  # the bin of the last age added (none yet)
        self.run_low = math.inf
        self.run_high = -math.inf
        """(Almost) the range of ages that fall in the last age's bin: the next sample's age mostly
        does (the estimate is constant between RTT samples, a timed age moves by microseconds)."""
        self.run = 0
        """Ages in that range not yet put into the bin (when an age falls in another bin, or a
        quantile is read). ``if run_low <= age <= run_high: run += 1`` is :meth:`add`'s first
        step, which a per-sample caller may take itself."""

    @property
    def count(self) -> int:
        """Ages added so far."""
        return self._counted + self.run

    def add(self, age: float) -> None:
        """Count one age in seconds (zero, negative or NaN ages land in the first bin)."""
        if self.run_low <= age <= self.run_high:
            self.run += 1
            return
        if self.run:
            self._settle()
        index = 0
        if age > FLOOR:
            index = int((math.log(age) - _LOG_FLOOR) / _LOG_GROWTH)
            if index >= BINS:
                index = BINS - 1
        self._bins[index] += 1
        self._counted += 1
        self._last = index
        self.run_low = _LOWS[index]
        self.run_high = _HIGHS[index]
        if index < self._low:
            self._low = index
        if index > self._high:
            self._high = index

    def _settle(self) -> None:
        """Put the run of ages counted in the last bin's range into that bin."""
        run = self.run
        self._bins[self._last] += run
        self._counted += run
        self.run = 0

    def quantile(self, fraction: float) -> float:
        """The nearest-rank quantile (``fraction`` in 0..1) as its bin's geometric middle, in
        seconds; 0.0 before any age was added."""
        if self.run:
            self._settle()
        count = self._counted
        if not count:
            return 0.0
        rank = max(1, math.ceil(fraction * count))
        bins = self._bins
        seen = 0
        index = self._low
        high = self._high
        while index < high:
            seen += bins[index]
            if seen >= rank:
                break
            index += 1
        return FLOOR * math.exp(index * _LOG_GROWTH) * _MIDDLE
