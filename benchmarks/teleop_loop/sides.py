"""The two ends of the bilateral loop, each a worker process running a 1 kHz control loop.

Protocol with the parent (a :func:`_common.start_worker` pipe): the slave sends ``{"port": N}`` once it
listens, the master ``{"ready": True}`` once connected. Then the **warm-up**: both sides send a
warm-up sample every millisecond (the device at rest, no force) and each says ``{"warm": S}`` once
the first sample from its peer has arrived, ``S`` seconds into the warm-up (a transport whose session
set-up crosses the impaired link, as Zenoh's does, may need several tries on a bursty one); the
parent bounds the wait. Both then get ``{"start_at": T, "duration": D}`` (``tdtp.monotonic`` seconds,
the host's shared monotonic clock), keep warming up until ``T``, run their loop from ``T`` for ``D``
seconds on a :class:`tdtp.Ticker`, and send back their log (one row per tick), their packet counts
and what their transport counted. Warm-up samples are numbered just below the run's first (the
counter wraps), so a receiver that keeps the newest by counter takes the run's samples over them.

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
from collections.abc import Callable
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


WARMUP_INDEX = (1 << 32) - (1 << 24)
"""The first warm-up sample's counter: 2**24 warm-up samples (4.6 hours) before the run's 0."""


def _run(loop_name: str, coroutine: Any) -> None:
    with asyncio.Runner(loop_factory=loop_factory(loop_name)) as runner:
        runner.run(coroutine)


async def _warm_up_then_start(
    conn: multiprocessing.connection.Connection, channel: Channel, out: HapticSample
) -> tuple[float, float]:
    """Send ``out`` (renumbered) every millisecond, say ``{"warm": seconds}`` once a sample from the
    peer has arrived, and carry on until the start time the parent sends; then the start time and
    the duration."""
    go: asyncio.Task[dict[str, float]] = asyncio.get_running_loop().create_task(
        asyncio.to_thread(conn.recv)
    )
    began = tdtp.monotonic()
    warm = False
    index = WARMUP_INDEX
    async for _ in tdtp.Ticker(round(1 / TICK)):
        if go.done():
            break
        if not warm and channel.latest() is not None:
            warm = True
            conn.send({"warm": round(tdtp.monotonic() - began, 3)})
        sample = HapticSample(tdtp.monotonic(), index, out.position, out.force)
        _send(channel, sample.encode(FRAME))
        index = (index + 1) & 0xFFFFFFFF
    message = await go
    start_at, duration = message["start_at"], message["duration"]
    while tdtp.monotonic() < start_at:  # keep the path warm until the run starts
        sample = HapticSample(tdtp.monotonic(), index, out.position, out.force)
        _send(channel, sample.encode(FRAME))
        index = (index + 1) & 0xFFFFFFFF
        await asyncio.sleep(min(TICK, max(0.0, start_at - tdtp.monotonic())))
    return start_at, duration


Vector = tuple[float, float, float]
Tick = tuple[Vector, Vector, tuple[float, ...]]
"""What a side's step returns each tick: the position and force it sends, and its log row between
the time and the age columns."""


async def _control_loop(
    conn: multiprocessing.connection.Connection,
    channel: Channel,
    duration: float,
    columns: tuple[str, ...],
    step: Callable[[int, HapticSample | None], Tick],
) -> None:
    """One side's 1 kHz loop for ``duration`` s: at every tick read the newest sample the peer sent
    (``None`` if there is none or it does not decode), let ``step`` act on it, send what it returns and
    log the tick (``columns``: time, the step's row, the newest sample's age); then report the log,
    the packet count and the transport's details to the parent and close the channel."""
    ticks = round(duration / TICK)
    log = np.full((ticks, len(columns)), math.nan)
    sent_before = channel.packets_sent()
    n = 0
    async for tick in tdtp.Ticker(round(1 / TICK)):
        if tick >= ticks:
            break
        now = tdtp.monotonic()
        payload = channel.latest()
        newest = HapticSample.decode(payload) if payload is not None else None
        age = now - newest.sent_at if newest is not None else math.nan
        position, force, row = step(tick, newest)
        _send(channel, HapticSample(tdtp.monotonic(), tick, position, force).encode(FRAME))
        log[n] = (now, *row, age)
        n += 1
    sent_after = channel.packets_sent()
    conn.send(
        {
            "log": log[:n],
            "packets_sent": _delta(sent_before, sent_after),
            "details": channel.details(),
        }
    )
    await channel.close()


def slave(
    conn: multiprocessing.connection.Connection,
    transport: str,
    spec: str,
    seed: int,
    loop: str,
    options: dict[str, Any] | None = None,
) -> None:
    from teleop_loop.arm import Arm  # noqa: PLC0415 - MuJoCo: only the slave needs it

    async def main() -> None:
        chosen = TRANSPORTS[transport]
        channel, port = await chosen.slave(0, spec, seed, **chosen.pick(options or {}))
        conn.send({"port": port})
        arm = Arm()
        rest = HapticSample(0.0, 0, (*arm.tip(), 0.0), (0.0, 0.0, 0.0))
        _, duration = await _warm_up_then_start(conn, channel, rest)
        command = REST

        def step(tick: int, newest: HapticSample | None) -> Tick:
            nonlocal command
            if newest is not None:
                command = (newest.position[0], newest.position[1])
            arm.tick(command)
            (x, y), (vx, vy), (fx, fy) = arm.tip(), arm.tip_velocity(), arm.contact_force()
            row = (command[0], command[1], x, y, vx, vy, fx, fy, arm.penetration())
            return (x, y, 0.0), (fx, fy, 0.0), row

        await _control_loop(conn, channel, duration, SLAVE_COLUMNS, step)

    _run(loop, main())


def master(
    conn: multiprocessing.connection.Connection,
    transport: str,
    port: int,
    spec: str,
    seed: int,
    motion_seed: int,
    loop: str,
    options: dict[str, Any] | None = None,
) -> None:
    async def main() -> None:
        chosen = TRANSPORTS[transport]
        channel = await chosen.master(port, spec, seed, **chosen.pick(options or {}))
        conn.send({"ready": True})
        rest = HapticSample(0.0, 0, (*REST, 0.0), (0.0, 0.0, 0.0))
        _, duration = await _warm_up_then_start(conn, channel, rest)
        operator = Operator(ReferenceMotion(motion_seed, duration))
        force = (0.0, 0.0)

        def step(tick: int, newest: HapticSample | None) -> Tick:
            nonlocal force
            if newest is not None:
                force = (newest.force[0], newest.force[1])
            x, y = operator.step(tick * TICK, force)
            (vx, vy), (fx, fy) = operator.velocity, operator.rendered
            return (x, y, 0.0), (0.0, 0.0, 0.0), (x, y, vx, vy, fx, fy)

        await _control_loop(conn, channel, duration, MASTER_COLUMNS, step)

    _run(loop, main())


def _send(channel: Channel, payload: bytes) -> None:
    # The peer may have gone already (its loop ended first): nothing is left to control then.
    with contextlib.suppress(tdtp.EndpointClosedError):
        channel.send(payload)


def _delta(before: int | None, after: int | None) -> int | None:
    return None if before is None or after is None else after - before
