"""The robot's side of the tutorial: a keyed slave that follows the operator's joystick."""

import asyncio
import sys

import tdtp


def drive(x: float, y: float) -> None:
    """Stands in for the robot's motors."""


def hold() -> None:
    """Stands in for the robot's safe stop."""


async def serve(ep: tdtp.Endpoint) -> None:
    async for _ in tdtp.Ticker(500):  # the robot's control loop, 500 times a second
        if ep.is_closed:
            hold()
            return
        sample = ep.latest()  # the newest command; None before the first
        if sample is None or ep.peer_silent:  # nothing heard for 100 ms: stop
            hold()
        else:
            x, y = (float(v) for v in sample.payload.split())
            drive(x, y)
            ep.send(b"ok %.3f %.3f" % (x, y))  # what the robot did, back to the operator


async def main(key_file: str, host: str, port: int) -> None:
    keys = tdtp.load_keys(key_file)  # every operator's key this robot accepts
    async with tdtp.listen(host, port, keys=keys) as server, asyncio.TaskGroup() as group:
        print(f"robot listening on {host}:{server.port}", flush=True)
        async for ep in server:
            print(f"operator {ep.connection.key.name} connected", flush=True)
            group.create_task(serve(ep))


if __name__ == "__main__":
    key_file, host, port = sys.argv[1:4]  # python robot.py robot.keys 0.0.0.0 7000
    asyncio.run(main(key_file, host, int(port)))
