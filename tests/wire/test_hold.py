"""HOLD, the 8-bit hold-time mini-float: pinned values, monotonicity, rounding down, saturation."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from tdtp.wire import HOLD_MAX, HOLD_NO_ACK, HOLD_SATURATED, decode_hold, encode_hold
from tdtp.wire.hold import HOLD_MAX_CODE, HOLD_SATURATES_AT, HOLD_UNIT

US = 1e-6
CODES = range(HOLD_MAX_CODE + 1)
# Float noise allowance for the error bounds only (the "never above the truth" property is exact).
EPS = 1e-15


def value(code: int) -> float:
    decoded = decode_hold(code)
    assert decoded is not None
    return decoded


# Code -> hold, derived by hand from "e = code >> 5, m = code & 31; e == 0: m units;
# e >= 1: (32 + m) << (e - 1) units; 1 unit = 8 us".
GOLDEN_CODES = [
    (0, 0.0),  # e0 m0
    (1, 8 * US),  # e0 m1
    (31, 248 * US),  # e0 m31: 31 * 8
    (32, 256 * US),  # e1 m0: 32 * 8
    (63, 504 * US),  # e1 m31: 63 * 8
    (64, 512 * US),  # e2 m0: 64 * 8
    (94, 992 * US),  # e2 m30: 62 << 1 = 124 units
    (95, 1008 * US),  # e2 m31: 63 << 1 = 126 units
    (96, 1024 * US),  # e3 m0: 32 << 2 = 128 units
    (110, 1472 * US),  # e3 m14: 46 << 2 = 184 units
    (128, 2048 * US),  # e4 m0: 32 << 3 = 256 units
    (160, 4096 * US),  # e5 m0: 32 << 4 = 512 units
    (192, 8192 * US),  # e6 m0: 32 << 5 = 1024 units
    (224, 16384 * US),  # e7 m0: 32 << 6 = 2048 units
    (231, 19968 * US),  # e7 m7: 39 << 6 = 2496 units
    (253, 31232 * US),  # e7 m29: 61 << 6 = 3904 units, the largest
]


def test_constants() -> None:
    assert pytest.approx(8 * US, rel=1e-12) == HOLD_UNIT
    assert (HOLD_MAX_CODE, HOLD_SATURATED, HOLD_NO_ACK) == (253, 254, 255)
    assert pytest.approx(31.232e-3, rel=1e-12) == HOLD_MAX
    assert value(HOLD_MAX_CODE) == HOLD_MAX


@pytest.mark.parametrize(("code", "seconds"), GOLDEN_CODES)
def test_golden_codes(code: int, seconds: float) -> None:
    assert value(code) == pytest.approx(seconds, rel=1e-12, abs=1e-18)
    assert encode_hold(value(code)) == code


@pytest.mark.parametrize(
    ("seconds", "code"),
    [
        (250 * US, 31),  # 31.25 units -> 31 (248 us)
        (1e-3, 94),  # 125 units -> e2 step 2 -> 124 units (992 us)
        (1.5e-3, 110),  # 187.5 units -> e3 step 4 -> 184 units (1.472 ms)
        (20e-3, 231),  # 2500 units -> e7 step 64 -> 2496 units (19.968 ms)
    ],
)
def test_golden_encodings(seconds: float, code: int) -> None:
    assert encode_hold(seconds) == code


def test_reserved_codes_decode_to_none() -> None:
    assert decode_hold(HOLD_SATURATED) is None
    assert decode_hold(HOLD_NO_ACK) is None


def test_decode_is_strictly_increasing() -> None:
    values = [value(c) for c in CODES]
    assert values[0] == 0.0
    assert all(a < b for a, b in itertools.pairwise(values))


def test_step_is_8us_to_512us_then_doubles_per_exponent() -> None:
    for code in range(1, HOLD_MAX_CODE + 1):
        exponent = code >> 5
        step_units = 1 << max(exponent - 1, 0)
        # Crossing into a new exponent the step is the previous exponent's.
        if code & 0x1F == 0 and exponent >= 2:
            step_units >>= 1
        step = value(code) - value(code - 1)
        assert step == pytest.approx(step_units * HOLD_UNIT, rel=1e-9), code


@pytest.mark.parametrize("code", CODES)
def test_encode_inverts_decode(code: int) -> None:
    assert encode_hold(value(code)) == code


@given(st.floats(min_value=0.0, max_value=HOLD_SATURATES_AT, exclude_max=True))
@example(math.nextafter(24 * US, 0.0))  # a division that used to round up to a whole unit
@example(123 * HOLD_UNIT)  # a division that used to round down by a whole unit
@example(HOLD_MAX)
@example(256 * US)
def test_encode_rounds_down_to_the_nearest_code(seconds: float) -> None:
    code = encode_hold(seconds)
    assert 0 <= code <= HOLD_MAX_CODE
    decoded = value(code)
    # Never longer than the truth (RTT samples err long, never short) ...
    assert decoded <= seconds
    # ... and the largest code with that property.
    if code < HOLD_MAX_CODE:
        assert value(code + 1) > seconds
    error = seconds - decoded
    if seconds < 256 * US:
        assert error < 8 * US + EPS
    else:
        assert error < seconds / 32 + EPS


@given(st.floats(min_value=0.0, max_value=1.024e-3))
def test_below_one_millisecond_the_step_is_at_most_16us(seconds: float) -> None:
    assert seconds - value(encode_hold(seconds)) < 16 * US + EPS


@given(st.floats(min_value=HOLD_MAX, max_value=HOLD_SATURATES_AT, exclude_max=True))
@example(math.nextafter(HOLD_MAX, 1.0))
@example(31.5e-3)
@example(math.nextafter(HOLD_SATURATES_AT, 0.0))
def test_between_the_largest_code_and_one_step_above_rounds_down(seconds: float) -> None:
    """PROTOCOL.md 3.4: one rule, rounding down, everywhere. 31.232 <= hold < 31.744 ms is 253
    (the error stays below one step, 1/32); 254 only from where code 254 would decode."""
    assert encode_hold(seconds) == HOLD_MAX_CODE


def test_the_saturation_boundary() -> None:
    assert pytest.approx(31.744e-3, rel=1e-12) == HOLD_SATURATES_AT
    assert HOLD_SATURATES_AT == 3968 * HOLD_UNIT  # (32 + 30) << 6 units: where 254 would decode
    assert encode_hold(HOLD_MAX) == HOLD_MAX_CODE
    assert encode_hold(31.5e-3) == HOLD_MAX_CODE
    assert encode_hold(math.nextafter(HOLD_SATURATES_AT, 0.0)) == HOLD_MAX_CODE
    assert encode_hold(HOLD_SATURATES_AT) == HOLD_SATURATED


@given(st.floats(min_value=HOLD_SATURATES_AT))
@example(HOLD_SATURATES_AT)
@example(1.0)
@example(math.inf)
def test_from_one_step_above_max_saturates(seconds: float) -> None:
    assert encode_hold(seconds) == HOLD_SATURATED


@given(st.floats(max_value=0.0))
@example(-0.0)
@example(-math.inf)
def test_negative_or_zero_encodes_as_zero(seconds: float) -> None:
    assert encode_hold(seconds) == 0


def test_nan_encodes_as_zero() -> None:
    assert encode_hold(math.nan) == 0
