"""A minimal haptic loop: a hand pushes into a virtual wall and feels it push back.

    python examples/haptic_loop.py [--seconds 3]

Both ends run in this one process, over a real UDP socket on 127.0.0.1: the slave (the robot's side)
listens, the master (the operator's haptic device) connects. 1000 times a second the master sends
the hand's position and the slave answers with the force of a spring wall at x = 5 cm, computed from
the newest position it has; the master renders the newest force. Typed samples (SampleCodec), the
newest value at each end (``ep.latest()``), one Ticker per end. Split it into two processes by
running ``slave()`` on the robot and ``master()`` on the operator's machine.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
from dataclasses import dataclass

import tdtp
from tdtp.teleop.schema import SampleCodec

WALL_X = 0.05  # metres
STIFFNESS = 500.0  # newtons per metre


@dataclass(frozen=True, slots=True)
class Position:
    x: float
    y: float
    z: float


@dataclass(frozen=True, slots=True)
class Force:
    fx: float
    fy: float
    fz: float


POSITION = SampleCodec(Position, x="f32", y="f32", z="f32")
FORCE = SampleCodec(Force, fx="f32", fy="f32", fz="f32")


async def slave(server: tdtp.Server, seconds: float) -> int:
    """The robot's side: answer every tick with the wall's force on the newest position."""
    ep = await server.accept()
    answered = 0
    async for tick in tdtp.Ticker(1000):
        if tick >= seconds * 1000 or ep.is_closed:
            return answered
        sample = ep.latest()
        if sample is not None:
            hand = POSITION.decode(sample.payload)
            push = -STIFFNESS * max(0.0, hand.x - WALL_X)  # the wall pushes back once touched
            ep.send(FORCE.encode(Force(push, 0.0, 0.0)))
            answered += 1
    return answered


async def master(port: int, seconds: float) -> dict[str, float]:
    """The operator's haptic device: the hand moves in and out of the wall; render the force."""
    strongest = 0.0
    async with tdtp.connect("127.0.0.1", port) as ep:
        async for tick in tdtp.Ticker(1000):
            t = tick / 1000
            if t >= seconds:
                break
            ep.send(POSITION.encode(Position(0.05 + 0.02 * math.sin(2 * math.pi * t), 0.0, 0.0)))
            sample = ep.latest()
            if sample is not None:
                force = FORCE.decode(sample.payload)  # a real device would render it here
                strongest = min(strongest, force.fx)
        return {
            "positions_sent": ep.stats.sent.data_packets,
            "forces_received": ep.stats.samples_delivered,
            "strongest_push_n": round(strongest, 3),
            "srtt_ms": round(ep.stats.srtt * 1e3, 3),
        }


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    args = parser.parse_args()
    async with tdtp.listen("127.0.0.1", 0) as server:
        answered, report = await asyncio.gather(
            slave(server, args.seconds + 1.0), master(server.port, args.seconds)
        )
    print(json.dumps({**report, "forces_sent": answered}))


if __name__ == "__main__":
    asyncio.run(main())
