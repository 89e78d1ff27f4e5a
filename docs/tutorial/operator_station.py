"""The operator's side of the tutorial: a keyed master that streams a joystick at 1 kHz."""

import asyncio
import math
import sys

import tdtp


def joystick(t: float) -> tuple[float, float]:
    """Stands in for the operator's joystick: a slow circle."""
    return math.cos(t), math.sin(t)


async def main(robot: str, key_file: str, seconds: float) -> None:
    host, _, port = robot.rpartition(":")
    key = tdtp.load_key(key_file)  # this operator's key: the file's first
    async with tdtp.connect(host, int(port), key=key) as ep:
        print(f"connected to {ep.peer}, keyed as {ep.connection.key.name}", flush=True)
        async for tick in tdtp.Ticker(1000):  # 1000 commands a second, on absolute deadlines
            if tick >= seconds * 1000:
                break
            x, y = joystick(tick / 1000)
            ep.send(b"%.3f %.3f" % (x, y))  # never blocks; a newer command replaces an unsent one
            if tick % 1000 == 0:
                answer = ep.latest()
                print(
                    f"robot says {answer.payload.decode() if answer else '-'}, "
                    f"round trip {ep.stats.srtt * 1e3:.2f} ms",
                    flush=True,
                )
        print(
            f"sent {ep.stats.sent.data_packets}, the robot answered {ep.stats.samples_delivered}",
            flush=True,
        )


if __name__ == "__main__":
    robot, key_file, seconds = sys.argv[
        1:4
    ]  # python operator_station.py 192.0.2.7:7000 station.keys 5
    asyncio.run(main(robot, key_file, float(seconds)))
