"""The fixed-rate baseline: paces at its rate, ignores every kind of feedback."""

from __future__ import annotations

import math

import pytest

from tdtp.control import NO_LIMIT, FixedConfig, FixedRateController


def test_paces_at_the_configured_rate_and_ignores_feedback() -> None:
    controller = FixedRateController(FixedConfig(rate=200.0))
    assert controller.name == "fixed"
    assert controller.rate == 200.0
    assert controller.next_send_time() == NO_LIMIT
    now = 0.0
    sent = 0
    while now < 1.0:
        controller.on_packet_sent(now=now, size=105)
        sent += 1
        controller.on_loss_event(now=now, srtt=0.1, loss_event_rate=0.5)
        controller.on_ack(
            now=now, acked=1, rtt_sample=0.1, srtt=0.1, rttvar=0.01, loss_event_rate=0.5
        )
        controller.on_timer(now=now)
        now = max(now, controller.next_send_time())
    assert 200 <= sent <= 202
    assert controller.rate == 200.0
    assert controller.get_timer() is None


def test_default_is_one_kilohertz() -> None:
    assert FixedRateController().rate == 1000.0


def test_infinite_rate_never_holds_a_packet_back() -> None:
    controller = FixedRateController(FixedConfig(rate=math.inf))
    for i in range(100):
        controller.on_packet_sent(now=i * 1e-6, size=100)
        assert controller.next_send_time() == NO_LIMIT


@pytest.mark.parametrize("rate", [0.0, -5.0, math.nan, -math.inf])
def test_config_rejects_non_positive_rates(rate: float) -> None:
    with pytest.raises(ValueError, match=r"FixedConfig\.rate must be a positive number"):
        FixedConfig(rate=rate)
