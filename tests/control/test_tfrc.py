"""TFRC (RFC 5348) sender: initial window, slow start, the equation with the 2 * X_recv limit,
the no-feedback timer, and its long-run TCP-friendliness through the path model."""

from __future__ import annotations

import itertools
import math

import pytest
from control_sim import Path, bernoulli, run

from tdtp.control import TfrcConfig, TfrcController, padhye_rate


def ack(c: TfrcController, now: float, *, srtt: float, p: float = 0.0, acked: int = 1) -> None:
    c.on_ack(now=now, acked=acked, rtt_sample=srtt, srtt=srtt, rttvar=0.0, loss_event_rate=p)


def test_initial_rate_then_the_rfc3390_window_per_rtt() -> None:
    c = TfrcController()
    assert c.rate == 1.0  # one packet per second until feedback (RFC 5348 section 4.2)
    c.on_packet_sent(now=0.0, size=125)
    ack(c, 0.05, srtt=0.05)
    # W_init = min(4 s, max(2 s, 4380)) = min(500, 4380) = 500 bytes = 4 packets; 4 / 0.05 s.
    assert c.rate == pytest.approx(80.0)
    c = TfrcController(TfrcConfig(packet_size=1500))
    c.on_packet_sent(now=0.0, size=125)  # the configured size wins over the measured one
    ack(c, 0.1, srtt=0.1)
    # min(6000, max(3000, 4380)) = 4380 bytes = 2.92 packets per 0.1 s
    assert c.rate == pytest.approx(29.2)


def test_slow_start_at_most_doubles_per_rtt_up_to_max_rate() -> None:
    rtt = 0.05
    c = TfrcController(TfrcConfig(max_rate=20_000.0))
    trace = run(c, Path(rtt=rtt), 40 * rtt)
    assert c.in_slow_start
    steps = [ch for ch in trace.changes if ch.after > ch.before][1:]  # after the first feedback
    assert len(steps) >= 5
    for ch in steps:
        assert ch.after <= 2 * ch.before * (1 + 1e-9)
    assert all(b.time - a.time >= rtt * (1 - 1e-9) for a, b in itertools.pairwise(steps))
    assert c.rate == 20_000.0
    assert max(ch.after for ch in trace.changes) == 20_000.0


def test_with_loss_the_rate_is_the_equation_limited_by_twice_the_receive_rate() -> None:
    rtt = 0.1
    c = TfrcController()
    now = 0.0
    for _ in range(200):  # 100 packets/s sent and acknowledged: X_recv ~ 100
        c.on_packet_sent(now=now, size=100)
        ack(c, now, srtt=rtt)
        now += 0.01
    assert c.x_recv == pytest.approx(100.0, rel=0.15)
    for p in (0.001, 0.05, 1.0):
        c.on_loss_event(now=now, srtt=rtt, loss_event_rate=p)
        expected = max(min(padhye_rate(rtt, p, 4 * rtt), 2 * c.x_recv), 1 / 64)
        assert c.rate == pytest.approx(expected)
        assert not c.in_slow_start
    # p = 0.001 gives X_eq = 366 > 2 X_recv; p = 0.05 gives 45.8; p = 1 gives 0.42 packets/s.
    assert c.rate == pytest.approx(padhye_rate(rtt, 1.0, 4 * rtt))


def test_application_limited_allowance_stays_within_twice_the_receive_rate() -> None:
    rtt, demand = 0.05, 1000.0
    c = TfrcController()
    trace = run(c, Path(rtt=rtt, demand=demand), 200 * rtt)
    # X <= 2 X_recv, and X_recv (packets acknowledged over a window of at least one RTT, the
    # window's first acknowledgement included) is at most demand + 1 / rtt.
    highest = max(ch.after for ch in trace.changes)
    assert highest <= 2 * (demand + 1 / rtt)
    assert trace.sent_between(50 * rtt, 200 * rtt) >= 0.99 * demand * 150 * rtt


# Same tolerance and reasoning as the trinomial test: 250+ loss events, eq. 1 within 3 % at one
# standard error of the measured p; 5 %.
@pytest.mark.parametrize(("p", "rtt", "rtts"), [(0.01, 0.05, 900), (0.05, 0.1, 600)])
def test_tcp_friendly_against_eq1(p: float, rtt: float, rtts: int) -> None:
    packets = events = 0
    seconds = 0.0
    for seed in range(3):
        c = TfrcController()
        trace = run(c, Path(rtt=rtt, loss=bernoulli(p, seed)), rtts * rtt)
        warm = trace.loss_events[10]
        packets += trace.sent_between(warm, rtts * rtt)
        events += sum(1 for t in trace.loss_events if t > warm)
        seconds += rtts * rtt - warm
    assert events >= 250
    assert packets / seconds <= padhye_rate(rtt, events / packets, 4 * rtt) * 1.05


def test_no_feedback_halves_per_timeout_down_to_min_rate() -> None:
    c = TfrcController(TfrcConfig(min_rate=1.0))
    c.on_packet_sent(now=0.0, size=125)
    ack(c, 0.1, srtt=0.1)
    assert c.rate == pytest.approx(40.0)  # 4 packets per 0.1 s
    now = 0.1
    halvings: list[tuple[float, float]] = []
    while now < 10.0:  # keep sending, never an acknowledgement
        before = c.rate
        timer = c.get_timer()
        assert timer is not None
        now = min(max(now, c.next_send_time()), timer)
        if now >= timer:
            c.on_timer(now=now)
        else:
            c.on_packet_sent(now=now, size=125)
        if c.rate < before:
            halvings.append((now, c.rate))
    # The timer runs max(4 R, 2 / X): 0.4 s while X >= 5, then 2 / X.
    assert [rate for _, rate in halvings[:6]] == pytest.approx([20.0, 10.0, 5.0, 2.5, 1.25, 1.0])
    gaps = [b - a for (a, _), (b, _) in itertools.pairwise([(0.1, 40.0), *halvings])]
    assert gaps[:5] == pytest.approx([0.4, 0.4, 0.4, 0.4, 0.8], abs=0.03)
    assert c.rate == 1.0
    assert c.backoff_count >= 6


def test_an_idle_sender_below_the_restart_rate_is_not_halved() -> None:
    c = TfrcController()
    c.on_packet_sent(now=0.0, size=125)
    ack(c, 0.1, srtt=0.1)  # X = 40 < 2 * W_init / R = 80, and p == 0
    for i in range(20):
        timer = c.get_timer()
        assert timer is not None
        c.on_timer(now=timer)
        assert c.rate == pytest.approx(40.0), i


def test_recovers_after_a_blackout_through_the_receive_rate() -> None:
    rtt, p = 0.05, 0.01
    c = TfrcController(TfrcConfig(max_rate=5000.0))
    trace = run(c, Path(rtt=rtt, blackouts=((3.0, 5.0),), report_p=p), 8.0)
    x_eq = padhye_rate(rtt, p, 4 * rtt)
    assert trace.rate_at(2.9) == pytest.approx(x_eq)
    assert trace.rate_at(4.99) < x_eq / 64  # halved at least six times
    assert min(ch.after for ch in trace.changes) >= c.config.min_rate
    assert c.rate == pytest.approx(x_eq)  # back on the equation...
    back = next(ch.time for ch in trace.changes if ch.time > 5.0 and ch.after >= x_eq * 0.999)
    assert back - 5.0 <= 2.0  # ...within 2 s (40 RTTs, most of them at a few packets/s)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("min_rate", 0.0),
        ("max_rate", math.inf),
        ("max_rate", 1e-3),
        ("initial_rate", 0.0),
        ("initial_rate", 1e9),
        ("packet_size", 0),
        ("packet_size", 1.5),
        ("initial_no_feedback_timeout", 0.0),
    ],
)
def test_config_validation_names_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"TfrcConfig\.{field} must"):
        TfrcConfig(**{field: value})  # type: ignore[arg-type]


@pytest.mark.parametrize("decrease", [0.85, 0.5, None])
def test_a_loss_in_a_data_limited_interval_caps_the_rate_below_the_receive_rate(
    decrease: float | None,
) -> None:
    """RFC 5348 section 4.3 step 4: after a loss in a data-limited interval (here a 1 kHz
    application whose equation rate, at a tiny p, is far above what it sends), ``recv_limit`` is
    ``max(X_recv_set)`` with the set halved and the new sample decayed, not twice it. Without the
    rule (``None``, the controller before the lock-out fix) the sender does not slow down at all."""
    rtt, demand, lost_seq = 0.04, 1000.0, 3000
    c = TfrcController(TfrcConfig(data_limited_decrease=decrease))
    trace = run(c, Path(rtt=rtt, demand=demand, loss=lambda seq, t: seq == lost_seq), 5.0)
    (event,) = trace.loss_events
    assert padhye_rate(rtt, 1 / lost_seq, 4 * rtt) > 1.5 * demand  # the equation is no limit
    lowest = min(trace.rate_at(event + k * rtt / 8) for k in range(16))
    if decrease is None:
        assert lowest >= demand
        assert trace.sent_between(event, event + 2 * rtt) >= 2 * demand * rtt - 1
    else:
        # X_recv is the demand (plus the one packet a window's edge can add): the cap is
        # decrease x X_recv, reached at the feedback that reports the loss.
        assert lowest <= decrease * (demand + 1 / rtt) * (1 + 1e-9)
        assert lowest >= decrease * demand * 0.9
    assert trace.sent_between(event + 10 * rtt, event + 20 * rtt) >= 0.99 * demand * 10 * rtt
