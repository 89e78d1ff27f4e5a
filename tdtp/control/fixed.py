"""A constant-rate controller: the UDP-like baseline, and the unpaced sender for benchmarks."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from mypy_extensions import mypyc_attr

from tdtp.control.base import NO_LIMIT, PacingSchedule, RateController

__all__ = ["FixedConfig", "FixedRateController"]


@mypyc_attr(native_class=False)  # a plain class: __post_init__ judges the types
@dataclass(frozen=True, slots=True)
class FixedConfig:
    """Configuration of :class:`FixedRateController`."""

    rate: float = 1000.0
    """Packets per second; ``math.inf`` sends every packet as soon as the application offers it."""

    def __post_init__(self) -> None:
        if not (self.rate > 0.0):  # also rejects NaN; math.inf is allowed
            raise ValueError(
                f"FixedConfig.rate must be a positive number of packets per second or math.inf "
                f"(no pacing), got {self.rate!r}"
            )


@mypyc_attr(allow_interpreted_subclasses=True)
class FixedRateController(RateController):
    """Paces data packets at a configured rate and ignores all feedback (no congestion control).

    This is what UDP plus a sampling timer gives a teleoperation application: it is neither
    TCP-friendly nor fair, and exists as the baseline the other controllers are measured against.
    """

    name: ClassVar[str] = "fixed"

    def __init__(self, config: FixedConfig | None = None) -> None:
        self._config = config if config is not None else FixedConfig()
        self._rate = self._config.rate
        self._paced = self._rate != math.inf  # unpaced: the schedule stays at NO_LIMIT
        self._schedule = PacingSchedule()

    @property
    def config(self) -> FixedConfig:
        """The configuration this controller runs with."""
        return self._config

    @property
    def rate(self) -> float:
        return self._rate

    def next_send_time(self) -> float:
        if not self._paced:
            return NO_LIMIT
        return self._schedule.next_departure

    def on_packet_sent(self, *, now: float, size: int, paced: bool = True) -> None:
        if self._paced:
            self._schedule.on_departure(now, self._rate)

    def on_ack(
        self,
        *,
        now: float,
        acked: int,
        rtt_sample: float | None,
        srtt: float,
        rttvar: float,
        loss_event_rate: float,
    ) -> None:
        pass

    def on_loss_event(self, *, now: float, srtt: float, loss_event_rate: float) -> None:
        pass

    def get_timer(self) -> float | None:
        return None

    def on_timer(self, *, now: float) -> None:
        pass
