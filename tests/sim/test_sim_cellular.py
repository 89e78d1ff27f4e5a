"""The cellular scenario's yardsticks (the figures, the ideal, what the trace allowed) and its runs over
synthetic traces in virtual time. The recorded traces are the benchmark's (benchmarks/cellular.py)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tdtp.sim.scenarios.cellular import (
    Arrivals,
    allowed,
    deadline,
    direction_figures,
    ideal,
    run_tdtp,
    run_udp,
)


@pytest.fixture
def trace_file(tmp_path: Path) -> Callable[[list[int]], str]:
    def write(times: list[int]) -> str:
        path = tmp_path / f"t{len(list(tmp_path.iterdir()))}.trace"
        path.write_text("".join(f"{t}\n" for t in times))
        return str(path)

    return write


def test_direction_figures_from_arrivals() -> None:
    # 1000 samples generated over 1 s; every one delivered 25 ms later except those of
    # [0.5, 0.7): a 200 ms hole, two dropout windows of the receiver's timeline.
    arrivals = Arrivals(0.0, 1.0, 1000)
    for k in range(1000):
        g = k / 1000
        if not 0.5 <= g < 0.7:
            arrivals.generated.append(g)
            arrivals.arrived.append(g + 0.025)
    figures = direction_figures(arrivals, propagation=0.020)
    assert figures["delivered"] == 800 and figures["samples_per_s"] == 800.0
    assert figures["delay_ms"]["p50"] == pytest.approx(25.0)
    assert figures["delay_ms"]["p99"] == pytest.approx(25.0)
    assert figures["windows"] == 10
    assert figures["dropouts"] == 1  # [0.52, 0.62) is empty; its neighbours have a sample each
    assert figures["longest_gap_ms"] == pytest.approx(201.0)
    assert figures["age_ms"]["p50"] == pytest.approx(25.0, abs=1.0)
    assert figures["age_ms"]["p99"] > 190.0  # the hole, as the receiver saw it


def test_ideal_with_ample_capacity_delivers_every_sample_at_the_next_opportunity(
    trace_file,
) -> None:  # type: ignore[no-untyped-def]
    # An opportunity every 2 ms, 1500 bytes: 11 samples of 128 bytes, far more than 2 ms brings.
    spec = f"delay 20ms trace {trace_file(list(range(2, 1001, 2)))}"
    arrivals = ideal(spec, start=0.0, duration=1.0)
    assert len(arrivals.arrived) == 1000
    delays = [a - g for g, a in zip(arrivals.generated, arrivals.arrived, strict=True)]
    assert min(delays) > 0.020 and max(delays) <= 0.022 + 1e-9
    assert allowed(spec, start=0.0, duration=1.0) == pytest.approx(1000)


def test_ideal_skips_what_does_not_fit_instead_of_queueing(trace_file) -> None:  # type: ignore[no-untyped-def]
    # One opportunity every 20 ms: 20 samples waiting, 1500 bytes carry 11 of 128 bytes (and the
    # bytes left over carry on while samples are waiting): the newest go, the rest are skipped.
    spec = f"trace {trace_file(list(range(20, 1001, 20)))}"
    arrivals = ideal(spec, start=0.0, duration=1.0)
    per_second = 50 * 1500 / 128
    assert len(arrivals.arrived) == pytest.approx(per_second, abs=2)
    delays = [a - g for g, a in zip(arrivals.generated, arrivals.arrived, strict=True)]
    assert max(delays) <= 0.0125  # only the newest samples before each opportunity
    assert allowed(spec, start=0.0, duration=1.0) == pytest.approx(per_second, rel=0.01)


def test_the_deadline_oracle_delivers_a_burst_oldest_first_within_its_bound(trace_file) -> None:  # type: ignore[no-untyped-def]
    # Three opportunities at the end of every 30 ms (33 samples' worth): the ideal sends only the
    # newest 11 each time; the oracle carries all 30 waiting, oldest first, each within 50 ms.
    spec = f"delay 20ms trace {trace_file([30, 30, 30])}"
    assert len(ideal(spec, start=0.0, duration=0.9).arrived) == pytest.approx(330, abs=11)
    full = deadline(spec, start=0.0, duration=0.9, bound=0.060)
    assert len(full.arrived) == 900
    delays = [a - g for g, a in zip(full.generated, full.arrived, strict=True)]
    assert max(delays) <= 0.050 + 1e-9
    # A tighter bound: samples older than 15 ms at an opportunity can no longer make it; given up.
    tight = deadline(spec, start=0.0, duration=0.9, bound=0.035)
    delays = [a - g for g, a in zip(tight.generated, tight.arrived, strict=True)]
    assert len(tight.arrived) == pytest.approx(450, abs=30)
    assert max(delays) <= 0.035 + 1e-9
    assert sorted(tight.generated) == tight.generated  # oldest first, never reordered


def test_allowed_is_zero_in_an_outage_and_follows_the_offset(trace_file) -> None:  # type: ignore[no-untyped-def]
    times = [*range(1, 501), 1000]  # capacity for 500 ms, then none until the loop at 1 s
    path = trace_file(times)
    # 100 samples in each of the first five windows, none in the next four, then the opportunity at
    # 1000 ms carries 1500 / 128 of the last window's 100.
    assert allowed(f"trace {path}", start=0.0, duration=1.0) == pytest.approx(500 + 1500 / 128)
    # 500 ms in, the outage comes first.
    assert allowed(f"trace {path} offset 500ms", start=0.0, duration=0.4) == 0


def test_raw_udp_over_a_slow_trace_queues_then_drops(trace_file) -> None:  # type: ignore[no-untyped-def]
    # 1500 bytes every 20 ms both ways: 586 packets/s of 128 bytes (1 kHz offered) through a
    # 15 kB queue: it fills, then drops what does not fit; nothing is lost otherwise.
    path = trace_file(list(range(20, 1001, 20)))
    spec = f"delay 20ms trace {path} limit-bytes 15000"
    run = run_udp(spec, spec, duration=2.0)
    for way in ("ms", "sm"):
        figures, link = run.figures[way], run.links[way]
        assert link["packets"] == 2000 == link["delivered"] + link["dropped"]
        assert link["dropped"] > 0
        assert figures["delivered"] == link["delivered"]
        # The link's rate over the 2 s, plus the full queue drained after the window.
        assert figures["samples_per_s"] == pytest.approx(
            (2 * 1500 / 128 / 0.020 + 117) / 2, rel=0.02
        )
        # A full 15 kB queue holds 117 packets: ~200 ms at 586/s, plus the propagation.
        assert 200 < figures["delay_ms"]["p99"] < 250


def test_a_tdtp_session_runs_over_two_different_traces(trace_file) -> None:  # type: ignore[no-untyped-def]
    fast = f"delay 20ms trace {trace_file(list(range(1, 1001)))} limit-bytes 150000"
    slow = f"delay 20ms trace {trace_file(list(range(20, 1001, 20)))} limit-bytes 15000"
    run = run_tdtp(fast, slow, "teleop", duration=3.0, seed=2)
    ms, sm = run.figures["ms"], run.figures["sm"]
    assert ms["offered"] == sm["offered"] == 3000
    assert 0 < sm["delivered"] <= sm["offered"] and 0 < ms["delivered"] <= ms["offered"]
    # Nothing arrives faster than the propagation delay, and the slow direction carries less.
    assert ms["delay_ms"]["p50"] >= 20.0 and sm["delay_ms"]["p50"] >= 20.0
    assert sm["delivered"] < ms["delivered"]
    assert run.senders["sm"]["samples_offered"] >= 3000
    link = run.links["sm"]  # (the sessions still exchange a packet now and then at the end)
    assert 0 <= link["packets"] - link["delivered"] - link["dropped"] <= 2
