"""Serial-number arithmetic for the 12-bit SEQ and ACK fields (RFC 1982 style).

Endpoints keep full, unbounded sequence numbers internally and put only the low 12 bits on the wire. A
receiver rebuilds the full value from the 12 bits and an *expected* full value: the candidate nearest to
the expectation wins. This is unambiguous while the true value lies within half the space (2048) of the
expectation, which is what ``docs/PROTOCOL.md`` turns into limits on loss bursts and reordering.
"""

from __future__ import annotations

from typing import Final

from tdtp.wire.header import SEQ_BITS, SEQ_MASK

SEQ_MODULUS: Final = 1 << SEQ_BITS
SEQ_HALF: Final = SEQ_MODULUS >> 1


def expand_seq(truncated: int, expected: int) -> int:
    """The full sequence number closest to ``expected`` whose low 12 bits are ``truncated``.

    The result lies in ``[expected - 2048, expected + 2047]``.
    """
    diff = (truncated - expected) & SEQ_MASK
    if diff >= SEQ_HALF:
        diff -= SEQ_MODULUS
    return expected + diff


def serial_lt(a: int, b: int) -> bool:
    """RFC 1982 "a < b" for two truncated 12-bit values (undefined when they are exactly 2048 apart)."""
    return a != b and ((b - a) & SEQ_MASK) < SEQ_HALF
