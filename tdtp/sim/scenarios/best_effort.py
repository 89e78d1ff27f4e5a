"""Best effort: how fast a session takes capacity that becomes free, and gives it back."""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

from tdtp.sim.endpoints import CbrSource, TdtpSession
from tdtp.sim.engine import Network
from tdtp.sim.readings import SEND_JITTER
from tdtp.sim.scenarios.dumbbell import (
    ROUTER_QUEUE,
    build_dumbbell,
    run_timed,
)
from tdtp.sim.scenarios.results import ScenarioResult, json_safe
from tdtp.sim.scenarios.schemes import (
    DEFAULT_SCHEMES,
    Encapsulation,
    connection_config,
    ip_overhead,
    schemes_named,
)


@dataclass
class BestEffortRun:
    scheme: str
    free_level_kbps: float
    """tdtp M->S goodput over the last half of the free period."""
    congested_level_kbps: float
    """...over the last half of the first period with the UDP source on."""
    fill_time_50: float | None
    """Seconds after the UDP source stopped until tdtp's goodput (0.5 s average) first reached the
    middle between its congested and free levels."""
    fill_time_90: float | None
    """...90 % of the way from the congested to the free level."""
    give_back_time: float | None
    """Seconds after the UDP source restarted until tdtp's goodput fell back below what is left
    for it plus 10 % of the capacity."""
    cbr_loss_after_restart: float
    """Loss ratio of the UDP source in the first 2 s after it restarted."""
    cbr_loss_steady: float
    """...in its last 5 s on."""
    wall_time: float
    series_time: list[float]
    tdtp_kbps: list[float]
    """tdtp M->S goodput per bin."""
    cbr_kbps: list[float]
    tdtp_sm_kbps: list[float]


@dataclass
class BestEffortResult(ScenarioResult):
    scenario: ClassVar[str] = "best-effort"
    params: dict[str, Any]
    runs: list[BestEffortRun]

    def headline(self) -> dict[str, Any]:
        return json_safe(  # type: ignore[no-any-return]
            {
                r.scheme: {
                    "congested_level_kbps": r.congested_level_kbps,
                    "free_level_kbps": r.free_level_kbps,
                    "fill_time_50_s": r.fill_time_50,
                    "fill_time_90_s": r.fill_time_90,
                    "give_back_time_s": r.give_back_time,
                    "cbr_loss_after_restart": r.cbr_loss_after_restart,
                    "cbr_loss_steady": r.cbr_loss_steady,
                }
                for r in self.runs
            }
        )

    def details(self) -> dict[str, Any]:
        return {"runs": [asdict(r) for r in self.runs]}


def best_effort(
    *,
    seed: int = 1,
    duration: float = 60.0,
    schemes: Sequence[str] = DEFAULT_SCHEMES,
    capacity_mbps: float = 1.0,
    cbr_kbps: float = 600.0,
    bin_width: float = 0.1,
    sample_rate: float = 1000.0,
    encapsulation: Encapsulation = "native",
    send_jitter: float = SEND_JITTER,
) -> BestEffortResult:
    """One session on a ``capacity_mbps`` bottleneck (10 ms, DropTail 15). An unresponsive UDP source
    of ``cbr_kbps`` (1000-byte packets) crosses it master-to-slave during the first and the last third
    of the run and is off in the middle third: capacity freed, then taken back."""
    chosen = schemes_named(schemes)
    third = duration / 3
    runs: list[BestEffortRun] = []
    smooth = max(1, round(0.5 / bin_width))
    for scheme in chosen:
        rng = random.Random(seed)
        net = Network(seed=seed)
        build_dumbbell(
            net,
            ["M", "U1"],
            ["S", "U2"],
            f"rate {capacity_mbps * 1e6:g}bit delay 10ms limit {ROUTER_QUEUE}",
        )
        session = TdtpSession.create(
            net,
            "M",
            "S",
            connection_config(scheme, encapsulation),
            sample_rate=sample_rate,
            ip_overhead=ip_overhead(encapsulation),
            bin_width=bin_width,
            duration=duration,
            seed=rng.getrandbits(32),
            send_jitter=send_jitter,
        )
        cbr = CbrSource(
            net,
            "U1",
            "U2",
            rate_bps=cbr_kbps * 1000,
            periods=((0.0, third), (2 * third, duration)),
            bin_width=bin_width,
            duration=duration,
        )
        wall = run_timed(net, duration)
        rec = session.ms
        smoothed = rec.rate_series(smooth)
        times = rec.bin_times()
        congested = rec.summary(third / 2, third).goodput_kbps
        free_level = rec.summary(1.5 * third, 2 * third).goodput_kbps

        window = smooth * bin_width
        mid = congested + 0.5 * (free_level - congested)
        high = congested + 0.9 * (free_level - congested)
        fill50 = _first_crossing(times, smoothed, window, third, 2 * third, above=mid)
        fill90 = _first_crossing(times, smoothed, window, third, 2 * third, above=high)
        capacity_kbps = capacity_mbps * 1000
        give_back_level = (capacity_kbps - cbr_kbps) + 0.1 * capacity_kbps
        give_back = _first_crossing(
            times, smoothed, window, 2 * third, duration, below=give_back_level
        )
        runs.append(
            BestEffortRun(
                scheme=scheme.key,
                free_level_kbps=free_level,
                congested_level_kbps=congested,
                fill_time_50=fill50,
                fill_time_90=fill90,
                give_back_time=give_back,
                cbr_loss_after_restart=cbr.recorder.summary(2 * third, 2 * third + 2.0).loss_ratio,
                cbr_loss_steady=cbr.recorder.summary(duration - 5.0, duration).loss_ratio,
                wall_time=wall,
                series_time=times,
                tdtp_kbps=rec.rate_series(),
                cbr_kbps=cbr.recorder.rate_series(),
                tdtp_sm_kbps=session.sm.rate_series(),
            )
        )
    params = {
        "seed": seed,
        "duration": duration,
        "schemes": list(schemes),
        "capacity_mbps": capacity_mbps,
        "cbr_kbps": cbr_kbps,
        "cbr_on": [[0.0, third], [2 * third, duration]],
        "bin_width": bin_width,
        "sample_rate": sample_rate,
        "encapsulation": encapsulation,
        "send_jitter": send_jitter,
    }
    return BestEffortResult(params=params, runs=runs)


def _first_crossing(
    times: Sequence[float],
    averaged: Sequence[float],
    window: float,
    after: float,
    until: float,
    *,
    above: float | None = None,
    below: float | None = None,
) -> float | None:
    """Seconds from ``after`` until the first moving average (over ``window`` s, ending with its bin)
    that lies entirely after ``after`` and is at least ``above`` (or at most ``below``)."""
    half = (times[1] - times[0]) / 2 if len(times) > 1 else 0.0
    for t, value in zip(times, averaged, strict=True):
        end = t + half
        if end - window < after - 1e-9 or end > until + 1e-9:
            continue
        if (above is not None and value >= above) or (below is not None and value <= below):
            return round(end - after, 6)
    return None
