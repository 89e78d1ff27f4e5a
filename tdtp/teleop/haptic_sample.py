"""The supermedia sample the examples and the demo exchange: a timestamped haptic/position record.

Layout (big-endian, 36 bytes, zero-padded to the requested payload size)::

    sent_at  f64  sender's monotonic clock, seconds (one-way latency when both ends share a host)
    index    u32  sample counter
    x y z    3 x f32  position (master -> slave) or velocity command
    fx fy fz 3 x f32  force feedback (slave -> master)

tdtp itself never looks inside payloads; this is application data.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from tdtp.errors import InvalidArgumentError

_LAYOUT = struct.Struct(">dI3f3f")
SAMPLE_SIZE = _LAYOUT.size


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
        """The sample in ``payload``, or ``None`` if it is too short to hold one."""
        if len(payload) < SAMPLE_SIZE:
            return None
        sent_at, index, x, y, z, fx, fy, fz = _LAYOUT.unpack_from(payload)
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
    """A spring wall at x = 0.05 m (stiffness 500 N/m) pushing back on the commanded position."""
    penetration = max(0.0, position[0] - 0.05)
    return HapticSample(sent_at, index, position, (-500.0 * penetration, 0.0, 0.0))
