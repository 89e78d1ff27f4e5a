"""The teleop controller's decisions on fake time: random loss holds, a growing queue cuts, the
byte-based TCP-friendly ceiling, the opt-in floor, and its config's validation."""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable

import pytest

from tdtp.control import TeleopConfig, TeleopController, create_controller
from tdtp.control.equations import padhye_rate
from tdtp.control.teleop import (
    LIMIT_APPLICATION,
    LIMIT_FLOOR,
    LIMIT_STALLED,
    LIMIT_TCP_FRIENDLY,
)

SIZE = 105  # a 100-byte sample and the 5-byte header


def drive(
    controller: TeleopController,
    *,
    duration: float,
    rtt: Callable[[float], float],
    start: float = 0.0,
    demand: float = 1000.0,
    lose: Callable[[int], bool] = lambda _: False,
    p: Callable[[float], float] = lambda _: 0.0,
) -> float:
    """A ``demand`` Hz application through the controller's pacer; each packet is acknowledged one
    ``rtt(send time)`` later (or reported lost then, as a loss event). Returns the end time."""
    step = 0.0001
    now = start
    next_tick = start
    pending = False
    paced = False
    in_flight: deque[tuple[float, float, bool]] = deque()  # (due, rtt, lost)
    srtt = rtt(start)
    index = 0
    while now < start + duration:
        while in_flight and in_flight[0][0] <= now:
            _, sample, lost = in_flight.popleft()
            srtt += 0.125 * (sample - srtt)
            if lost:
                controller.on_loss_event(now=now, srtt=srtt, loss_event_rate=p(now))
            else:
                controller.on_ack(
                    now=now,
                    acked=1,
                    rtt_sample=sample,
                    srtt=srtt,
                    rttvar=0.0,
                    loss_event_rate=p(now),
                )
        if now >= next_tick:
            paced = pending  # a newer sample replaces one still waiting
            pending = True
            next_tick += 1.0 / demand
        if pending and now >= controller.next_send_time():
            if not paced and now > next_tick - 1.0 / demand + step:
                paced = True  # it had to wait
            controller.on_packet_sent(now=now, size=SIZE, paced=paced)
            sample = rtt(now)
            in_flight.append((now + sample, sample, lose(index)))
            index += 1
            pending = paced = False
        timer = controller.get_timer()
        if timer is not None and now >= timer:
            controller.on_timer(now=now)
        now += step
    return now


def flat(value: float) -> Callable[[float], float]:
    return lambda _: value


def test_random_loss_on_a_path_whose_delay_is_not_rising_holds_the_rate() -> None:
    controller = TeleopController()
    drive(
        controller,
        duration=5.0,
        rtt=flat(0.040),
        lose=lambda i: i % 50 == 25,  # 2 % loss, one loss event every 50 ms
        p=lambda _: 0.02,
    )
    assert controller.losses_ignored > 50
    assert controller.loss_decrease_count == 0
    assert controller.delay_decrease_count == 0
    assert controller.rate >= 1000.0  # the 1 kHz loop is never held back
    assert controller.rate_limit == LIMIT_APPLICATION


def test_a_sustained_queue_above_the_target_cuts_the_rate() -> None:
    controller = TeleopController()
    end = drive(controller, duration=2.0, rtt=flat(0.040))
    assert controller.rate >= 1000.0
    # A queue building up: the RTT grows 50 ms per second from 2 s on.
    drive(controller, start=end, duration=1.0, rtt=lambda t: 0.040 + 0.05 * (t - end))
    assert controller.delay_decrease_count >= 1
    assert controller.rate < 1000.0
    assert controller.queue_delay > controller.config.target_queue_delay


def test_a_jittery_path_whose_floor_rises_with_the_rate_is_not_a_queue() -> None:
    # RTT samples spread over 20 ms at random; then the floor rises 8 ms (a FIFO with random delays
    # holds a fast flow's packets behind slower ones). A flat 8 ms rise would be a queue to cut;
    # with that jitter it is within 1.5 x the jitter the threshold allows.
    rng = random.Random(5)
    controller = TeleopController()
    end = drive(controller, duration=2.0, rtt=lambda _: 0.040 + rng.uniform(0.0, 0.020))
    drive(controller, start=end, duration=2.0, rtt=lambda _: 0.048 + rng.uniform(0.0, 0.020))
    assert controller.jitter == pytest.approx(0.0067, abs=0.0015)  # E|U - U'| of U(0, 20 ms)
    assert controller.delay_decrease_count == 0
    assert controller.rate >= 1000.0


def test_the_same_rise_without_jitter_is_a_queue() -> None:
    controller = TeleopController()
    end = drive(controller, duration=2.0, rtt=flat(0.040))
    drive(controller, start=end, duration=2.0, rtt=flat(0.052))
    assert controller.jitter < 0.0005
    assert controller.delay_decrease_count >= 1


def test_a_queue_far_above_the_target_is_cut_after_one_interval() -> None:
    # A start-up into a bottleneck: the standing RTT jumps 30 ms (six times the 5 ms target) in
    # one interval; jitter cannot explain that, so it is cut without waiting for a second.
    controller = TeleopController()
    end = drive(controller, duration=1.0, rtt=flat(0.040))
    nominal = max(0.040, controller.config.interval)
    drive(controller, start=end, duration=2.6 * nominal, rtt=flat(0.070))
    assert controller.delay_decrease_count == 1


def test_a_control_interval_is_at_most_twice_the_base_rtt() -> None:
    # A queue that stretches the RTT to 200 ms does not stretch the decisions that drain it.
    controller = TeleopController()
    end = drive(controller, duration=1.0, rtt=flat(0.030))
    drive(controller, start=end, duration=0.3, rtt=lambda t: 0.030 + (t - end) * 0.6)
    assert controller.base_rtt == pytest.approx(0.030, abs=0.002)
    assert controller.delay_decrease_count >= 1
    controller.on_ack(
        now=end + 0.31, acked=1, rtt_sample=0.2, srtt=0.2, rttvar=0.0, loss_event_rate=0
    )
    assert controller._nominal_interval() == pytest.approx(0.060, abs=0.004)  # not srtt's 200 ms


def test_queue_below_the_target_does_not_cut() -> None:
    controller = TeleopController(TeleopConfig(target_queue_delay=0.010))
    end = drive(controller, duration=2.0, rtt=flat(0.040))
    drive(controller, start=end, duration=2.0, rtt=flat(0.046))  # a 6 ms standing queue
    assert controller.delay_decrease_count == 0
    assert controller.rate >= 1000.0


def test_loss_with_a_growing_queue_cuts_the_rate() -> None:
    controller = TeleopController(TeleopConfig(target_queue_delay=0.020))
    end = drive(controller, duration=2.0, rtt=flat(0.040))
    drive(
        controller,
        start=end,
        duration=0.6,
        rtt=lambda t: 0.040 + 0.08 * (t - end),
        lose=lambda i: i % 50 == 25,
        p=lambda _: 0.02,
    )
    assert controller.loss_decrease_count >= 1
    assert controller.rate < 1000.0


def test_the_tcp_friendly_ceiling_counts_bytes_on_the_wire() -> None:
    controller = TeleopController(TeleopConfig(initial_rate=5000.0))
    drive(controller, duration=0.2, rtt=flat(0.100), p=lambda _: 0.0, demand=5000.0)
    for when in (0.21, 0.25):  # p is trusted from the second loss event (RFC 5348 6.3.1)
        controller.on_loss_event(now=when, srtt=0.1, loss_event_rate=0.05)
    controller.on_ack(now=0.3, acked=1, rtt_sample=0.1, srtt=0.1, rttvar=0.0, loss_event_rate=0.05)
    tcp_packets = padhye_rate(0.1, 0.05, 0.4)  # what a TCP gets in 1460-byte segments
    expected = 1460 * tcp_packets / (SIZE + 28)
    assert controller.ceiling == pytest.approx(expected)
    assert controller.rate == pytest.approx(expected)
    # About 11 times TCP's packet rate: the flow's bytes, headers counted, match TCP's.
    assert controller.rate / tcp_packets == pytest.approx(1460 / 133)
    assert controller.rate_limit == LIMIT_TCP_FRIENDLY


def test_a_loss_among_the_first_packets_does_not_throttle_the_loop() -> None:
    # The third packet is lost: p rests on a 3-packet first interval (1/3) until more arrive. The
    # ceiling would be ~30 packets/s; until a second loss event it stays at the rate in use.
    controller = TeleopController()
    drive(
        controller,
        duration=0.5,
        rtt=flat(0.040),
        lose=lambda i: i == 3,
        p=lambda t: 0.0 if t < 0.043 else 1 / 3 if t < 0.3 else 0.02,  # lost at 3 ms + 40 ms
    )
    assert controller.rate >= 1000.0  # (55/s here without the first-interval rule)
    assert controller.rate_limit == LIMIT_APPLICATION


def test_the_ceiling_gives_back_what_it_took_as_p_falls() -> None:
    controller = TeleopController()
    end = drive(controller, duration=1.0, rtt=flat(0.040))
    before = controller.rate
    for when in (end, end + 0.1):  # two loss events: p is trusted from now on
        controller.on_loss_event(now=when, srtt=0.04, loss_event_rate=0.01)
    assert controller.rate == before  # no queue in sight: random loss
    controller.on_ack(
        now=end + 0.2, acked=1, rtt_sample=0.04, srtt=0.04, rttvar=0.0, loss_event_rate=0.3
    )
    assert controller.rate < 0.1 * before
    assert controller.rate_limit == LIMIT_TCP_FRIENDLY
    # The open loss interval grows, p falls: the rate returns at once, not one probe at a time.
    controller.on_ack(
        now=end + 0.21, acked=1, rtt_sample=0.04, srtt=0.04, rttvar=0.0, loss_event_rate=0.001
    )
    assert controller.rate == before


def test_the_opt_in_floor_holds_against_congestion() -> None:
    floor = 600.0
    controller = TeleopController(TeleopConfig(min_rate=floor))
    end = drive(controller, duration=1.0, rtt=flat(0.040))
    drive(controller, start=end, duration=3.0, rtt=lambda t: 0.040 + 0.2 * (t - end))
    assert controller.delay_decrease_count >= 1
    assert controller.rate == floor
    assert controller.rate_limit == LIMIT_FLOOR


def test_without_the_floor_the_same_congestion_goes_lower() -> None:
    controller = TeleopController()
    end = drive(controller, duration=1.0, rtt=flat(0.040))
    drive(controller, start=end, duration=3.0, rtt=lambda t: 0.040 + 0.2 * (t - end))
    assert controller.rate < 600.0


class Counting(TeleopController):
    """Counts the packets the controller let go."""

    sent = 0

    def on_packet_sent(self, *, now: float, size: int, paced: bool = True) -> None:
        self.sent += 1
        super().on_packet_sent(now=now, size=size, paced=paced)


def test_before_any_acknowledgement_one_start_window_leaves_then_two_per_packet_acked() -> None:
    # Nothing comes back for a second: a 1 kHz loop sends its start window, not 1000 blind packets
    # into a path that may carry a third of them (docs/CONTROL.md 9.10).
    controller = Counting(TeleopConfig(start_window=10))
    end = drive(controller, duration=0.045, rtt=flat(1.0))
    assert controller.sent == 10
    assert controller.rate_limit == LIMIT_STALLED
    controller.on_ack(now=end, acked=3, rtt_sample=0.04, srtt=0.04, rttvar=0.0, loss_event_rate=0.0)
    drive(controller, start=end, duration=0.0095, rtt=flat(1.0))  # (the probe: at 59 ms)
    assert controller.sent == 16  # three acknowledged let six more go
    off = Counting(TeleopConfig(start_window=0))
    drive(off, duration=0.045, rtt=flat(1.0))
    assert off.sent >= 44  # the application's rate from the first packet


def test_the_start_reaches_the_loops_rate_within_a_few_round_trips_and_ends() -> None:
    controller = Counting()
    end = drive(controller, duration=0.3, rtt=flat(0.080))
    before = controller.sent
    drive(controller, start=end, duration=0.2, rtt=flat(0.080))
    assert controller.sent - before >= 199  # 1 kHz by 0.3 s on an 80 ms round trip
    assert controller.rate_limit == LIMIT_APPLICATION  # the start has handed over


def test_it_is_the_default_and_selectable_by_name() -> None:
    controller = create_controller("teleop")
    assert isinstance(controller, TeleopController)
    assert controller.config == TeleopConfig()
    assert controller.config.min_rate == 0.0  # the floor is opt-in


@pytest.mark.parametrize(
    ("field", "value", "words"),
    [
        ("target_queue_delay", 0.0, "target_queue_delay must be a positive"),
        ("target_queue_delay", math.inf, "target_queue_delay must be a positive"),
        ("min_rate", -1.0, "min_rate must be 0"),
        ("min_rate", 1e9, "min_rate must be 0"),
        ("initial_rate", 1.0, "initial_rate must lie between"),
        ("max_rate", math.inf, "max_rate must be finite"),
        ("lowest_rate", 0.0, "lowest_rate must be a positive"),
        ("interval", 0.0, "interval must be a positive"),
        ("base_window", 0.001, "base_window must be"),
        ("delay_decrease", 1.0, "delay_decrease must be strictly between"),
        ("loss_decrease", 0.0, "loss_decrease must be strictly between"),
        ("probe_gain", 2.0, "probe_gain must be positive"),
        ("ramp_gain", 1.5, "ramp_gain must be in"),
        ("ramp_reset", -1.0, "ramp_reset must be"),
        ("heavy_loss", 0.0, "heavy_loss must be"),
        ("tcp_segment", 0, "tcp_segment must be"),
        ("ip_overhead", -1, "ip_overhead must be"),
        ("app_headroom", 0.5, "app_headroom must be"),
        ("no_feedback_rtts", 0.5, "no_feedback_rtts must be"),
        ("initial_rtt", 0.0, "initial_rtt must be"),
        ("drain_every", 0.0, "drain_every must be"),
        ("drain_fraction", 1.0, "drain_fraction must be"),
        ("target_queue_delay", math.nan, "target_queue_delay must be"),
        ("start_window", -1, "start_window must be a whole number"),
        ("start_window", 4.5, "start_window must be a whole number"),
        ("start_window", True, "start_window must be a whole number"),
    ],
)
def test_config_validation(field: str, value: object, words: str) -> None:
    with pytest.raises(ValueError, match=f"TeleopConfig.{words}"):
        TeleopConfig(**{field: value})  # type: ignore[arg-type]
