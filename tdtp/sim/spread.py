"""The spread of a result over seeds: the median and a distribution-free confidence interval for it.

With ``n`` independent runs (seeds) of one configuration, sorted ``x(1) <= ... <= x(n)``, the interval
``[x(k), x(n + 1 - k)]`` contains the true median with probability ``1 - 2 P(B <= k - 1)`` where
``B ~ Binomial(n, 1/2)``, whatever the distribution of the result (the *order-statistic* interval, e.g.
Conover, *Practical Nonparametric Statistics*, section 3.2). :func:`median_interval` takes the
narrowest such interval whose coverage is at least the confidence asked for: ``[x(2), x(9)]`` (97.9 %)
for 10 seeds, ``[x(6), x(15)]`` (95.9 %) for 20. It is exact and deterministic, unlike a bootstrap,
which with 10 runs resamples too few distinct values to estimate the tails of a median. Below 6 runs no
order-statistic interval reaches 95 %; the range ``[x(1), x(n)]`` is returned with its true, lower
coverage, and the coverage is always reported beside the interval.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from typing import Any

__all__ = ["INTERVAL_METHOD", "MedianInterval", "median_interval", "quantile"]

INTERVAL_METHOD = "order-statistic (distribution-free) confidence interval of the median"


@dataclass(frozen=True, slots=True)
class MedianInterval:
    """The median of ``n`` values and a confidence interval for the true median."""

    median: float
    low: float
    high: float
    coverage: float
    """Exact probability that ``[low, high]`` holds the true median (``nan`` with fewer than 2 values)."""
    n: int
    """Values counted (NaN values are left out)."""

    def to_dict(self, digits: int = 4) -> dict[str, Any]:
        """JSON-ready: the median and bounds rounded to ``digits``, the coverage to 3, NaN as None."""
        out: dict[str, Any] = {}
        for key, value in asdict(self).items():
            if isinstance(value, float):
                places = 3 if key == "coverage" else digits
                out[key] = round(value, places) if math.isfinite(value) else None
            else:
                out[key] = value
        return out

    def format(self, spec: str = ".2f") -> str:
        """``1.23 [1.10, 1.40]``."""
        if self.n == 0:
            return "-"
        return f"{self.median:{spec}} [{self.low:{spec}}, {self.high:{spec}}]"


def _binomial_cdf_half(n: int, k: int) -> float:
    """``P(B <= k)`` for ``B ~ Binomial(n, 1/2)``."""
    if k < 0:
        return 0.0
    return math.fsum(math.comb(n, i) for i in range(min(k, n) + 1)) / 2.0**n


def quantile(ordered: list[float], q: float) -> float:
    """The ``q`` quantile (0-1) of sorted values, interpolating linearly between order statistics."""
    if not ordered:
        return math.nan
    pos = (len(ordered) - 1) * q
    low = math.floor(pos)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (pos - low)


def median_interval(values: Iterable[float], confidence: float = 0.95) -> MedianInterval:
    """The median of ``values`` and its order-statistic interval of at least ``confidence``."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be between 0 and 1, got {confidence!r}")
    ordered = sorted(v for v in values if not math.isnan(v))
    n = len(ordered)
    if n == 0:
        return MedianInterval(math.nan, math.nan, math.nan, math.nan, 0)
    median = quantile(ordered, 0.5)
    if n == 1:
        return MedianInterval(median, ordered[0], ordered[0], math.nan, 1)
    tail = (1.0 - confidence) / 2.0
    k = 1  # 1-based rank of the lower bound
    while k + 1 <= (n + 1) // 2 and _binomial_cdf_half(n, k) <= tail:
        k += 1
    coverage = 1.0 - 2.0 * _binomial_cdf_half(n, k - 1)
    return MedianInterval(median, ordered[k - 1], ordered[n - k], coverage, n)
