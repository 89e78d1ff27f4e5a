"""Token buckets: one for the slave's replies to unvalidated sources, one per source for its OPENs.

The per-source table is bounded: past ``max_sources`` the least recently seen source is forgotten
(it starts again with a full bucket, which an attacker with that many addresses could have anyway).
"""

from __future__ import annotations

from collections import OrderedDict


class TokenBucket:
    """``rate`` tokens per second, at most ``burst`` saved up."""

    __slots__ = ("_last", "_tokens", "burst", "rate")

    def __init__(self, rate: float, burst: float, now: float = 0.0) -> None:
        self.rate = rate
        self.burst = burst
        self._tokens = burst
        self._last = now

    def take(self, now: float) -> bool:
        """Spend one token if there is one."""
        elapsed = now - self._last
        if elapsed > 0.0:
            self._tokens = min(self.burst, self._tokens + elapsed * self.rate)
            self._last = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False


class SourceRateLimiter:
    """A token bucket per source address (host and port), in a bounded LRU table.

    Keyed on the whole address, not the host: forged datagrams from a master's host with other ports
    (which an off-path attacker can send, not knowing the master's port) do not touch the master's
    own bucket."""

    __slots__ = ("_buckets", "_burst", "_max_sources", "_rate")

    def __init__(self, rate: float, burst: float, max_sources: int) -> None:
        self._rate = rate
        self._burst = burst
        self._max_sources = max_sources
        self._buckets: OrderedDict[object, TokenBucket] = OrderedDict()

    def __len__(self) -> int:
        return len(self._buckets)

    def allow(self, source: object, now: float) -> bool:
        buckets = self._buckets
        bucket = buckets.get(source)
        if bucket is None:
            if len(buckets) >= self._max_sources:
                buckets.popitem(last=False)
            bucket = buckets[source] = TokenBucket(self._rate, self._burst, now)
        else:
            buckets.move_to_end(source)
        return bucket.take(now)
