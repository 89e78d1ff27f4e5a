"""Typed samples and the perceptual deadband (issue 21): both sans-IO, checked on fake time."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tdtp import TdtpError
from tdtp.teleop.deadband import DeadbandConfig, DeadbandReceiver, DeadbandSender
from tdtp.teleop.schema import SampleCodec, SampleFormatError


@dataclass(frozen=True, slots=True)
class JointCommand:
    sent_at: float
    q: tuple[float, ...]
    gripper: int


CODEC = SampleCodec(JointCommand, sent_at="f64", q="f32[7]", gripper="u8")


def test_a_joint_command_round_trips_through_one_struct() -> None:
    command = JointCommand(12.5, (0.0, 0.25, -0.5, 1.0, 0.0, 0.5, -1.0), 1)
    payload = CODEC.encode(command)
    assert CODEC.size == len(payload) == 8 + 7 * 4 + 1
    assert CODEC.decode(payload) == command
    assert CODEC.decode(memoryview(payload + b"xx"), allow_trailing=True) == command
    assert "q=f32[7]" in repr(CODEC)
    assert CODEC.field_slots("q") == tuple(range(1, 8))


@pytest.mark.parametrize(
    ("build", "words"),
    [
        (lambda: SampleCodec(JointCommand, sent_at="f64", q="f32[7]"), "missing gripper"),
        (
            lambda: SampleCodec(JointCommand, sent_at="f64", q="f32[7]", gripper="u8", x="u8"),
            "not fields",
        ),
        (
            lambda: SampleCodec(JointCommand, sent_at="float", q="f32[7]", gripper="u8"),
            "unknown type",
        ),
        (lambda: SampleCodec(dict, a="u8"), "needs a dataclass"),  # type: ignore[type-var]
        (
            lambda: SampleCodec(
                JointCommand, byte_order="!", sent_at="f64", q="f32[7]", gripper="u8"
            ),
            "byte_order",
        ),
    ],
)
def test_a_bad_layout_is_refused_naming_what_to_fix(build: object, words: str) -> None:
    with pytest.raises(SampleFormatError, match=words):
        build()  # type: ignore[operator]


def test_what_does_not_fit_is_refused_both_ways() -> None:
    good = (1.0, (0.0,) * 7, 0)
    with pytest.raises(SampleFormatError, match=r"q must be a sequence of 7"):
        CODEC.encode(JointCommand(1.0, (0.0,) * 6, 0))
    with pytest.raises(SampleFormatError, match=r"q\[3\] is nan"):
        CODEC.encode(JointCommand(1.0, (0.0, 0.0, 0.0, math.nan, 0.0, 0.0, 0.0), 0))
    with pytest.raises(SampleFormatError, match="does not fit"):
        CODEC.encode(JointCommand(1.0, (0.0,) * 7, 300))  # u8
    with pytest.raises(SampleFormatError, match="is 37 bytes, got 36"):
        CODEC.decode(CODEC.encode_values(*good)[:-1])
    hostile = struct.pack("<d7fB", 1.0, 0, 0, math.inf, 0, 0, 0, 0, 0)
    with pytest.raises(SampleFormatError, match=r"q\[2\] is inf in the payload"):
        CODEC.decode(hostile)
    assert issubclass(SampleFormatError, TdtpError) and issubclass(SampleFormatError, ValueError)


@given(st.binary(min_size=0, max_size=80))
def test_any_payload_decodes_or_raises_sample_format_error(payload: bytes) -> None:
    """Peer bytes either make a valid command (which encodes back to the same bytes) or a
    SampleFormatError: nothing else escapes."""
    try:
        command = CODEC.decode(payload)
    except SampleFormatError:
        return
    assert CODEC.encode(command) == payload


# ---------------------------------------------------------------- deadband


def _sender(**config: float) -> DeadbandSender:
    return DeadbandSender(groups=[(0, 1, 2)], config=DeadbandConfig(**config))


def test_changes_below_the_weber_fraction_are_held() -> None:
    band = _sender(k=0.1, max_hold=math.inf)
    assert band.offer([10.0, 0.0, 0.0], now=0.0)  # the first sample always goes
    assert not band.offer([10.9, 0.0, 0.0], now=0.001)  # 9 % of 10
    assert band.offer([11.1, 0.0, 0.0], now=0.002)  # 11 %: felt
    assert not band.offer([11.1, 1.0, 0.0], now=0.003)  # |change| 1.0 < 1.11
    assert band.stats.offered == 4 and band.stats.sent == 2 and band.stats.saving == 0.5


def test_near_zero_the_absolute_floor_applies_and_the_heartbeat_sends() -> None:
    band = _sender(k=0.1, min_threshold=0.05, max_hold=0.1)
    assert band.offer([0.0, 0.0, 0.0], now=0.0)
    assert not band.offer([0.04, 0.0, 0.0], now=0.01)
    assert band.offer([0.06, 0.0, 0.0], now=0.02)
    assert not band.offer([0.06, 0.0, 0.0], now=0.05)
    assert band.offer([0.06, 0.0, 0.0], now=0.121)  # max_hold passed: a heartbeat
    assert band.stats.heartbeats == 1


def test_fast_motion_widens_the_threshold() -> None:
    still, moving = (
        _sender(k=0.1, max_hold=math.inf),
        _sender(k=0.1, velocity_gain=1.0, max_hold=math.inf),
    )
    for band in (still, moving):
        band.offer([10.0, 0.0, 0.0], now=0.0)
        band.offer([10.5, 0.0, 0.0], now=0.001)  # 500 units/s
    # 12 % above the reference: felt at rest, not while moving at 500/s.
    assert still.offer([11.2, 0.0, 0.0], now=0.002)
    assert not moving.offer([11.2, 0.0, 0.0], now=0.002)


def test_the_reconstruction_error_is_what_the_receiver_holds() -> None:
    band = _sender(k=0.5, max_hold=math.inf)
    band.offer([1.0, 0.0, 0.0], now=0.0)
    band.offer([1.3, 0.0, 0.0], now=0.001)  # held: error 0.3
    band.offer([1.4, 0.0, 0.0], now=0.002)  # held: error 0.4
    assert band.stats.reconstruction_rmse == pytest.approx(math.sqrt((0.09 + 0.16) / 3))


def test_the_receiver_holds_or_extrapolates_for_at_most_max_hold() -> None:
    hold, slope = DeadbandReceiver(), DeadbandReceiver(extrapolate=True, max_hold=0.1)
    assert hold.value_at(0.0) is None
    for receiver in (hold, slope):
        receiver.receive([0.0], now=0.0)
        receiver.receive([1.0], now=0.1)
    assert hold.value_at(0.15) == [1.0]
    assert slope.value_at(0.15) == pytest.approx([1.5])
    assert slope.value_at(5.0) == pytest.approx([2.0])  # extrapolation stops after max_hold


@pytest.mark.parametrize(
    "config",
    [
        {"k": -0.1},
        {"k": math.nan},
        {"max_hold": 0.0},
        {"min_threshold": -1.0},
        {"velocity_gain": math.inf},
    ],
)
def test_deadband_settings_are_validated(config: dict[str, float]) -> None:
    with pytest.raises(ValueError, match=next(iter(config))):
        DeadbandConfig(**config)
    with pytest.raises(ValueError, match="non-empty group"):
        DeadbandSender(groups=[])
