"""The master: an operator's hand, modelled as an impedance, holding a haptic device.

:class:`ReferenceMotion` is what the operator means to do, drawn from a seed: repeated reaches from a
rest point toward the wall, a press some millimetres beyond the wall's face (the hand pushes, the wall
stops the robot, the operator feels it), a slide along the wall while pressing, and a retreat. Every
segment is a minimum-jerk move, so the motion is smooth like a person's.

:class:`Operator` is the hand and the device in one: the device (the hand's and the handle's mass,
with a little friction) is pulled towards the reference by the hand's stiffness and damping and
pushed by the force the device renders, the force that came back from the slave. Integrated at the
1 kHz control rate (semi-implicit Euler), it gives the device position the master sends.
"""

from __future__ import annotations

import bisect
import random
from dataclasses import dataclass

from teleop_loop.workspace import CONTACT_X, REST, TICK

HAND_STIFFNESS = 300.0
"""The hand's grip stiffness (N/m): a relaxed-to-firm grip on a haptic handle is 100-1000 N/m."""
HAND_DAMPING = 20.0
"""The hand's damping (N s/m)."""
DEVICE_MASS = 0.4
"""The handle's and the hand's moving mass (kg)."""
DEVICE_DAMPING = 2.0
"""The device's own viscous friction (N s/m)."""
MAX_RENDERED_FORCE = 20.0
"""The device's motors saturate here (N), as a desktop haptic device's do."""


@dataclass(frozen=True)
class Segment:
    """A minimum-jerk move from ``start`` to ``end`` over ``[t0, t1]``."""

    t0: float
    t1: float
    start: tuple[float, float]
    end: tuple[float, float]


def _min_jerk(s: float) -> tuple[float, float]:
    """Position and rate of the minimum-jerk profile at normalised time ``s`` in [0, 1]."""
    s2 = s * s
    return s2 * s * (10 - 15 * s + 6 * s2), 30 * s2 * (1 - 2 * s + s2)


class ReferenceMotion:
    """The operator's intended hand path: reaches, presses and slides on the wall, from ``seed``.

    The same seed and duration give the same path, sample for sample.
    """

    def __init__(self, seed: int, duration: float, *, settle: float = 0.5) -> None:
        rng = random.Random(seed)
        segments: list[Segment] = []
        t = settle
        here = REST
        while t < duration:
            depth = rng.uniform(0.010, 0.030)  # how far past the wall's face the hand aims
            y0 = rng.uniform(-0.06, 0.06)
            y1 = max(-0.1, min(0.1, y0 + rng.choice((-1, 1)) * rng.uniform(0.03, 0.07)))
            press = (CONTACT_X + depth, y0)
            slide = (CONTACT_X + depth, y1)
            for end, length in (
                (press, rng.uniform(0.7, 1.1)),  # reach and press
                (press, rng.uniform(0.2, 0.5)),  # hold the press
                (slide, rng.uniform(0.8, 1.4)),  # slide along the wall, pressing
                (REST, rng.uniform(0.6, 1.0)),  # retreat
                (REST, rng.uniform(0.2, 0.6)),  # rest
            ):
                segments.append(Segment(t, t + length, here, end))
                here, t = end, t + length
        self.segments = segments
        self._starts = [s.t0 for s in segments]
        self.duration = duration

    def at(self, t: float) -> tuple[tuple[float, float], tuple[float, float]]:
        """The reference position (m) and velocity (m/s) at time ``t`` (s from the start)."""
        i = bisect.bisect_right(self._starts, t) - 1
        if i < 0:
            return REST, (0.0, 0.0)
        seg = self.segments[i]
        span = seg.t1 - seg.t0
        s = min(1.0, (t - seg.t0) / span)
        p, rate = _min_jerk(s)
        rate = rate / span if s < 1.0 else 0.0
        dx, dy = seg.end[0] - seg.start[0], seg.end[1] - seg.start[1]
        return (seg.start[0] + p * dx, seg.start[1] + p * dy), (rate * dx, rate * dy)


class Operator:
    """The hand (an impedance tracking :class:`ReferenceMotion`) and the haptic device it holds."""

    def __init__(self, reference: ReferenceMotion, dt: float = TICK) -> None:
        self.reference = reference
        self.dt = dt
        self.position = REST
        """The device's position (m): what the master sends."""
        self.velocity = (0.0, 0.0)
        self.rendered = (0.0, 0.0)
        """The force the device rendered on the last step (N), after saturation."""

    def step(self, t: float, feedback: tuple[float, float]) -> tuple[float, float]:
        """Advance by one period at time ``t`` with ``feedback`` (N) rendered; the new position."""
        (rx, ry), (rvx, rvy) = self.reference.at(t)
        fx, fy = feedback
        norm = (fx * fx + fy * fy) ** 0.5
        if norm > MAX_RENDERED_FORCE:
            fx, fy = fx * MAX_RENDERED_FORCE / norm, fy * MAX_RENDERED_FORCE / norm
        self.rendered = (fx, fy)
        (x, y), (vx, vy) = self.position, self.velocity
        ax = (
            HAND_STIFFNESS * (rx - x) + HAND_DAMPING * (rvx - vx) - DEVICE_DAMPING * vx + fx
        ) / DEVICE_MASS
        ay = (
            HAND_STIFFNESS * (ry - y) + HAND_DAMPING * (rvy - vy) - DEVICE_DAMPING * vy + fy
        ) / DEVICE_MASS
        vx, vy = vx + ax * self.dt, vy + ay * self.dt
        self.velocity = (vx, vy)
        self.position = (x + vx * self.dt, y + vy * self.dt)
        return self.position
