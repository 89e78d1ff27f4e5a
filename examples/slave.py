"""A TDTP slave: a robot arm that follows the master's position and reports contact forces.

Run it first, then ``python examples/master.py 127.0.0.1:7000`` in another terminal:

    python examples/slave.py --port 7000

Each period (1 kHz) the slave answers with the force of a virtual spring wall at x = 5 cm, computed
from the newest position it has. It prints one line per second for each connected master, and a line
when the watchdog finds a master silent (the arm would hold its position) and when it is back.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib

import tdtp
from tdtp.teleop.haptic_sample import HapticSample, slave_feedback


async def serve_master(ep: tdtp.Endpoint, rate: float) -> None:
    newest = (0.0, 0.0, 0.0)
    received = 0

    def on_position(sample: tdtp.DataReceived) -> None:
        nonlocal newest, received
        decoded = HapticSample.decode(sample.payload)
        if decoded is not None:
            newest = decoded.position
            received += 1

    def on_watchdog(event: tdtp.PeerSilent | tdtp.PeerResumed) -> None:
        # A real arm would hold its position here (or stop), and release it on PeerResumed.
        if isinstance(event, tdtp.PeerSilent):
            print(f"{ep.peer}: silent since {event.since:.3f}: holding the arm")
        else:
            print(f"{ep.peer}: back after {event.silent_for:.3f} s: following again")

    ep.set_data_callback(on_position)
    ep.set_watchdog_callback(on_watchdog)
    last_print, last_received = tdtp.monotonic(), 0
    async for index in tdtp.Ticker(rate):
        if ep.is_closed:
            break
        ep.send(slave_feedback(newest, index, tdtp.monotonic()).encode(100))
        now = tdtp.monotonic()
        if now - last_print >= 1.0:
            stats = ep.stats
            print(
                f"{ep.peer}: {(received - last_received) / (now - last_print):6.0f} positions/s in, "
                f"srtt {stats.srtt * 1e3:6.3f} ms, lost {stats.packets_lost}, "
                f"allowed {stats.rate:6.0f}/s, superseded {stats.samples_superseded}, "
                f"force x {slave_feedback(newest, 0, 0).force[0]:6.2f} N"
            )
            last_print, last_received = now, received
    closed = await ep.wait_closed()
    print(f"{ep.peer}: connection over ({closed.cause.value}: {closed.detail})")


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=7000)
    parser.add_argument("--rate", type=float, default=1000.0)
    args = parser.parse_args()
    async with tdtp.listen(args.host, args.port) as server:
        print(f"slave listening on {args.host}:{server.port}")
        async with asyncio.TaskGroup() as group:
            async for ep in server:
                print(f"master {ep.peer} connected")
                group.create_task(serve_master(ep, args.rate))


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C ends it quietly
        asyncio.run(main())
