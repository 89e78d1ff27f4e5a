"""Whatever bytes a peer puts in its samples, the demo's feedback loop keeps running (issue 20, item 5).

A payload counts as a haptic sample only if it looks like one; anything else is opaque bytes. The
slave's per-sample path (take the sample in, compute the wall's force, encode the answer) must never
raise, for any content and any size the CLI allows.
"""

from __future__ import annotations

import math
import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from tdtp.cli.outcome import Side
from tdtp.session.events import DataReceived
from tdtp.teleop.haptic_sample import (
    FORCE_LIMIT,
    POSITION_LIMIT,
    SAMPLE_SIZE,
    HapticSample,
    slave_feedback,
)

MAX_SIZE = 1500


def _delivered(payload: bytes) -> DataReceived:
    return DataReceived(payload, 0, None, 1.0)


def _answer(side: Side, payload: bytes, size: int) -> bytes:
    """What the CLI slave does with one sample: record it, then answer from the newest position."""
    side.on_data(_delivered(payload))
    return slave_feedback(side.last_position, side.received, 1.0).encode(size)


@settings(max_examples=400, deadline=None)
@given(payload=st.binary(min_size=1, max_size=MAX_SIZE), size=st.integers(SAMPLE_SIZE, MAX_SIZE))
def test_any_payload_is_answered(payload: bytes, size: int) -> None:
    side = Side("fuzz")
    answer = _answer(side, payload, size)
    assert len(answer) == size
    assert side.received == 1
    decoded = HapticSample.decode(answer)
    assert decoded is not None  # our own answer is always a well-formed sample
    assert all(abs(v) <= POSITION_LIMIT for v in decoded.position)
    assert all(abs(f) <= FORCE_LIMIT for f in decoded.force)


@settings(max_examples=300, deadline=None)
@given(
    values=st.lists(
        st.floats(allow_nan=True, allow_infinity=True, width=32), min_size=6, max_size=6
    ),
    sent_at=st.floats(allow_nan=True, allow_infinity=True),
    pad=st.integers(0, 64),
)
def test_the_demo_layout_with_hostile_numbers(
    values: list[float], sent_at: float, pad: int
) -> None:
    """The layout the demo recognises, filled with what a float32 can hold: 1e38, NaN, inf."""
    payload = struct.pack(">dI3f3f", sent_at, 7, *values) + bytes(pad)
    side = Side("hostile")
    _answer(side, payload, SAMPLE_SIZE + pad)
    sample = HapticSample.decode(payload)
    if sample is None:
        assert side.not_haptic == 1 and side.last_position == (0.0, 0.0, 0.0)
    else:
        assert all(math.isfinite(v) and abs(v) <= POSITION_LIMIT for v in sample.position)


def test_the_numbers_that_broke_the_slave_are_opaque() -> None:
    """The cases the issue reports: 1e38 and 7e35 where the demo's layout has a float32."""
    for big in (1e38, 7e35, -3.4e38):
        payload = struct.pack(">dI3f3f", 1.0, 1, big, 0.0, 0.0, 0.0, 0.0, 0.0) + bytes(64)
        assert HapticSample.decode(payload) is None
        side = Side("slave")
        assert len(_answer(side, payload, 100)) == 100
        assert side.not_haptic == 1


def test_a_demo_sample_is_still_recognised() -> None:
    sample = HapticSample(3.0, 9, (0.06, 0.0, -0.01), (0.0, 0.0, 0.0))
    side = Side("slave")
    answer = _answer(side, sample.encode(100), 100)
    assert (
        side.not_haptic == 0
        and side.last_position[0] == struct.unpack(">f", struct.pack(">f", 0.06))[0]
    )
    decoded = HapticSample.decode(answer)
    assert decoded is not None and decoded.force[0] < 0.0  # the wall pushes back
    # Non-zero padding: not the demo's layout (random bytes after a plausible prefix).
    assert HapticSample.decode(sample.encode(100)[:-1] + b"\x01") is None
