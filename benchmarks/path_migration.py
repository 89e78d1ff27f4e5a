"""Path migration on loopback: does a session survive its master's NAT rebinding (issue 20, item 3)?

1 kHz of 100-byte samples each way through a loopback relay (``delay 1ms``); at ``--change`` seconds the
relay gives the master a new source port (``NetemRelay.rebind``: a new upstream socket, the old one
closed). Reported per run, each way, over the window from 1.5 s after the change to 0.2 s before the
end: the share of the samples *offered* that arrived (with the same share before the change beside
it: on a loaded machine the sender supersedes samples whatever the path does), and the share of the
samples *sent on the wire* that arrived. ``--baseline`` runs without the rebinding.

    .venv/bin/python benchmarks/path_migration.py [--runs N] [--seconds S] [--change S] [--baseline]
"""

from __future__ import annotations

import argparse
import asyncio
import time

from tdtp import Endpoint, Ticker, connect, listen
from tdtp.aio.relay import start_relay
from tdtp.protection import PresharedKey

KEY = PresharedKey(bytes(range(32)), name="operator")


async def _stream(ep: Endpoint, t0: float, total: float, sent: list[tuple[int, float]]) -> None:
    count = 0
    async for _ in Ticker(1000.0):
        now = time.monotonic() - t0
        if now > total or ep.is_closed:
            return
        count += 1
        sent.append((count, now))
        ep.send(count.to_bytes(4, "big") + bytes(96))


async def _read(ep: Endpoint, got: set[int]) -> None:
    async for sample in ep:
        got.add(int.from_bytes(sample.payload[:4], "big"))


def _wire(master: Endpoint, slave: Endpoint) -> list[tuple[int, int]]:
    return [
        (master.stats.sent.data_packets, slave.stats.samples_delivered),
        (slave.stats.sent.data_packets, master.stats.samples_delivered),
    ]


async def run(keyed: bool, total: float, change: float, rebind: bool) -> str:
    sent: dict[str, list[tuple[int, float]]] = {"m": [], "s": []}
    got: dict[str, set[int]] = {"m": set(), "s": set()}
    async with listen(keys=[KEY] if keyed else None) as server:
        relay = await start_relay(("127.0.0.1", 0), ("127.0.0.1", server.port), "delay 1ms")
        try:
            async with connect(*relay.address, key=KEY if keyed else None) as master:
                slave = await server.accept()
                t0 = time.monotonic()
                tasks = [
                    asyncio.create_task(_stream(master, t0, total, sent["m"])),
                    asyncio.create_task(_stream(slave, t0, total, sent["s"])),
                    asyncio.create_task(_read(slave, got["m"])),
                    asyncio.create_task(_read(master, got["s"])),
                ]
                await asyncio.sleep(change)
                if rebind:
                    await relay.rebind()
                await asyncio.sleep(1.5)
                first = _wire(master, slave)
                await asyncio.sleep(total - change - 1.7)
                last = _wire(master, slave)
                await asyncio.sleep(0.5)
                for task in tasks:
                    task.cancel()
                parts = []
                for (name, label), (s0, d0), (s1, d1) in zip(
                    (("m", "master->slave"), ("s", "slave->master")), first, last, strict=True
                ):
                    before = [k for k, t in sent[name] if 0.5 <= t <= change - 0.05]
                    after = [k for k, t in sent[name] if change + 1.5 <= t <= total - 0.2]
                    share = sum(k in got[name] for k in after) / len(after)
                    base = sum(k in got[name] for k in before) / len(before)
                    parts.append(
                        f"{label}: offered {share:.1%} (before the change {base:.1%}), "
                        f"sent {(d1 - d0) / (s1 - s0):.1%} of {s1 - s0}"
                    )
                stats = slave.stats
                return (
                    f"{'keyed' if keyed else 'unkeyed'}: {'; '.join(parts)}; migrations "
                    f"{stats.migrations}, validated {stats.paths_validated}, unvalidated bytes "
                    f"in/out {stats.unvalidated_bytes_in}/{stats.unvalidated_bytes_out}"
                )
        finally:
            await relay.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2)
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--change", type=float, default=2.0)
    parser.add_argument("--baseline", action="store_true")
    args = parser.parse_args()
    for keyed in (False, True):
        for _ in range(args.runs):
            print(asyncio.run(run(keyed, args.seconds, args.change, not args.baseline)))


if __name__ == "__main__":
    main()
