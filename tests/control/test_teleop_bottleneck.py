"""The teleop controller behind a bottleneck below the stream's rate, in virtual time (the connection
and the in-process netem link of ``benchmarks/virtual_paths.py``: no clock, no machine load)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def _virtual_paths() -> ModuleType:
    spec = importlib.util.spec_from_file_location("virtual_paths", BENCHMARKS / "virtual_paths.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("virtual_paths", module)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    ("profile", "p99_ms"),
    [("rate 500kbit", 150.0), ("delay 20ms rate 500kbit", 190.0)],  # issue 19's bars
)
def test_a_bottleneck_below_the_stream_keeps_the_queue_short_and_the_link_busy(
    profile: str, p99_ms: float
) -> None:
    # Both ways 1 kHz of 100-byte samples into 500 kbit/s (~595 packets/s): after the start-up's
    # overshoot a decrease remembers what the path carried, not the doubled allowance, so the
    # recovery that follows does not refill the queue (before: 186/195 ms p99 20 ms away).
    report = _virtual_paths().run(profile, "teleop", seed=1, duration=6.0, rate=1000.0, size=100)
    for direction in ("M->S", "S->M"):
        figures = report[direction]
        assert figures["latency_p99_ms"] <= p99_ms * 0.6, direction
        assert figures["link_use"] >= 0.85, direction


def test_the_start_up_does_not_fill_a_slow_deep_bottleneck() -> None:
    # Issue 32: 1 kHz of 100-byte samples each way into 300 kbit/s (~330 packets/s) 20 ms away, a
    # 3000-packet queue, the start-up counted. Sent at 1 kHz until the first feedback, which the
    # other direction's queue delayed, each end had put ~100 samples (0.3 s) in its queue before it
    # heard anything: p99 183 / 349 ms over the first 2 s. The start window (docs/CONTROL.md 9.10)
    # lets one window go, then two per packet acknowledged, until the queue shows.
    report = _virtual_paths().run(
        "delay 20ms rate 300kbit limit 3000",
        "teleop",
        seed=1,
        duration=2.0,
        rate=1000.0,
        size=100,
        warmup=0.0,
    )
    for direction in ("M->S", "S->M"):
        figures = report[direction]
        assert figures["latency_p99_ms"] <= 150.0, direction
        assert figures["newest_per_s"] >= 280.0, direction  # (the link carries ~330/s)
