"""The two ends of the bilateral loop, each a worker process running a 1 kHz control loop.

Protocol with the parent (a :func:`_common.start_worker` pipe): the slave sends ``{"port": N}`` once it
listens, the master ``{"ready": True}`` once connected; both then get ``{"start_at": T, "duration": D}``
(``tdtp.monotonic`` seconds, the host's shared monotonic clock), run their loop from ``T`` for ``D``
seconds on a :class:`tdtp.Ticker`, and send back their log (one row per tick) and their packet counts.

Every sample is a :class:`~tdtp.teleop.haptic_sample.HapticSample` padded to
:data:`~teleop_loop.transports.FRAME` bytes: the master sends the device's position, the slave the
fingertip's position and the contact force it measured. Each side reads the newest sample it holds at
every tick (the latest-value read every transport gets) and logs how old it is.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import multiprocessing.connection
from typing import Any

import numpy as np
from _common import loop_factory

import tdtp
from tdtp.teleop.haptic_sample import HapticSample

from teleop_loop.operator_model import Operator, ReferenceMotion
from teleop_loop.transports import FRAME, TRANSPORTS, Channel
from teleop_loop.workspace import REST, TICK

MASTER_COLUMNS = ("t", "x", "y", "vx", "vy", "fx", "fy", "age")
"""Master log: time, device position and velocity, the force rendered, the newest force sample's age."""
SLAVE_COLUMNS = ("t", "cx", "cy", "x", "y", "vx", "vy", "fx", "fy", "penetration", "age")
"""Slave log: time, the command followed, fingertip position and velocity, measured force,
penetration into the wall, the newest command's age."""


def _run(loop_name: str, coroutine: Any) -> None:
    with asyncio.Runner(loop_factory=loop_factory(loop_name)) as runner:
        runner.run(coroutine)


async def _wait_for_start(conn: multiprocessing.connection.Connection) -> tuple[float, float]:
    go: dict[str, float] = await asyncio.to_thread(conn.recv)
    start_at, duration = go["start_at"], go["duration"]
    await asyncio.sleep(max(0.0, start_at - tdtp.monotonic()))
    return start_at, duration


def slave(
    conn: multiprocessing.connection.Connection, transport: str, spec: str, seed: int, loop: str
) -> None:
    from teleop_loop.arm import Arm  # noqa: PLC0415 - MuJoCo: only the slave needs it

    async def main() -> None:
        channel, port = await TRANSPORTS[transport].slave(0, spec, seed)
        conn.send({"port": port})
        arm = Arm()
        _, duration = await _wait_for_start(conn)
        ticks = round(duration / TICK)
        log = np.full((ticks, len(SLAVE_COLUMNS)), math.nan)
        sent_before = channel.packets_sent()
        command = REST
        n = 0
        async for tick in tdtp.Ticker(round(1 / TICK)):
            if tick >= ticks:
                break
            now = tdtp.monotonic()
            age = math.nan
            payload = channel.latest()
            if payload is not None and (sample := HapticSample.decode(payload)) is not None:
                command = (sample.position[0], sample.position[1])
                age = now - sample.sent_at
            arm.tick(command)
            (x, y), (vx, vy), (fx, fy) = arm.tip(), arm.tip_velocity(), arm.contact_force()
            out = HapticSample(tdtp.monotonic(), tick, (x, y, 0.0), (fx, fy, 0.0))
            _send(channel, out.encode(FRAME))
            log[n] = (now, command[0], command[1], x, y, vx, vy, fx, fy, arm.penetration(), age)
            n += 1
        sent_after = channel.packets_sent()
        conn.send({"log": log[:n], "packets_sent": _delta(sent_before, sent_after)})
        await channel.close()

    _run(loop, main())


def master(
    conn: multiprocessing.connection.Connection,
    transport: str,
    port: int,
    spec: str,
    seed: int,
    motion_seed: int,
    loop: str,
) -> None:
    async def main() -> None:
        channel = await TRANSPORTS[transport].master(port, spec, seed)
        conn.send({"ready": True})
        _, duration = await _wait_for_start(conn)
        operator = Operator(ReferenceMotion(motion_seed, duration))
        ticks = round(duration / TICK)
        log = np.full((ticks, len(MASTER_COLUMNS)), math.nan)
        sent_before = channel.packets_sent()
        force = (0.0, 0.0)
        n = 0
        async for tick in tdtp.Ticker(round(1 / TICK)):
            if tick >= ticks:
                break
            now = tdtp.monotonic()
            age = math.nan
            payload = channel.latest()
            if payload is not None and (sample := HapticSample.decode(payload)) is not None:
                force = (sample.force[0], sample.force[1])
                age = now - sample.sent_at
            x, y = operator.step(tick * TICK, force)
            out = HapticSample(tdtp.monotonic(), tick, (x, y, 0.0), (0.0, 0.0, 0.0))
            _send(channel, out.encode(FRAME))
            vx, vy = operator.velocity
            fx, fy = operator.rendered
            log[n] = (now, x, y, vx, vy, fx, fy, age)
            n += 1
        sent_after = channel.packets_sent()
        conn.send({"log": log[:n], "packets_sent": _delta(sent_before, sent_after)})
        await channel.close()

    _run(loop, main())


def _send(channel: Channel, payload: bytes) -> None:
    # The peer may have gone already (its loop ended first): nothing is left to control then.
    with contextlib.suppress(tdtp.EndpointClosedError):
        channel.send(payload)


def _delta(before: int | None, after: int | None) -> int | None:
    return None if before is None or after is None else after - before
