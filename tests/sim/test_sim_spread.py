"""The median and its order-statistic confidence interval: exact coverage, the ranks chosen, and the
edge cases (few values, NaN)."""

from __future__ import annotations

import math
import random

import pytest

from tdtp.sim.spread import median_interval, quantile


def test_ranks_and_exact_coverage() -> None:
    ten = median_interval(range(10))
    # [x(2), x(9)]: 1 - 2 P(B <= 1) with B ~ Binomial(10, 1/2) = 1 - 2 * 11 / 1024
    assert (ten.low, ten.high, ten.median) == (1, 8, 4.5)
    assert ten.coverage == pytest.approx(1 - 22 / 1024)
    twenty = median_interval(reversed(range(20)))  # order of the input does not matter
    assert (twenty.low, twenty.high) == (5, 14)  # [x(6), x(15)]
    assert twenty.coverage == pytest.approx(0.9586, abs=1e-4)
    assert median_interval(range(20), 0.99).coverage >= 0.99


def test_few_values_give_the_range_with_its_true_coverage() -> None:
    five = median_interval([5.0, 1.0, 3.0, 2.0, 4.0])
    assert (five.low, five.median, five.high) == (1.0, 3.0, 5.0)
    assert five.coverage == pytest.approx(1 - 2 / 32)  # below 95 %, and said so
    one = median_interval([7.0])
    assert (one.low, one.median, one.high, one.n) == (7.0, 7.0, 7.0, 1)
    assert math.isnan(one.coverage)
    empty = median_interval([math.nan])
    assert empty.n == 0 and math.isnan(empty.median) and empty.format() == "-"
    assert empty.to_dict()["median"] is None
    with pytest.raises(ValueError, match="confidence"):
        median_interval([1.0], 1.5)


def test_the_interval_covers_the_true_median_as_often_as_it_says() -> None:
    rng = random.Random(4)
    trials = 4000
    hits = 0
    for _ in range(trials):
        m = median_interval([rng.expovariate(1.0) for _ in range(10)])
        hits += m.low <= math.log(2) <= m.high  # the exponential's median
    assert hits / trials == pytest.approx(1 - 22 / 1024, abs=0.01)


def test_quantile_interpolates() -> None:
    assert quantile([1.0, 2.0, 3.0, 4.0], 0.5) == 2.5
    assert quantile([1.0, 2.0, 3.0, 4.0], 0.1) == pytest.approx(1.3)
    assert math.isnan(quantile([], 0.5))
