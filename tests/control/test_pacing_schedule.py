"""PacingSchedule: the long-run rate is the allowed rate, late wake-ups do not drift it, a stall
buys at most one catch-up packet, and reschedule re-aims a pending deadline both ways."""

from __future__ import annotations

import itertools
import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tdtp.control import NO_LIMIT, PacingSchedule


def depart_greedily(
    rate: float, duration: float, lateness: list[float] | None = None
) -> list[float]:
    """A sender that always has data and wakes at each deadline (plus ``lateness[i]``)."""
    schedule = PacingSchedule()
    now = 0.0
    times: list[float] = []
    i = 0
    while now < duration:
        schedule.on_departure(now, rate)
        times.append(now)
        late = lateness[i % len(lateness)] if lateness else 0.0
        i += 1
        now = max(now, schedule.next_departure) + late
    return times


def test_long_run_rate_equals_allowed_rate() -> None:
    times = depart_greedily(1000.0, 10.0)
    # 10 000 gaps in 10 s plus the single catch-up packet the first departure allows.
    assert 10_000 <= len(times) <= 10_002


@settings(max_examples=30, deadline=None)
@given(
    rate=st.floats(min_value=10.0, max_value=5000.0),
    seed=st.integers(min_value=0, max_value=2**32 - 1),
)
def test_late_wakeups_do_not_drift(rate: float, seed: int) -> None:
    rng = random.Random(seed)
    gap = 1.0 / rate
    # Every wake-up is late by up to 90 % of a gap: a relative scheduler (now + gap) would lose
    # about 45 % of the rate; the absolute schedule loses nothing.
    lateness = [rng.uniform(0.0, 0.9 * gap) for _ in range(997)]
    duration = 2000 * gap
    times = depart_greedily(rate, duration, lateness)
    assert rate * duration - 1 <= len(times) <= rate * duration + 2


@settings(max_examples=30, deadline=None)
@given(
    rate=st.floats(min_value=10.0, max_value=5000.0),
    stalls=st.lists(st.floats(min_value=0.0, max_value=50.0), min_size=1, max_size=20),
)
def test_a_stall_buys_at_most_one_catch_up_packet(rate: float, stalls: list[float]) -> None:
    """Wake-ups late by any number of gaps: every window of length T holds <= rate*T + 2 packets,
    and after each stall at most one packet leaves early (less than a gap after the previous)."""
    gap = 1.0 / rate
    schedule = PacingSchedule()
    now = 0.0
    times: list[float] = []
    for stall in stalls:
        for _ in range(5):  # a few on-time departures, then a wake-up ``stall`` gaps late
            schedule.on_departure(now, rate)
            times.append(now)
            now = max(now, schedule.next_departure)
        now += stall * gap
    short_gaps = sum(1 for a, b in itertools.pairwise(times) if b - a < gap * (1 - 1e-9))
    assert short_gaps <= len(stalls) + 1  # one per stall, one for the very first departure
    for i, start in enumerate(times):
        window = 3 * gap
        inside = sum(1 for t in times[i:] if t < start + window)
        assert inside <= rate * window + 2 + 1e-9


def test_first_departure_allows_one_catch_up_then_paces() -> None:
    schedule = PacingSchedule()
    assert schedule.next_departure == NO_LIMIT
    schedule.on_departure(0.0, 100.0)
    assert schedule.next_departure == 0.0  # the one catch-up packet
    schedule.on_departure(0.0, 100.0)
    assert schedule.next_departure == pytest.approx(0.01)
    schedule.on_departure(0.01, 100.0)
    assert schedule.next_departure == pytest.approx(0.02)


def test_reschedule_after_a_decrease_pushes_the_deadline_back() -> None:
    schedule = PacingSchedule()
    schedule.on_departure(0.0, 1000.0)
    schedule.on_departure(0.0, 1000.0)
    assert schedule.next_departure == pytest.approx(0.001)
    schedule.reschedule(0.0002, 100.0)  # the rate fell tenfold before the next packet left
    assert schedule.next_departure == pytest.approx(0.01)


def test_reschedule_after_an_increase_pulls_the_deadline_in_but_not_before_now() -> None:
    schedule = PacingSchedule()
    schedule.on_departure(0.0, 4.0)
    schedule.on_departure(0.0, 4.0)
    assert schedule.next_departure == pytest.approx(0.25)
    schedule.reschedule(0.002, 1000.0)  # last slot 0.0 + 1 ms is already past: leave now
    assert schedule.next_departure == pytest.approx(0.002)
    schedule.on_departure(0.002, 1000.0)
    assert schedule.next_departure == pytest.approx(0.003)
    schedule.reschedule(0.0025, 500.0)
    assert schedule.next_departure == pytest.approx(0.004)


def test_reschedule_leaves_a_reached_deadline_alone() -> None:
    schedule = PacingSchedule()
    schedule.on_departure(0.0, 10.0)
    schedule.on_departure(0.0, 10.0)
    schedule.reschedule(0.5, 1.0)
    assert schedule.next_departure == pytest.approx(0.1)


def test_infinite_rate_and_reset_mean_no_limit() -> None:
    schedule = PacingSchedule()
    schedule.on_departure(0.0, math.inf)
    assert schedule.next_departure == NO_LIMIT
    schedule.on_departure(0.0, 10.0)
    schedule.on_departure(0.0, 10.0)
    schedule.reschedule(0.01, math.inf)
    assert schedule.next_departure == NO_LIMIT
    schedule.on_departure(0.0, 10.0)
    schedule.on_departure(0.0, 10.0)
    schedule.reset()
    assert schedule.next_departure == NO_LIMIT
