"""Sample time and age (docs/PROTOCOL.md section 3.6), in fake time.

A sample whose header acknowledges one of the receiver's packets is timed by that round trip: its
send time on the receiver's clock is the arrival minus half the round trip, wrong by at most
``(R - min_rtt) / 2`` when both directions share the base delay. The fake network knows every
datagram's true one-way delay, so each test compares the estimate with the truth.
"""

from __future__ import annotations

import math
import random
import statistics

import pytest

from tdtp import ConnectionConfig, DataReceived
from tdtp.session.sample_age import BINS, SampleAgeHistogram
from tests.pair import Direction, Pair

BASE = 0.010


class RecordingDirection(Direction):
    """A direction that remembers each data packet's one-way delay by the sample stamp it carries."""

    def __init__(self, delay: float, jitter: float = 0.0, seed: int = 0) -> None:
        rng = random.Random(seed)
        extra = [rng.uniform(0.0, jitter) for _ in range(200_000)] if jitter else None
        super().__init__(
            delay=delay, extra_delay=(lambda i: extra[i]) if extra else (lambda i: 0.0)
        )
        self.delays: dict[bytes, float] = {}

    def admit(self, datagram: bytes) -> tuple[float, bytes] | None:
        admitted = super().admit(datagram)
        if admitted is not None and datagram[0] >> 6 == 0:  # DATA: the payload starts with a stamp
            self.delays[datagram[5:9]] = admitted[0]
        return admitted


def run_pair(
    *, ms_jitter: float = 0.0, sm_jitter: float = 0.0, master_rate: float, slave_rate: float
) -> tuple[Pair, RecordingDirection]:
    ms = RecordingDirection(BASE, ms_jitter, seed=1)
    sm = RecordingDirection(BASE, sm_jitter, seed=2)
    # No reorder wait: the truth compared with is the network's one-way delay, and a sample that
    # waited would be older by its wait (tests/test_reorder_wait.py checks that).
    config = ConnectionConfig(controller="fixed", max_reorder_wait=0.0)
    pair = Pair(config, config, ms=ms, sm=sm)
    pair.open()
    pair.start_samples(master_rate, slave_rate)
    pair.run_for(3.0)
    pair.drain()
    return pair, ms


def errors(received: list[DataReceived], truth: RecordingDirection) -> list[tuple[float, float]]:
    """(estimated age - true one-way delay, the round trip R) of every timed sample."""
    out = []
    for sample in received:
        if sample.sent_at is None:
            continue
        age = sample.age
        assert age is not None
        assert sample.received_at - sample.sent_at == pytest.approx(age)
        out.append((age - truth.delays[sample.payload[:4]], 2 * age))
    return out


def test_constant_symmetric_delay_gives_the_exact_age() -> None:
    pair, ms = run_pair(master_rate=1000, slave_rate=1000)
    received = pair.slave.received
    timed = errors(received, ms)
    assert len(timed) >= 0.99 * len(received) > 2500
    # Exact up to HOLD's rounding (the decoded hold is at most 3.1 % short of a hold under 1 ms).
    assert max(abs(error) for error, _ in timed) < 1e-5
    stats = pair.slave.conn.stats
    assert stats.samples_timed == len(timed)
    assert stats.sample_age_p50 == pytest.approx(BASE, rel=0.011)
    assert stats.sample_age_p99 == pytest.approx(BASE, rel=0.011)


def test_jitter_keeps_each_age_within_half_the_excess_round_trip() -> None:
    pair, ms = run_pair(ms_jitter=0.008, sm_jitter=0.008, master_rate=1000, slave_rate=1000)
    timed = errors(pair.slave.received, ms)
    assert len(timed) > 1000  # the jitter reorders; late samples are not delivered
    min_rtt = 2 * BASE
    for error, round_trip in timed:
        # The bound of section 3.6, plus HOLD's rounding (3.1 % of a hold of up to ~20 ms here).
        assert abs(error) <= (round_trip - min_rtt) / 2 + 4e-4
    # Symmetric jitter: the split in the middle is unbiased, so the errors average out.
    assert abs(statistics.fmean(error for error, _ in timed)) < 5e-4


def test_a_one_way_stream_estimates_age_from_the_opening_round_trip() -> None:
    pair, _ = run_pair(master_rate=1000, slave_rate=0)
    received = pair.slave.received
    assert len(received) > 2500
    assert all(sample.sent_at is None for sample in received)  # no ACK of ours to time them
    # The slave's only round trip: its OPEN_ACK out, the master's first packet back.
    assert all(sample.estimated_age == pytest.approx(BASE) for sample in received)
    assert all(sample.age == pytest.approx(BASE) for sample in received)
    stats = pair.slave.conn.stats
    assert stats.samples_timed == 0
    assert stats.sample_age_p50 == pytest.approx(BASE, rel=0.011)
    # The master, which hears only ACKs, has its RTT estimate as before.
    assert pair.master.conn.stats.srtt == pytest.approx(2 * BASE, rel=0.05)


def test_a_sparse_reverse_stream_times_the_samples_it_can() -> None:
    # The slave sends 20 samples a second: the master's samples carry an ACK of the slave's newest
    # packet held up to 50 ms; those held under 31.7 ms are timed, the others take srtt / 2.
    pair, ms = run_pair(master_rate=1000, slave_rate=20)
    received = pair.slave.received
    timed = errors(received, ms)
    assert 0.3 * len(received) < len(timed) < 0.9 * len(received)
    assert max(abs(error) for error, _ in timed) < 5e-4  # HOLD's rounding on holds up to 31 ms
    for sample in received:
        age = sample.age
        assert age is not None and age == pytest.approx(BASE, rel=0.06)


def test_a_sample_without_any_estimate_has_no_age() -> None:
    sample = DataReceived(b"x", 1, None, 2.0)
    assert sample.sent_at is None and sample.age is None and sample.age_at(3.0) is None
    timed = DataReceived(b"x", 1, 0.02, 2.0, 1.99)
    assert timed.age == pytest.approx(0.01)
    assert timed.age_at(2.5) == pytest.approx(0.51)


def test_the_histogram_is_bounded_and_within_one_percent() -> None:
    rng = random.Random(5)
    histogram = SampleAgeHistogram()
    assert histogram.quantile(0.5) == 0.0
    ages = [rng.lognormvariate(math.log(0.02), 0.5) for _ in range(50_000)]
    for age in ages:
        histogram.add(age)
    ages.sort()
    for fraction in (0.01, 0.5, 0.9, 0.99):
        exact = ages[max(1, math.ceil(fraction * len(ages))) - 1]
        assert histogram.quantile(fraction) == pytest.approx(exact, rel=0.0101)
    assert len(histogram._bins) == BINS  # fixed size, whatever was added
    for odd in (0.0, -1.0, math.nan, 1e9):
        histogram.add(odd)
    assert histogram.count == 50_004
