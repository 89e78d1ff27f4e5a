"""The slave: the MuJoCo arm of ``arm.xml`` under a task-space position controller.

Each 1 kHz control tick (:meth:`Arm.tick`) takes the newest position command for the fingertip,
computes joint torques from a task-space PD law through the fingertip Jacobian (gravity and
Coriolis compensated from MuJoCo's bias forces), and advances the physics by 1 ms (two 0.5 ms steps).
The contact force the arm measures is the wall's push on the fingertip, in world coordinates.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

from teleop_loop.workspace import REST, TICK, TIP_RADIUS, WALL_X

MODEL_PATH = Path(__file__).with_name("arm.xml")

LINK = 0.3
"""Both links' length (m)."""

KP = 1200.0
"""Task-space stiffness of the position controller (N/m)."""
KD = 50.0
"""Task-space damping of the position controller (N s/m)."""


def inverse_kinematics(x: float, y: float) -> tuple[float, float]:
    """Joint angles (shoulder, elbow; elbow bent clockwise) that put the fingertip at ``(x, y)``."""
    r2 = x * x + y * y
    cos_elbow = (r2 - 2 * LINK * LINK) / (2 * LINK * LINK)
    if not -1.0 <= cos_elbow <= 1.0:
        raise ValueError(f"({x}, {y}) is out of the arm's reach ({2 * LINK} m)")
    elbow = -math.acos(cos_elbow)
    shoulder = math.atan2(y, x) - math.atan2(LINK * math.sin(elbow), LINK + LINK * math.cos(elbow))
    return shoulder, elbow


class Arm:
    """The simulated arm and its position controller; one :meth:`tick` per millisecond."""

    def __init__(self, start: tuple[float, float] = REST) -> None:
        self.model = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
        self.data = mujoco.MjData(self.model)
        self._site = self.model.site("fingertip").id
        self._tip_geom = self.model.geom("fingertip").id
        self._wall_geom = self.model.geom("wall").id
        self._substeps = round(TICK / self.model.opt.timestep)
        self._jacp = np.zeros((3, self.model.nv))
        self._force6 = np.zeros(6)
        self.data.qpos[:] = inverse_kinematics(*start)
        mujoco.mj_forward(self.model, self.data)
        self.command = start
        """The position command the controller follows (the newest one received)."""

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return float(self.data.time)

    def tip(self) -> tuple[float, float]:
        """The fingertip's centre, x and y (m)."""
        p = self.data.site_xpos[self._site]
        return float(p[0]), float(p[1])

    def tip_velocity(self) -> tuple[float, float]:
        """The fingertip's velocity, x and y (m/s)."""
        mujoco.mj_jacSite(self.model, self.data, self._jacp, None, self._site)
        v = self._jacp @ self.data.qvel
        return float(v[0]), float(v[1])

    def contact_force(self) -> tuple[float, float]:
        """The wall's force on the fingertip, x and y (N): what the slave measures and sends back."""
        fx = fy = 0.0
        data = self.data
        for i in range(data.ncon):
            contact = data.contact[i]
            pair = {int(contact.geom1), int(contact.geom2)}
            if pair != {self._tip_geom, self._wall_geom}:
                continue
            mujoco.mj_contactForce(self.model, data, i, self._force6)
            # The force is in the contact frame (normal first), acting on geom2 from geom1 when
            # positive along the frame's normal, which points from geom1 to geom2.
            world = contact.frame.reshape(3, 3).T @ self._force6[:3]
            sign = 1.0 if int(contact.geom2) == self._tip_geom else -1.0
            fx += sign * float(world[0])
            fy += sign * float(world[1])
        return fx, fy

    def penetration(self) -> float:
        """How far the fingertip's surface is inside the wall (m), 0 when it is not."""
        return max(0.0, self.tip()[0] + TIP_RADIUS - WALL_X)

    def tick(self, command: tuple[float, float] | None = None) -> None:
        """Follow ``command`` (or keep the last one) for one control period."""
        if command is not None:
            self.command = command
        model, data = self.model, self.data
        mujoco.mj_jacSite(model, data, self._jacp, None, self._site)
        jac = self._jacp[:2]
        tip = data.site_xpos[self._site]
        velocity = jac @ data.qvel
        error = np.array([self.command[0] - tip[0], self.command[1] - tip[1]])
        force = KP * error - KD * velocity
        torque = jac.T @ force + data.qfrc_bias
        np.clip(torque, model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1], out=torque)
        data.ctrl[:] = torque
        for _ in range(self._substeps):
            mujoco.mj_step(model, data)
