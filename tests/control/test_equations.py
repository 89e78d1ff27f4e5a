"""The paper's eqs. 1 and 2 and RFC 5348's equation against values worked out by hand."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

import tdtp.control
from tdtp.control import padhye_rate, tcp_friendly_rate, tfrc_rate


def test_eq2_hand_computed() -> None:
    # sqrt(3) / (0.1 * sqrt(2 * 0.01)) = 1.7320508 / (0.1 * 0.1414214) = 1.7320508 / 0.01414214
    #                                  = 122.47449 packets/s  (= sqrt(150) / 0.1)
    assert tcp_friendly_rate(0.1, 0.01) == pytest.approx(122.474487, rel=1e-7)
    # p = 0.5: sqrt(2p) = 1, so sqrt(3) / 0.05 = 34.641016
    assert tcp_friendly_rate(0.05, 0.5) == pytest.approx(34.641016, rel=1e-7)
    # 2p = 0.0012 = 3 * 0.0004, sqrt(2p) = 0.02 * sqrt(3): sqrt(3) / (0.2 * 0.02 * sqrt(3)) = 250
    assert tcp_friendly_rate(0.2, 0.0006) == pytest.approx(250.0, rel=1e-12)
    # p = 0.375, rtt = 1: sqrt(3) / sqrt(0.75) = sqrt(4) = 2
    assert tcp_friendly_rate(1.0, 0.375) == pytest.approx(2.0, rel=1e-12)


def test_eq1_hand_computed() -> None:
    # rtt = 0.1, p = 0.01, rto = 0.4:
    #   rtt * sqrt(2p/3)                   = 0.1 * 0.0816497         = 0.00816497
    #   rto * 3 sqrt(3p/8) * p * (1+32p^2) = 0.4 * 3 * 0.0612372 * 0.01 * 1.0032 = 0.00073720
    #   1 / (0.00816497 + 0.00073720)      = 1 / 0.00890217          = 112.3322 packets/s
    assert padhye_rate(0.1, 0.01, 0.4) == pytest.approx(112.3322, rel=1e-6)
    # rtt = 1, p = 0.375, rto = 1: sqrt(2p/3) = sqrt(0.25) = 0.5, sqrt(3p/8) = sqrt(0.140625) = 0.375,
    #   32 p^2 = 4.5, so the denominator is 0.5 + 3 * 0.375 * 0.375 * 5.5 = 0.5 + 2.3203125 = 2.8203125
    assert padhye_rate(1.0, 0.375, 1.0) == pytest.approx(1.0 / 2.8203125, rel=1e-12)


def test_rfc5348_equation_in_bytes() -> None:
    # s = 100 bytes, t_RTO = 4 R = 0.4: 100 * 112.3322 bytes/s
    assert tfrc_rate(100.0, 0.1, 0.01) == pytest.approx(11233.22, rel=1e-6)
    assert tfrc_rate(100.0, 0.1, 0.01) == pytest.approx(100.0 * padhye_rate(0.1, 0.01, 0.4))


def test_no_loss_means_no_bound() -> None:
    assert tcp_friendly_rate(0.1, 0.0) == math.inf
    assert padhye_rate(0.1, 0.0, 0.4) == math.inf
    assert tfrc_rate(100.0, 0.1, 0.0) == math.inf


def test_public_names() -> None:
    assert tdtp.control.tcp_friendly_rate(0.1, 0.01) == tcp_friendly_rate(0.1, 0.01)
    assert tdtp.control.padhye_rate is padhye_rate


@pytest.mark.parametrize(
    ("rtt", "p", "word"),
    [
        (0.0, 0.01, "rtt"),
        (-0.1, 0.01, "rtt"),
        (math.nan, 0.01, "rtt"),
        (math.inf, 0.01, "rtt"),
        (0.1, -0.01, "p must"),
        (0.1, 1.5, "p must"),
        (0.1, math.nan, "p must"),
    ],
)
def test_bad_arguments_raise(rtt: float, p: float, word: str) -> None:
    with pytest.raises(ValueError, match=word):
        tcp_friendly_rate(rtt, p)
    with pytest.raises(ValueError, match=word):
        padhye_rate(rtt, p, 0.4)


def test_percentages_are_rejected_with_a_hint() -> None:
    with pytest.raises(ValueError, match="not a percentage"):
        tcp_friendly_rate(0.1, 5.0)


@pytest.mark.parametrize("rto", [0.0, -1.0, math.nan, math.inf])
def test_bad_rto_raises(rto: float) -> None:
    with pytest.raises(ValueError, match="rto"):
        padhye_rate(0.1, 0.01, rto)


def test_bad_packet_size_raises() -> None:
    with pytest.raises(ValueError, match="packet size"):
        tfrc_rate(0.0, 0.1, 0.01)


rtts = st.floats(min_value=1e-4, max_value=10.0)
probabilities = st.floats(min_value=1e-7, max_value=1.0)


@given(rtt=rtts, p=probabilities, factor=st.floats(min_value=1.01, max_value=100.0))
def test_rates_fall_with_loss_and_rtt(rtt: float, p: float, factor: float) -> None:
    assert tcp_friendly_rate(rtt * factor, p) < tcp_friendly_rate(rtt, p)
    assert padhye_rate(rtt * factor, p, 4 * rtt * factor) < padhye_rate(rtt, p, 4 * rtt)
    if p * factor <= 1.0:
        assert tcp_friendly_rate(rtt, p * factor) < tcp_friendly_rate(rtt, p)
        assert padhye_rate(rtt, p * factor, 4 * rtt) < padhye_rate(rtt, p, 4 * rtt)


@given(rtt=rtts, p=probabilities)
def test_eq1_never_exceeds_eq2_and_meets_it_at_low_loss(rtt: float, p: float) -> None:
    # eq. 1 only adds a (timeout) term to eq. 2's denominator.
    assert padhye_rate(rtt, p, 4 * rtt) <= tcp_friendly_rate(rtt, p) * (1 + 1e-12)
    # ...a term of order p^(3/2) against p^(1/2): at p = 1e-6 they agree to about 0.5 %.
    low = 1e-6
    assert padhye_rate(rtt, low, 4 * rtt) / tcp_friendly_rate(rtt, low) > 0.99
