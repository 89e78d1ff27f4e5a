"""HOLD: how long the acknowledged packet waited at the receiver, as an 8-bit mini-float.

The sender subtracts HOLD from ``now - send_time`` to get an RTT sample that does not include the time the
receiver sat on the ACK waiting for its next reverse packet. The code is a floating-point number with a
3-bit exponent ``e`` and a 5-bit mantissa ``m`` in units of 8 microseconds::

    e == 0:  hold = m * 8 us                       (0 .. 248 us, exact to 8 us)
    e >= 1:  hold = (32 + m) << (e - 1) * 8 us     (256 us .. 31.232 ms, within 1/32 below the truth)

Encoding rounds down to the largest code not above the true hold, everywhere: a decoded hold is never
longer than the real one, so RTT samples err on the long (conservative) side, and never by more than
one step. Holds from 31.232 ms up to (not including) 31.744 ms, where code 254 would sit if the
exponent went on, are therefore code 253. Two codes are reserved:

* ``HOLD_SATURATED`` (254): the ACK is valid but was held 31.744 ms or longer (beyond one step above
  the largest code); no RTT sample.
* ``HOLD_NO_ACK`` (255): the packet carries no acknowledgement at all (ACK and SACK are ignored).
"""

from __future__ import annotations

from typing import Final

HOLD_UNIT: Final = 8e-6
"""Seconds per unit of the mini-float (8 microseconds)."""
HOLD_SATURATED: Final = 254
HOLD_NO_ACK: Final = 255
HOLD_MAX_CODE: Final = 253


def _decode(code: int) -> float:
    exponent, mantissa = code >> 5, code & 0x1F
    units = mantissa if exponent == 0 else (32 + mantissa) << (exponent - 1)
    return units * HOLD_UNIT


_DECODE_TABLE: Final[tuple[float | None, ...]] = tuple(
    _decode(code) for code in range(HOLD_MAX_CODE + 1)
)
"""Every code's hold (as objects: decoding hands one out per packet, unboxed and boxed again
otherwise in the compiled build)."""

HOLD_MAX: Final = _decode(HOLD_MAX_CODE)
"""The longest hold a code can express (31.232 ms)."""
HOLD_SATURATES_AT: Final = _decode(HOLD_SATURATED)
"""The shortest hold that encodes as :data:`HOLD_SATURATED`: 31.744 ms, the value code 254 would have
if it were not reserved. Anything shorter rounds down to a code (253 from 31.232 ms)."""


def encode_hold(seconds: float) -> int:
    """Encode a hold time, rounding down; :data:`HOLD_SATURATES_AT` or longer gives
    :data:`HOLD_SATURATED`."""
    if not seconds > 0.0:  # zero, negative or NaN
        return 0
    if seconds >= HOLD_SATURATES_AT:  # as documented (also keeps int() away from infinity)
        return HOLD_SATURATED
    # The largest whole number of units not above ``seconds``, judged with the same float products
    # the decode table holds (the division alone can land one unit off either way when ``seconds``
    # sits within an ulp of a multiple of HOLD_UNIT), so decode_hold(encode_hold(x)) <= x exactly.
    units = int(seconds / HOLD_UNIT)
    if units * HOLD_UNIT > seconds:
        units -= 1
    elif (units + 1) * HOLD_UNIT <= seconds:
        units += 1
    if units < 32:
        return units
    exponent = units.bit_length() - 5
    code = (exponent << 5) | ((units >> (exponent - 1)) - 32)
    return code if code <= HOLD_MAX_CODE else HOLD_SATURATED


def decode_hold(code: int) -> float | None:
    """The hold time in seconds, or ``None`` for the two reserved codes (no RTT sample possible)."""
    if code > HOLD_MAX_CODE:
        return None
    return _DECODE_TABLE[code]
