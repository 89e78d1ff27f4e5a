"""RFC 5348 loss intervals and RFC 6298 RTT smoothing, against hand-computed values."""

from __future__ import annotations

import pytest

from tdtp.session.loss_rate import LossIntervalEstimator
from tdtp.session.rtt import RttEstimator


def test_no_loss_means_p_zero() -> None:
    estimator = LossIntervalEstimator(0)
    assert estimator.update(10_000) == 0.0


def test_regular_losses_give_p_one_over_the_interval() -> None:
    estimator = LossIntervalEstimator(0)
    for k in range(1, 12):
        estimator.on_packet_lost(100 * k, float(k), 0.05, 100 * k)
    # Eight closed intervals of 100, open interval of 1 (ignored: it would raise p).
    assert estimator.loss_event_rate == pytest.approx(1 / 100)


def test_losses_within_one_rtt_are_one_event() -> None:
    estimator = LossIntervalEstimator(0)
    assert estimator.on_packet_lost(50, 1.000, 0.1, 60)
    assert not estimator.on_packet_lost(51, 1.050, 0.1, 60)
    assert not estimator.on_packet_lost(55, 1.100, 0.1, 60)
    assert estimator.on_packet_lost(70, 1.101, 0.1, 80)


def test_weighted_mean_and_the_open_interval_rule() -> None:
    estimator = LossIntervalEstimator(0)
    starts = [10, 30, 60, 100, 150]  # intervals 10, 20, 30, 40, 50 (newest last)
    for i, start in enumerate(starts):
        estimator.on_packet_lost(start, float(i), 0.01, start)
    # Closed, newest first: 50, 40, 30, 20, 10 with weights 1, 1, 1, 1, 0.8.
    closed = (50 + 40 + 30 + 20 + 0.8 * 10) / 4.8
    assert estimator.loss_event_rate == pytest.approx(1 / closed)
    # A long open interval (1000 since seq 150) raises the mean, so it counts.
    with_open = (1001 + 50 + 40 + 30 + 0.8 * 20 + 0.6 * 10) / (4 + 0.8 + 0.6)
    assert estimator.update(1150) == pytest.approx(1 / with_open)


def test_rtt_smoothing_follows_rfc_6298() -> None:
    rtt = RttEstimator(0.1)
    assert not rtt.has_sample and rtt.srtt == 0.1
    rtt.on_sample(0.040)
    assert (rtt.srtt, rtt.rttvar) == (0.040, 0.020)
    rtt.on_sample(0.048)
    # rttvar = 0.75 * 0.020 + 0.25 * |0.040 - 0.048| = 0.017; srtt = 0.875 * 0.040 + 0.125 * 0.048
    assert rtt.rttvar == pytest.approx(0.017)
    assert rtt.srtt == pytest.approx(0.041)
    assert rtt.min_rtt == 0.040
    rtt.on_sample(-1.0)  # a hold longer than the true delay cannot make the RTT negative
    assert rtt.latest > 0
