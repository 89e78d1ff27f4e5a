"""One end of tests/test_multipath_netns.py's session, run inside a network namespace.

    python multipath_peer.py slave PORT DURATION SCHEDULER[:CONTROLLER]
    python multipath_peer.py master PORT DURATION SCHEDULER[:CONTROLLER] SLAVE_ADDR LOCAL[=REMOTE] ...

CONTROLLER is the session's (and so each path's) rate controller: ``fixed`` at no limit unless
named, because the test is about failing over, and on a loaded machine each path's controller reads
the processes' late turns as queueing and holds copies back (docs/CONTROL.md 11.2), which is the
congestion control's business, tested in fake time; ``teleop`` (the default) for a figure on a quiet
machine.

Both ends send a numbered 100-byte sample every millisecond for DURATION seconds once the session is
up (after "ready" on stdout), then drain for half a second and print one JSON line: what they sent,
which sample numbers arrived, the watchdog's silences, and (the master) its path events and each
path's copies over time. Times are on the host's monotonic clock, which both namespaces share.
"""

from __future__ import annotations

import asyncio
import dataclasses
import itertools
import json
import math
import struct
import sys
import time
from typing import Any

import tdtp
from tdtp.control.fixed import FixedConfig

STAMP = struct.Struct(">I")
SIZE = 100
STALL = 0.05
"""A tick this much later than the one before: the process was not scheduled (recorded, so that the
test tells a peer that fell silent from a process that did not run)."""


async def stream(ep: tdtp.Endpoint, duration: float, record: dict[str, Any]) -> None:
    received: list[int] = []
    arrivals: list[float] = []
    silences: list[float] = []

    def on_data(sample: tdtp.DataReceived) -> None:
        received.append(STAMP.unpack_from(sample.payload)[0])
        arrivals.append(sample.received_at)

    ep.set_data_callback(on_data)
    ep.set_watchdog_callback(
        lambda event: (
            silences.append(time.monotonic()) if isinstance(event, tdtp.PeerSilent) else None
        )
    )
    print("ready", flush=True)
    start = time.monotonic()
    record["start"] = start
    sent = 0
    copies: list[tuple[float, dict[int, int]]] = []
    stalls: list[tuple[float, float]] = []  # this process did not run (a loaded machine)
    sent_at: list[float] = []  # when each sample was offered
    last = start
    async for _ in tdtp.Ticker(1000):
        now = time.monotonic()
        if now - last > STALL:
            stalls.append((last, now))
        last = now
        if now - start >= duration or ep.is_closed:
            break
        ep.send(STAMP.pack(sent) + bytes(SIZE - STAMP.size))
        sent_at.append(now)
        sent += 1
        if sent % 20 == 0:
            copies.append((now, {p.path_id: p.sent for p in ep.paths}))
    await asyncio.sleep(0.5)
    record.update(
        sent=sent,
        received=sorted(set(received)),
        duplicates_delivered=len(received) - len(set(received)),
        silences=silences,
        stalls=stalls,
        sent_at=sent_at,
        closed=ep.is_closed,
        copies=copies,
        events=[(e.at, e.path_id, e.state) for e in ep.paths.events],
        paths=[
            {"id": p.path_id, "state": p.state, "sent": p.sent, "first": p.first_received}
            for p in ep.paths
        ],
        drops=dict(ep.stats.drops),
        departed=ep.stats.sent.data_packets,
        longest_gaps=sorted(((b - a, a) for a, b in itertools.pairwise(arrivals)), reverse=True)[
            :3
        ],
        superseded=ep.stats.samples_superseded,
        multipath=dataclasses.asdict(ep.connection.multipath.stats)
        if ep.connection.multipath is not None
        else {},
        send_errors=ep.send_errors + ep.paths.send_errors,
    )


async def main(argv: list[str]) -> None:
    role, port, duration = argv[0], int(argv[1]), float(argv[2])
    record: dict[str, Any] = {"role": role}
    scheduler, _, controller = argv[3].partition(":")
    multipath = tdtp.MultipathConfig(scheduler=scheduler)  # type: ignore[arg-type]
    if controller:
        config = tdtp.ConnectionConfig(controller=controller, multipath=multipath)
    else:
        config = tdtp.ConnectionConfig(
            controller="fixed", controller_config=FixedConfig(rate=math.inf), multipath=multipath
        )
    if role == "slave":
        async with tdtp.listen("0.0.0.0", port, config=config) as server:
            print("listening", flush=True)
            ep = await asyncio.wait_for(server.accept(), 10.0)
            await stream(ep, duration, record)
            record["paths_learned"] = server.stats.paths_learned
    else:
        slave, locals_ = argv[4], argv[5:]
        async with tdtp.connect(slave, port, config=config, local_addresses=locals_) as ep:
            deadline = time.monotonic() + 5.0
            while len([p for p in ep.paths if p.state == "active"]) < len(locals_):
                if time.monotonic() > deadline:
                    raise SystemExit(f"paths not validated: {list(ep.paths)}")
                await asyncio.sleep(0.01)
            await stream(ep, duration, record)
    print(json.dumps(record), flush=True)


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1:]))
