"""The teleop controller's configuration: every field, its default and what it accepts.

:class:`TeleopConfig` is a frozen dataclass that validates itself; a wrong value raises
:class:`ValueError` naming the field and what it accepts. docs/CONTROL.md section 9 argues every
default. The controller is :mod:`tdtp.control.teleop`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mypy_extensions import mypyc_attr

__all__ = ["TeleopConfig"]


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise ValueError(f"TeleopConfig.{message}")


def positive_finite(value: float) -> bool:
    return 0.0 < value < math.inf


@mypyc_attr(native_class=False)  # a plain class: __post_init__ judges the types
@dataclass(frozen=True, slots=True)
class TeleopConfig:
    """Configuration of :class:`~tdtp.control.teleop.TeleopController`; docs/CONTROL.md section 9 argues every default."""

    target_queue_delay: float = 0.005
    """Seconds of queueing the flow tolerates before it slows down (a few ms: haptics)."""
    min_rate: float = 0.0
    """Opt-in floor, packets/s, held whatever the path signals (0 = off). Gives up fairness."""
    initial_rate: float = 1000.0
    """Packets/s before any feedback: a 1 kHz loop is not throttled at start."""
    max_rate: float = 100_000.0
    """Ceiling, packets/s."""
    lowest_rate: float = 4.0
    """Liveness floor, packets/s: one packet per 250 ms keeps feedback flowing in a blackout."""
    interval: float = 0.025
    """Shortest control interval, seconds (an interval is ``max(srtt, interval)``): long enough that a
    1 kHz stream's RTT samples in one interval show the queue's floor through jitter."""
    base_window: float = 10.0
    """Seconds over which the smallest standing RTT is the path's base RTT."""
    drain_every: float = 4.0
    """At most every this many seconds, and only after a loss event (losses with no queue in sight
    are what a hidden standing queue looks like), one control interval runs at ``drain_fraction`` of
    the rate, so that a queue this flow keeps standing drains and the base RTT is measured without it
    (BBR's ProbeRTT). Keep it below half of ``base_window``; ``math.inf`` never drains."""
    drain_fraction: float = 0.5
    """The rate during a drain interval, as a fraction of the rate in use."""
    delay_decrease: float = 0.85
    """A queue above the target sets the rate to this fraction of the rate the peer received."""
    loss_decrease: float = 0.5
    """A loss event with a growing queue multiplies the rate in use by this."""
    probe_gain: float = 0.05
    """Growth per interval once congestion has been seen (the search near the path's capacity)."""
    ramp_gain: float = 1.0
    """Growth per interval before congestion has been seen (1 = doubling, as slow start)."""
    ramp_reset: float = 5.0
    """Seconds without a congestion signal after which the ramp gain applies again."""
    heavy_loss: float = 0.1
    """Loss event rate above which loss alone cuts the rate by ``p / 2`` per interval (GCC's 10 %)."""
    tcp_segment: int = 1460
    """Segment size, bytes, of the TCP the byte-based ceiling compares the flow with."""
    ip_overhead: int = 28
    """Bytes below each datagram on the wire (IPv4 + UDP), counted against the flow."""
    app_headroom: float = 2.0
    """While the application sets the pace, the allowance grows to at most this multiple of its rate."""
    no_feedback_rtts: float = 4.0
    """Blackout: halve the rate after ``max(this * srtt, 2 / rate)`` without feedback (RFC 5348)."""
    start_window: int = 48
    """Packets in flight before the first acknowledgement; each one acknowledged lets two more go,
    until the first sign of a queue or the application's own rate (slow start, docs/CONTROL.md
    9.10). 48 is a 1 kHz loop's round trip on a 48 ms path, and 0.15 s of queue behind 300 kbit/s.
    ``0``: no start window (the full ``initial_rate`` from the first packet)."""
    initial_rtt: float = 0.5
    """srtt assumed before the first feedback."""
    blind_hold: float = 2.0
    """With one-way delays (a session with timestamps): seconds a direction whose peer has gone
    silent keeps the rate its receiver last reported, before the no-feedback back-off resumes (the
    way back may be what failed: docs/CONTROL.md 9.8). ``0``: back off at once, as without stamps."""

    def __post_init__(self) -> None:
        need = _check
        need(
            positive_finite(self.target_queue_delay),
            f"target_queue_delay must be a positive, finite number of seconds, "
            f"got {self.target_queue_delay!r} (0.005 is 5 ms)",
        )
        need(
            positive_finite(self.lowest_rate),
            f"lowest_rate must be a positive, finite rate in packets/s, got {self.lowest_rate!r}",
        )
        need(
            positive_finite(self.max_rate) and self.max_rate >= self.lowest_rate,
            f"max_rate must be finite and at least lowest_rate ({self.lowest_rate!r}), "
            f"got {self.max_rate!r}; use FixedConfig(rate=math.inf) for an unpaced sender",
        )
        need(
            0.0 <= self.min_rate <= self.max_rate,
            f"min_rate must be 0 (no floor) or a rate in packets/s up to max_rate "
            f"({self.max_rate!r}), got {self.min_rate!r}",
        )
        need(
            self.lowest_rate <= self.initial_rate <= self.max_rate,
            f"initial_rate must lie between lowest_rate ({self.lowest_rate!r}) and max_rate "
            f"({self.max_rate!r}), got {self.initial_rate!r}",
        )
        need(
            positive_finite(self.interval),
            f"interval must be a positive, finite number of seconds, got {self.interval!r}",
        )
        need(
            positive_finite(self.base_window) and self.base_window >= self.interval,
            f"base_window must be a finite number of seconds, at least interval "
            f"({self.interval!r}), got {self.base_window!r}",
        )
        need(
            self.drain_every > 0.0 and not math.isnan(self.drain_every),
            f"drain_every must be a positive number of seconds (math.inf: never), "
            f"got {self.drain_every!r}",
        )
        need(
            0.0 < self.drain_fraction < 1.0,
            f"drain_fraction must be strictly between 0 and 1, got {self.drain_fraction!r}",
        )
        need(
            0.0 < self.delay_decrease < 1.0,
            f"delay_decrease must be strictly between 0 and 1, got {self.delay_decrease!r}",
        )
        need(
            0.0 < self.loss_decrease < 1.0,
            f"loss_decrease must be strictly between 0 and 1, got {self.loss_decrease!r}",
        )
        need(
            positive_finite(self.probe_gain) and self.probe_gain <= self.ramp_gain,
            f"probe_gain must be positive and at most ramp_gain ({self.ramp_gain!r}), "
            f"got {self.probe_gain!r}",
        )
        need(
            0.0 < self.ramp_gain <= 1.0,
            f"ramp_gain must be in (0, 1] (1 doubles the rate per interval), got {self.ramp_gain!r}",
        )
        need(
            self.ramp_reset >= 0.0,
            f"ramp_reset must be a non-negative number of seconds, got {self.ramp_reset!r}",
        )
        need(
            0.0 < self.heavy_loss <= 1.0,
            f"heavy_loss must be a loss event rate in (0, 1], got {self.heavy_loss!r}",
        )
        need(
            isinstance(self.tcp_segment, int) and 1 <= self.tcp_segment <= 65535,
            f"tcp_segment must be a segment size in bytes (1..65535), got {self.tcp_segment!r}",
        )
        need(
            isinstance(self.ip_overhead, int) and 0 <= self.ip_overhead <= 1024,
            f"ip_overhead must be a number of bytes in 0..1024 (28 for IPv4 + UDP), "
            f"got {self.ip_overhead!r}",
        )
        need(
            self.app_headroom >= 1.0,
            f"app_headroom must be at least 1 (math.inf disables it), got {self.app_headroom!r}",
        )
        need(
            1.0 <= self.no_feedback_rtts < math.inf,
            f"no_feedback_rtts must be a finite number of RTTs, at least 1, "
            f"got {self.no_feedback_rtts!r}",
        )
        # (Read untyped: the compiled build checks an int field's type on a typed read, and would
        # raise TypeError for 4.5 instead of naming the field.)
        window: object = getattr(self, "start_window")  # noqa: B009
        need(
            isinstance(window, int) and not isinstance(window, bool) and 0 <= window <= 1_000_000,
            f"start_window must be a whole number of packets from 0 (off) to 1000000, "
            f"got {window!r}",
        )
        need(
            positive_finite(self.initial_rtt),
            f"initial_rtt must be a positive, finite number of seconds, got {self.initial_rtt!r}",
        )
        need(
            0.0 <= self.blind_hold < math.inf,
            f"blind_hold must be a finite number of seconds, at least 0, got {self.blind_hold!r}",
        )
