"""A passivity observer for the communication channel, after Hannaford and Ryu's time-domain
passivity approach (IEEE Trans. Robotics and Automation 18(1), 2002).

The channel of a position-force teleoperator is a two-port. At the master port the device moves with
velocity ``v_m`` and the channel pushes it with the rendered force ``f_m``; at the slave port the
channel hands the slave a position command moving with velocity ``v_s`` and takes back the force
``f_s`` the slave measured (the environment's push on the robot). Power flowing *into* the channel is
``-f_m . v_m`` at the master port and ``+f_s . v_s`` at the slave port (with an ideal channel,
``f_m = f_s`` and ``v_s = v_m``, the two cancel). The observer integrates their sum,

    E(t) = sum over samples of (f_s . v_s - f_m . v_m) * dt,

and the channel is passive while ``E(t) >= 0``: it has never given out more energy than it took in.
Delay, jitter and loss make it active (``E`` < 0): the wall feels softer or springier than it is and the
loop can oscillate. Here the observer runs after the run, on both ends' logs on the host's shared
monotonic clock, which a distributed implementation would have to approximate by sending each port's
energy across.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ChannelEnergy:
    """What the observer saw over a run (joules)."""

    injected_j: float
    """The most energy the channel had generated at any moment: ``max(0, -min E(t))``. 0 if passive."""
    final_j: float
    """``E`` at the end of the run (positive: the channel dissipated that much in total)."""
    active_fraction: float
    """The share of the run during which ``E(t) < 0``."""


def observe(
    dt: float | Array, f_master: Array, v_master: Array, f_slave: Array, v_slave: Array
) -> Array:
    """``E(t)`` at every sample. Forces and velocities are ``(n, k)`` arrays (or ``(n,)``), one row per
    sample, all on one time base; ``dt`` is the period or an array of ``n`` sample durations."""
    fm, vm = np.atleast_2d(f_master.T).T, np.atleast_2d(v_master.T).T
    fs, vs = np.atleast_2d(f_slave.T).T, np.atleast_2d(v_slave.T).T
    power = np.sum(fs * vs, axis=1) - np.sum(fm * vm, axis=1)
    return np.cumsum(power * dt)


def summarise(energy: Array) -> ChannelEnergy:
    """The figures the benchmark reports from ``E(t)``."""
    if energy.size == 0:
        return ChannelEnergy(0.0, 0.0, 0.0)
    return ChannelEnergy(
        injected_j=max(0.0, -float(energy.min())),
        final_j=float(energy[-1]),
        active_fraction=float(np.mean(energy < 0)),
    )
