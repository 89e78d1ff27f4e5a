"""12-bit sequence numbers: expansion against an expectation and RFC 1982 comparison."""

from __future__ import annotations

from hypothesis import example, given
from hypothesis import strategies as st

from tdtp.wire import SEQ_MODULUS, expand_seq, serial_lt

MASK = 0xFFF
HALF = 2048

full = st.integers(-(10**15), 10**15)
truncated = st.integers(0, MASK)
near = st.integers(-(HALF - 1), HALF - 1)


def test_modulus() -> None:
    assert SEQ_MODULUS == 4096


@given(full, near)
@example(0, 0)
@example(4095, 1)  # across the wrap, forwards
@example(4096, -1)  # across the wrap, backwards
@example(-1, 1)  # negative full numbers work like any other
@example(10**15, 2047)
@example(10**15, -2047)
def test_expansion_is_exact_within_half_the_space(x: int, offset: int) -> None:
    expected = x - offset  # |x - expected| < 2048
    assert expand_seq(x & MASK, expected) == x


@given(truncated, full)
def test_expansion_is_the_nearest_candidate(low: int, expected: int) -> None:
    result = expand_seq(low, expected)
    assert result & MASK == low
    assert expected - HALF <= result <= expected + HALF - 1


@given(full)
def test_half_space_ties_resolve_backwards(x: int) -> None:
    # Exactly 2048 away is ambiguous; the expansion picks the older candidate.
    assert expand_seq(x & MASK, x + HALF) == x
    assert expand_seq(x & MASK, x - HALF) == x - SEQ_MODULUS


@given(full, st.integers(HALF, 10 * SEQ_MODULUS))
def test_beyond_half_the_space_is_off_by_a_multiple_of_the_modulus(x: int, distance: int) -> None:
    # What PROTOCOL.md says about loss bursts longer than 2047: the low 12 bits are still right, the
    # full number may be off by a multiple of 4096.
    result = expand_seq(x & MASK, x - distance)
    assert (result - x) % SEQ_MODULUS == 0
    assert result != x


@given(full, st.lists(st.integers(1, HALF), min_size=1, max_size=300))
@example(0, [HALF] * 10)  # 2047 lost in a row, ten times: 5 wraps
def test_receiver_tracks_a_stream_across_many_wraps(start: int, gaps: list[int]) -> None:
    # A receiver expanding each SEQ against (highest received + 1) follows the sender exactly as
    # long as at most 2047 packets are lost in a row (gap = lost + 1 <= 2048).
    sent = highest = start  # the last packet received
    for gap in gaps:
        sent += gap
        highest = expand_seq(sent & MASK, highest + 1)
        assert highest == sent


@given(full, near)
def test_sender_window_for_acks(largest_acked: int, offset: int) -> None:
    # The sender expands ACK against LA + 1024, which decodes [LA - 1024, LA + 3071] exactly.
    ack = largest_acked + 1024 + offset
    assert expand_seq(ack & MASK, largest_acked + 1024) == ack
    for edge in (largest_acked - 1024, largest_acked + 3071):
        assert expand_seq(edge & MASK, largest_acked + 1024) == edge


@given(truncated)
def test_serial_lt_is_irreflexive(a: int) -> None:
    assert not serial_lt(a, a)


@given(truncated, st.integers(1, HALF - 1))
def test_serial_lt_within_half_the_space(a: int, d: int) -> None:
    b = (a + d) & MASK
    assert serial_lt(a, b)
    assert not serial_lt(b, a)


@given(truncated)
def test_serial_lt_at_exactly_half_is_never_both_ways(a: int) -> None:
    b = (a + HALF) & MASK
    assert not (serial_lt(a, b) and serial_lt(b, a))


@given(truncated, truncated)
def test_serial_lt_is_asymmetric_and_agrees_with_expansion(a: int, b: int) -> None:
    assert not (serial_lt(a, b) and serial_lt(b, a))
    if (b - a) & MASK != HALF:
        assert serial_lt(a, b) == (expand_seq(b, a) > a)


def test_serial_lt_examples() -> None:
    assert serial_lt(4095, 0)
    assert serial_lt(4000, 100)
    assert not serial_lt(100, 4000)
    assert serial_lt(0, 2047)
    assert not serial_lt(0, 2049)
    assert serial_lt(2049, 0)
