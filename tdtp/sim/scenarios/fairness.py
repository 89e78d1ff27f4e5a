"""Fairness between TDTP sessions: several sessions starting one after another on one bottleneck."""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

from tdtp.sim.endpoints import TdtpSession
from tdtp.sim.engine import Network
from tdtp.sim.metrics import FlowRecorder, jain_index, mean
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
class FairnessRun:
    scheme: str
    flows: int
    starts: list[float]
    converged_from: float
    jain_times: list[float]
    jain_ms: list[float | None]
    """Jain's index of the active flows' master-to-slave goodput, per bin."""
    jain_sm: list[float | None]
    mean_jain_ms: float
    """Mean of the per-bin index after convergence."""
    min_jain_ms: float
    jain_of_means_ms: float
    """Jain's index of each flow's mean goodput after convergence."""
    mean_jain_sm: float
    per_flow_kbps: list[float]
    """Each flow's mean M->S goodput after convergence."""
    wall_time: float


@dataclass
class FairnessResult(ScenarioResult):
    scenario: ClassVar[str] = "fairness"
    params: dict[str, Any]
    runs: list[FairnessRun]

    def headline(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for run in self.runs:
            out.setdefault(run.scheme, {})[f"N={run.flows}"] = {
                "mean_jain": run.mean_jain_ms,
                "min_jain": run.min_jain_ms,
                "jain_of_means": run.jain_of_means_ms,
                "mean_jain_S->M": run.mean_jain_sm,
            }
        return json_safe(out)  # type: ignore[no-any-return]

    def details(self) -> dict[str, Any]:
        return {"runs": [asdict(r) for r in self.runs]}


def fairness(
    *,
    seed: int = 1,
    flow_counts: Sequence[int] = (2, 4, 8),
    schemes: Sequence[str] = DEFAULT_SCHEMES,
    capacity_mbps: float = 1.0,
    stagger: float = 5.0,
    settle: float = 40.0,
    convergence: float = 10.0,
    bin_width: float = 1.0,
    sample_rate: float = 1000.0,
    encapsulation: Encapsulation = "native",
    send_jitter: float = SEND_JITTER,
) -> FairnessResult:
    """N sessions (M_i behind R1, S_i behind R2) share a ``capacity_mbps`` bottleneck (10 ms, DropTail
    15); session i opens at ``i * stagger`` s; the run lasts ``settle`` s after the last start, and the
    flows count as converged ``convergence`` s after it (at most half of ``settle``). Jain's index per
    ``bin_width`` s bin."""
    convergence = min(convergence, settle / 2)
    chosen = schemes_named(schemes)
    runs: list[FairnessRun] = []
    for n in flow_counts:
        duration = (n - 1) * stagger + settle
        converged = (n - 1) * stagger + convergence
        for scheme in chosen:
            rng = random.Random(seed)
            net = Network(seed=seed)
            build_dumbbell(
                net,
                [f"M{i}" for i in range(n)],
                [f"S{i}" for i in range(n)],
                f"rate {capacity_mbps * 1e6:g}bit delay 10ms limit {ROUTER_QUEUE}",
            )
            starts = [i * stagger + rng.random() * 0.01 for i in range(n)]
            sessions = [
                TdtpSession.create(
                    net,
                    f"M{i}",
                    f"S{i}",
                    connection_config(scheme, encapsulation),
                    name=f"flow {i}",
                    sample_rate=sample_rate,
                    ip_overhead=ip_overhead(encapsulation),
                    start=starts[i],
                    bin_width=bin_width,
                    duration=duration,
                    seed=rng.getrandbits(32),
                    send_jitter=send_jitter,
                )
                for i in range(n)
            ]
            wall = run_timed(net, duration)
            nbins = sessions[0].ms.nbins
            times = [(b + 0.5) * bin_width for b in range(nbins)]
            jain_ms = _jain_series([x.ms for x in sessions], starts, bin_width)
            jain_sm = _jain_series([x.sm for x in sessions], starts, bin_width)
            after_ms = [
                j for t, j in zip(times, jain_ms, strict=True) if t >= converged and j is not None
            ]
            after_sm = [
                j for t, j in zip(times, jain_sm, strict=True) if t >= converged and j is not None
            ]
            per_flow = [s.ms.summary(converged, duration).goodput_kbps for s in sessions]
            runs.append(
                FairnessRun(
                    scheme=scheme.key,
                    flows=n,
                    starts=starts,
                    converged_from=converged,
                    jain_times=times,
                    jain_ms=jain_ms,
                    jain_sm=jain_sm,
                    mean_jain_ms=mean(after_ms),
                    min_jain_ms=min(after_ms) if after_ms else math.nan,
                    jain_of_means_ms=jain_index(per_flow),
                    mean_jain_sm=mean(after_sm),
                    per_flow_kbps=per_flow,
                    wall_time=wall,
                )
            )
    params = {
        "seed": seed,
        "flow_counts": list(flow_counts),
        "schemes": list(schemes),
        "capacity_mbps": capacity_mbps,
        "stagger": stagger,
        "settle": settle,
        "convergence": convergence,
        "bin_width": bin_width,
        "sample_rate": sample_rate,
        "encapsulation": encapsulation,
        "send_jitter": send_jitter,
    }
    return FairnessResult(params=params, runs=runs)


def _jain_series(
    recorders: Sequence[FlowRecorder], starts: Sequence[float], bin_width: float
) -> list[float | None]:
    """Jain's index per bin over the flows started at least two bins before it (None below two)."""
    out: list[float | None] = []
    for b in range(recorders[0].nbins):
        t0 = b * bin_width
        active = [
            r for r, start in zip(recorders, starts, strict=True) if start + 2 * bin_width <= t0
        ]
        out.append(jain_index([r.delivered_bytes[b] for r in active]) if len(active) >= 2 else None)
    return out
