"""The figures of one run, from the two sides' logs (``sides.MASTER_COLUMNS``, ``sides.SLAVE_COLUMNS``).

Both logs are stamped with the host's shared monotonic clock; the slave's is interpolated onto the
master's ticks, so every comparison is at the same instant:

* ``position_rmse_mm``: the fingertip against the master device, both in the plane (the operator's
  view of how well the robot follows the hand, lag included);
* ``force_rmse_n``: the force rendered to the operator against the force the slave measured at the
  same instant;
* ``penetration_max_mm``: the deepest the fingertip went into the wall;
* ``age_p99_ms``: the 99th percentile, over ticks, of the age of the newest sample each side holds;
* ``channel_energy_j``: the passivity observer's figures (:mod:`teleop_loop.passivity`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from teleop_loop import passivity
from teleop_loop.sides import MASTER_COLUMNS, SLAVE_COLUMNS

Array = npt.NDArray[np.float64]
M = {name: i for i, name in enumerate(MASTER_COLUMNS)}
S = {name: i for i, name in enumerate(SLAVE_COLUMNS)}


def _p99_ms(ages: Array) -> float | None:
    ages = ages[~np.isnan(ages)]
    return None if ages.size == 0 else round(float(np.percentile(ages, 99)) * 1000, 2)


def _rms(values: Array) -> float:
    return float(np.sqrt(np.mean(values))) if values.size else math.nan


def slave_on_master_ticks(master: Array, slave: Array, column: str) -> Array:
    return np.interp(master[:, M["t"]], slave[:, S["t"]], slave[:, S[column]])


def summarise(
    master: Array,
    slave: Array,
    duration: float,
    packets: dict[str, int | None],
) -> dict[str, Any]:
    """The figures of one run; ``packets`` has what entered the path each way (``m2s``, ``s2m``)."""
    if len(master) < 2 or len(slave) < 2:
        raise ValueError("a side logged fewer than two ticks")
    sx, sy = (slave_on_master_ticks(master, slave, c) for c in ("x", "y"))
    sfx, sfy = (slave_on_master_ticks(master, slave, c) for c in ("fx", "fy"))
    mx, my = master[:, M["x"]], master[:, M["y"]]
    mfx, mfy = master[:, M["fx"]], master[:, M["fy"]]
    position_sq = (mx - sx) ** 2 + (my - sy) ** 2
    force_sq = (mfx - sfx) ** 2 + (mfy - sfy) ** 2

    # The channel's slave port moves with the command the slave received.
    t_s = slave[:, S["t"]]
    vcx, vcy = (np.gradient(slave[:, S[c]], t_s) for c in ("cx", "cy"))
    vcx_m, vcy_m = (np.interp(master[:, M["t"]], t_s, v) for v in (vcx, vcy))
    dt = np.diff(master[:, M["t"]], prepend=master[0, M["t"]])
    energy = passivity.observe(
        dt,
        np.column_stack((mfx, mfy)),
        np.column_stack((master[:, M["vx"]], master[:, M["vy"]])),
        np.column_stack((sfx, sfy)),
        np.column_stack((vcx_m, vcy_m)),
    )
    channel = passivity.summarise(energy)

    def rate(count: int | None) -> float | None:
        return None if count is None else round(count / duration, 1)

    return {
        "position_rmse_mm": round(_rms(position_sq) * 1000, 3),
        "force_rmse_n": round(_rms(force_sq), 3),
        "penetration_max_mm": round(float(np.max(slave[:, S["penetration"]])) * 1000, 3),
        "packets_per_s": {"m2s": rate(packets.get("m2s")), "s2m": rate(packets.get("s2m"))},
        "age_p99_ms": {
            "m2s": _p99_ms(slave[:, S["age"]]),
            "s2m": _p99_ms(master[:, M["age"]]),
        },
        "channel_energy_j": {
            "injected": round(channel.injected_j, 4),
            "final": round(channel.final_j, 4),
            "active_fraction": round(channel.active_fraction, 3),
        },
        "ticks": {"master": len(master), "slave": len(slave)},
    }
