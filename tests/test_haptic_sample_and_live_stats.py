"""The demo's payload format and the statistics helpers behind the live display."""

from __future__ import annotations

import io
import math

import pytest

from tdtp.cli.live_stats import DirectionMeter, LatencyRecorder, LiveDisplay, percentile
from tdtp.teleop.haptic_sample import SAMPLE_SIZE, HapticSample, master_trajectory, slave_feedback


def test_sample_round_trip_and_padding() -> None:
    sample = HapticSample(12.5, 7, (0.1, -0.2, 0.3), (1.0, 2.0, -3.0))
    payload = sample.encode(100)
    assert len(payload) == 100 and payload[SAMPLE_SIZE:] == bytes(100 - SAMPLE_SIZE)
    decoded = HapticSample.decode(payload)
    assert decoded is not None
    assert decoded.sent_at == 12.5 and decoded.index == 7
    assert decoded.position == pytest.approx((0.1, -0.2, 0.3))
    assert HapticSample.decode(payload[: SAMPLE_SIZE - 1]) is None
    with pytest.raises(ValueError, match="at least 36 bytes"):
        sample.encode(10)


def test_the_wall_pushes_back_only_when_penetrated() -> None:
    outside = slave_feedback((0.04, 0.0, 0.0), 1, 0.0)
    inside = slave_feedback((0.06, 0.0, 0.0), 2, 0.0)
    assert outside.force == (0.0, 0.0, 0.0)
    assert inside.force[0] == pytest.approx(-5.0)
    # The operator reaches into the wall, presses and slides, and retreats, every 4 s.
    rest = master_trajectory(0.2, 0, 0.0).position
    pressing = master_trajectory(2.0, 1, 0.0).position
    assert rest[0] == pytest.approx(0.0, abs=2e-4) and pressing[0] == pytest.approx(0.06, abs=2e-4)
    assert slave_feedback(pressing, 2, 0.0).force[0] == pytest.approx(-5.0, abs=0.1)
    assert master_trajectory(6.0, 3, 0.0).position == pytest.approx(pressing, abs=1e-9)


def test_percentiles_and_latency_summary() -> None:
    values = sorted(float(i) for i in range(1, 101))
    assert percentile(values, 0.5) == 50.0 and percentile(values, 0.99) == 99.0
    assert math.isnan(percentile([], 0.5))
    recorder = LatencyRecorder()
    assert recorder.summary_ms() is None
    for i in range(1, 101):
        recorder.add(i / 1000)
    assert recorder.summary_ms() == {"p50": 50.0, "p99": 99.0, "max": 100.0}
    assert len(recorder.take_window()) == 100 and recorder.take_window() == []


def test_display_appends_when_not_a_terminal() -> None:
    stream = io.StringIO()
    display = LiveDisplay(stream)
    display.update(["a", "b"])
    display.update(["c", "d"])
    assert stream.getvalue() == "a\nb\nc\nd\n"  # no cursor movement in a log file


def test_the_live_line_starts_over_with_a_new_session_and_says_when_there_is_none() -> None:
    """After a reconnect the endpoint's counters are the new session's, from zero: the line shows
    the new session's rate, never a negative one (it showed "M->S -3084 pkt/s ... (-0.00%)")."""
    from tdtp.session.stats import ConnectionStats

    meter = DirectionMeter("M->S")
    old = ConnectionStats()
    old.sent.data_packets = old.packets_acked = 3084
    assert "3084 pkt/s" in meter.line(old, old.packets_acked, 1.0, None)
    new = ConnectionStats()  # the next session, 0.5 s old
    new.sent.data_packets = new.packets_acked = 500
    line = meter.line(new, new.packets_acked, 1.0, None)
    assert "M->S      500 pkt/s" in line and "(-" not in line
    gone = meter.line(new, new.packets_acked, 1.0, None, session="no session: reconnecting")
    assert gone == "M->S  no session: reconnecting"
