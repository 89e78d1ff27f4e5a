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
from dataclasses import dataclass

from tdtp.errors import InvalidArgumentError
from tdtp.teleop.schema import SampleCodec, SampleFormatError

__all__ = [
    "CODEC",
    "FORCE_LIMIT",
    "MOTION_PERIOD",
    "POSITION_LIMIT",
    "SAMPLE_SIZE",
    "WALL_X",
    "HapticSample",
    "master_trajectory",
    "operator_motion",
    "slave_feedback",
]

POSITION_LIMIT = 10.0
"""Metres: the largest coordinate a haptic sample may carry (a workspace, not a float32's range)."""
FORCE_LIMIT = 1e4
"""Newtons: the largest force component a haptic sample may carry."""


@dataclass(frozen=True, slots=True)
class HapticSample:
    """One demo sample: when it was sent, its number, a position and a force."""

    sent_at: float
    index: int
    position: tuple[float, ...]
    force: tuple[float, ...]

    def encode(self, size: int | None = None) -> bytes:
        """The sample padded with zeros to ``size`` bytes (at least :data:`SAMPLE_SIZE`, the default)."""
        if size is None:
            size = SAMPLE_SIZE
        if size < SAMPLE_SIZE:
            raise InvalidArgumentError(
                f"a haptic sample needs at least {SAMPLE_SIZE} bytes, got size={size}"
            )
        body = CODEC.encode_values(self.sent_at, self.index & 0xFFFFFFFF, self.position, self.force)
        return body + bytes(size - SAMPLE_SIZE)

    @classmethod
    def decode(cls, payload: bytes) -> HapticSample | None:
        """The sample in ``payload``, or ``None`` if the payload is not one: too short, a number
        that is not finite or lies outside the workspace limits, or padding that is not zero."""
        if len(payload) < SAMPLE_SIZE or any(payload[SAMPLE_SIZE:]):
            return None
        try:
            sample = CODEC.decode(payload[:SAMPLE_SIZE])
        except SampleFormatError:  # a NaN or an infinity: not the demo's sample
            return None
        if sample.sent_at < 0.0:
            return None
        for value in sample.position:
            if not -POSITION_LIMIT <= value <= POSITION_LIMIT:
                return None
        for value in sample.force:
            if not -FORCE_LIMIT <= value <= FORCE_LIMIT:
                return None
        return sample


CODEC = SampleCodec(
    HapticSample, byte_order=">", sent_at="f64", index="u32", position="f32[3]", force="f32[3]"
)
"""The layout above, as a :class:`~tdtp.teleop.schema.SampleCodec`."""
SAMPLE_SIZE = CODEC.size


WALL_X = 0.05
"""Metres: where the demo's virtual wall stands (the slave pushes back beyond it)."""
MOTION_PERIOD = 4.0
"""Seconds: one reach-press-slide-retreat cycle of the demo operator."""


def _minimum_jerk(s: float) -> float:
    """0 -> 1 over s in [0, 1] with zero velocity and acceleration at both ends (Flash and Hogan's
    model of a point-to-point hand movement)."""
    s = min(max(s, 0.0), 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


def operator_motion(t: float) -> tuple[float, ...]:
    """Where a person's hand is at ``t`` seconds: a repeating teleoperation task with contact.

    Each 4-second cycle: rest at the start (0.4 s), a minimum-jerk reach of 6 cm towards the wall at
    x = 5 cm that ends 1 cm inside it (1.0 s), pressing while sliding 4 cm along it (1.4 s), a
    minimum-jerk retreat (0.8 s), rest (0.4 s). A physiological tremor of 0.1 mm at 9 Hz rides on
    top, as on a real hand (so a deadband has something below its threshold to hold back).
    """
    phase = t % MOTION_PERIOD
    x = y = 0.0
    if phase < 0.4:
        x = 0.0
    elif phase < 1.4:
        x = 0.06 * _minimum_jerk((phase - 0.4) / 1.0)
    elif phase < 2.8:
        x = 0.06
        y = 0.04 * _minimum_jerk((phase - 1.4) / 1.4)
    elif phase < 3.6:
        back = _minimum_jerk((phase - 2.8) / 0.8)
        x = 0.06 * (1.0 - back)
        y = 0.04 * (1.0 - back)
    tremor = 0.0001 * math.sin(2 * math.pi * 9.0 * t)
    return (x + tremor, y, 0.01 * math.sin(2 * math.pi * t / MOTION_PERIOD))


def master_trajectory(t: float, index: int, sent_at: float) -> HapticSample:
    """The demo master's sample at ``t`` seconds into the run: :func:`operator_motion`."""
    return HapticSample(sent_at, index, operator_motion(t), (0.0, 0.0, 0.0))


def slave_feedback(position: tuple[float, ...], index: int, sent_at: float) -> HapticSample:
    """A spring wall at x = :data:`WALL_X` (stiffness 500 N/m) pushing back on the commanded position.

    The position is clamped to the workspace first, so whatever a caller passes the force stays
    finite and within :data:`FORCE_LIMIT`."""
    x, y, z = (_clamp(value) for value in position)
    penetration = max(0.0, x - WALL_X)
    return HapticSample(sent_at, index, (x, y, z), (-500.0 * penetration, 0.0, 0.0))


def _clamp(value: float) -> float:
    """``value`` within +-:data:`POSITION_LIMIT` (NaN becomes 0)."""
    if math.isnan(value):
        return 0.0
    return POSITION_LIMIT if value > POSITION_LIMIT else max(value, -POSITION_LIMIT)
