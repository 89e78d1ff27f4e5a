"""A TDTP master: an operator's hand tracing a circle, feeling the slave's wall.

    python examples/master.py 127.0.0.1:7000 [--seconds 10]

Sends a position sample 1000 times a second (a 10 cm circle at 0.5 Hz, so it crosses the slave's wall at
x = 5 cm) and prints one line per second: samples each way, RTT, loss, the rate the controller allows,
superseded samples and the force felt.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib

import tdtp
from tdtp.teleop.haptic_sample import HapticSample, master_trajectory


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("slave", help="HOST:PORT")
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    host, _, port = args.slave.rpartition(":")

    force = [0.0, 0.0, 0.0]
    received = 0

    def on_force(sample: tdtp.DataReceived) -> None:
        nonlocal received
        decoded = HapticSample.decode(sample.payload)
        if decoded is not None:
            force[:] = decoded.force  # a real master would drive its motors with this
            received += 1

    async with tdtp.connect(host.strip("[]"), int(port), on_data=on_force) as ep:
        print(f"connected to {ep.peer} (controller {ep.connection.config.controller})")
        start = last_print = tdtp.monotonic()
        last_sent = last_received = 0
        async for index in tdtp.Ticker(args.rate):
            now = tdtp.monotonic()
            if now - start >= args.seconds:
                break
            try:
                ep.send(master_trajectory(now - start, index, now).encode(100))
            except tdtp.EndpointClosedError as exc:  # the slave closed, or its silence outlasted
                print(f"the slave went away: {exc}")  # idle_timeout: the message says which
                break
            if now - last_print >= 1.0:
                stats = ep.stats
                interval = now - last_print
                print(
                    f"t={now - start:5.1f} s  out {(stats.sent.data_packets - last_sent) / interval:6.0f}/s"
                    f"  in {(received - last_received) / interval:6.0f}/s"
                    f"  srtt {stats.srtt * 1e3:6.3f} ms  lost {stats.packets_lost}"
                    f"  allowed {stats.rate:6.0f}/s  superseded {stats.samples_superseded}"
                    f"  force x {force[0]:6.2f} N"
                )
                last_print, last_sent, last_received = now, stats.sent.data_packets, received


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C ends it quietly
        asyncio.run(main())
