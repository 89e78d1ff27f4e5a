"""The supermedia sample the examples and the demo exchange: a timestamped haptic/position record.

Layout (big-endian, 36 bytes, zero-padded to the requested payload size)::

    sent_at  f64  sender's monotonic clock, seconds (one-way latency when both ends share a host)
    index    u32  sample counter
    x y z    3 x f32  position (master -> slave) or velocity command
    fx fy fz 3 x f32  force feedback (slave -> master)

tdtp itself never looks inside payloads; this is application data. A payload is taken for a haptic sample
only if it looks like one (:meth:`HapticSample.decode`): long enough, every number finite and within
:data:`POSITION_LIMIT` / :data:`FORCE_LIMIT`, the padding zero. Anything else is opaque bytes, so a peer
that sends something else (random bytes, 1e38 where a float32 stands) cannot break the demo's
feedback loop.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from tdtp.errors import InvalidArgumentError

_LAYOUT = struct.Struct(">dI3f3f")
SAMPLE_SIZE = _LAYOUT.size
POSITION_LIMIT = 10.0
"""Metres: the largest coordinate a haptic sample may carry (a workspace, not a float32's range)."""
FORCE_LIMIT = 1e4
"""Newtons: the largest force component a haptic sample may carry."""


@dataclass(frozen=True, slots=True)
class HapticSample:
    sent_at: float
    index: int
    position: tuple[float, float, float]
    force: tuple[float, float, float]

    def encode(self, size: int = SAMPLE_SIZE) -> bytes:
        """The sample padded with zeros to ``size`` bytes (at least :data:`SAMPLE_SIZE`)."""
        if size < SAMPLE_SIZE:
            raise InvalidArgumentError(
                f"a haptic sample needs at least {SAMPLE_SIZE} bytes, got size={size}"
            )
        body = _LAYOUT.pack(self.sent_at, self.index & 0xFFFFFFFF, *self.position, *self.force)
        return body + bytes(size - SAMPLE_SIZE)

    @classmethod
    def decode(cls, payload: bytes) -> HapticSample | None:
        """The sample in ``payload``, or ``None`` if the payload is not one: too short, a number
        that is not finite or lies outside the workspace limits, or padding that is not zero."""
        if len(payload) < SAMPLE_SIZE or any(payload[SAMPLE_SIZE:]):
            return None
        sent_at, index, x, y, z, fx, fy, fz = _LAYOUT.unpack_from(payload)
        if not math.isfinite(sent_at) or sent_at < 0.0:
            return None
        for value in (x, y, z):
            if not -POSITION_LIMIT <= value <= POSITION_LIMIT:  # False for NaN too
                return None
        for value in (fx, fy, fz):
            if not -FORCE_LIMIT <= value <= FORCE_LIMIT:
                return None
        return cls(sent_at, index, (x, y, z), (fx, fy, fz))


def master_trajectory(t: float, index: int, sent_at: float) -> HapticSample:
    """A 0.5 Hz circle of 10 cm radius: what an operator's hand might trace."""
    phase = 2 * math.pi * 0.5 * t
    return HapticSample(
        sent_at, index, (0.1 * math.cos(phase), 0.1 * math.sin(phase), 0.0), (0, 0, 0)
    )


def slave_feedback(
    position: tuple[float, float, float], index: int, sent_at: float
) -> HapticSample:
    """A spring wall at x = 0.05 m (stiffness 500 N/m) pushing back on the commanded position.

    The position is clamped to the workspace first, so whatever a caller passes the force stays
    finite and within :data:`FORCE_LIMIT`."""
    x, y, z = (_clamp(value) for value in position)
    penetration = max(0.0, x - 0.05)
    return HapticSample(sent_at, index, (x, y, z), (-500.0 * penetration, 0.0, 0.0))


def _clamp(value: float) -> float:
    """``value`` within +-:data:`POSITION_LIMIT` (NaN becomes 0)."""
    if math.isnan(value):
        return 0.0
    return POSITION_LIMIT if value > POSITION_LIMIT else max(value, -POSITION_LIMIT)
