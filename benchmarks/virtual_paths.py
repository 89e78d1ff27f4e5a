"""Path profiles in virtual time: a master and a slave Connection through in-process netem links.

Each side offers a ``--size``-byte sample every ``1/--rate`` seconds, both ways; each direction crosses
its own :class:`tdtp.netem.NetemLink` with the profile (as ``tdtp demo --netem`` does on real
sockets). Time jumps from event to event, so a 10 s run costs about a second of CPU and no machine
load can change the figures.

    .venv/bin/python benchmarks/virtual_paths.py --controllers teleop,trinomial --duration 10 \\
        --seeds 1,2,3 'delay 20ms 5ms loss 2%' 'rate 500kbit'

Per profile and controller, the median over the seeds (and the range) of, each way:
``arrived/s`` (data packets that reached the receiver: delivered plus late), ``newest/s`` (samples
delivered: newer than any before them), ``late/s``, latency p50/p99 of the delivered samples, the
sender's declared losses and reordered packets, and for a ``rate`` profile the share of the link's
capacity the data used. A profile ``"A | B"`` gives each direction its own (A master to slave, B
slave to master: a bottleneck in one direction), and then each way also reports the receiver's
sample age p50 (``DataReceived.age``, or its estimate) beside the true latency.
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import struct
import sys
from dataclasses import dataclass, field
from typing import Any

from tdtp import Connection, ConnectionConfig, DataReceived, Role
from tdtp.netem import NetemLink, parse_netem

MASTER = ("192.0.2.1", 40001)
SLAVE = ("192.0.2.2", 40002)
_STAMP = struct.Struct(">d")
IP_UDP = 28


@dataclass
class Side:
    conn: Connection
    addr: tuple[str, int]
    link: NetemLink  # the link this side sends into
    latencies: list[float] = field(default_factory=list)
    ages: list[float] = field(default_factory=list)
    arrived: int = 0
    limits: dict[str, int] = field(default_factory=dict)


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def run(
    profile: str,
    controller: str,
    *,
    seed: int,
    duration: float,
    rate: float,
    size: int,
    warmup: float = 1.0,
) -> dict[str, Any]:
    forward, _, backward = profile.partition("|")
    spec = parse_netem(forward.strip())
    spec_back = parse_netem(backward.strip()) if backward.strip() else spec
    config = ConnectionConfig(controller=controller)  # type: ignore[arg-type]
    rng = random.Random(seed)
    master = Side(
        Connection(config, role=Role.MASTER, rng=random.Random(rng.random())),
        MASTER,
        NetemLink(spec, seed=rng.getrandbits(32)),
    )
    slave = Side(
        Connection(config, role=Role.SLAVE, rng=random.Random(rng.random())),
        SLAVE,
        NetemLink(spec_back, seed=rng.getrandbits(32)),
    )
    peer_of = {id(master): slave, id(slave): master}
    padding = bytes(size - _STAMP.size)
    now = 0.0
    master.conn.connect(SLAVE, now=now)
    established_at: float | None = None
    next_tick = 0.0
    measure_from = warmup  # skip the opening (the default: its first second)

    def flush(side: Side, t: float) -> None:
        for datagram, _addr in side.conn.datagrams_to_send(now=t):
            side.link.send(datagram, t)

    def take_events(side: Side, t: float) -> None:
        nonlocal established_at
        while (event := side.conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                if t >= measure_from:
                    side.latencies.append(t - _STAMP.unpack_from(event.payload)[0])
                    age = event.age
                    if age is not None:
                        side.ages.append(age)
            elif established_at is None and side is master:
                established_at = t

    end = duration + measure_from
    samples = 0
    sent_at_start: dict[int, int] = {}
    while now < end:
        candidates = [end]
        for side in (master, slave):
            timer = side.conn.get_timer()
            if timer is not None:
                candidates.append(timer)
            due = side.link.next_delivery()
            if due is not None:
                candidates.append(due)
        if established_at is not None:
            candidates.append(next_tick)
        now = max(now, min(candidates))
        for side in (master, slave):
            other = peer_of[id(side)]
            for datagram, _tag in side.link.deliver(now):
                other.conn.receive_datagram(datagram, side.addr, now=now)
            other_events = other
            take_events(other_events, now)
        for side in (master, slave):
            side.conn.handle_timer(now=now)
            take_events(side, now)
        if established_at is not None and now >= next_tick:
            if now >= measure_from and not sent_at_start:
                for side in (master, slave):
                    stats = side.conn.stats
                    sent_at_start[id(side)] = stats.received.data_packets
                    side.limits = {}
                    side.arrived = stats.drops.get("late", 0)
            for side in (master, slave):
                if side.conn.state.value == "established":
                    side.conn.send(_STAMP.pack(now) + padding, now=now)
            samples += 1
            next_tick += 1.0 / rate
            if now >= measure_from:
                for side in (master, slave):
                    limit = side.conn.stats.rate_limit.split(" ")[0] or "-"
                    side.limits[limit] = side.limits.get(limit, 0) + 1
        for side in (master, slave):
            flush(side, now)
    out: dict[str, Any] = {}
    for name, side in (("M->S", master), ("S->M", slave)):
        receiver = peer_of[id(side)]
        rstats = receiver.conn.stats
        sstats = side.conn.stats
        delivered = rstats.received.data_packets - sent_at_start.get(id(receiver), 0)
        late = rstats.drops.get("late", 0) - receiver.arrived
        wire = sstats.sent.bytes + IP_UDP * sstats.sent.datagrams
        out[name] = {
            "arrived_per_s": round((delivered + late) / duration, 1),
            "newest_per_s": round(delivered / duration, 1),
            "late_per_s": round(late / duration, 1),
            "latency_p50_ms": round(_percentile(receiver.latencies, 0.5) * 1e3, 2),
            "latency_p99_ms": round(_percentile(receiver.latencies, 0.99) * 1e3, 2),
            "age_p50_ms": round(_percentile(receiver.ages, 0.5) * 1e3, 2),
            "declared_lost": sstats.packets_lost,
            "reordered": sstats.packets_reordered,
            "loss_events": sstats.loss_events,
            "allowed_rate": round(sstats.rate, 1),
            "wire_kbit_s": round(wire * 8 / (duration + measure_from) / 1e3, 1),
            "decreases": [
                getattr(side.conn.controller, n, None)
                for n in ("delay_decrease_count", "loss_decrease_count", "losses_ignored")
            ],
            "limits": dict(sorted(side.limits.items(), key=lambda kv: -kv[1])),
        }
        side_rate = side.link.spec.rate
        if side_rate is not None:
            link = side.link.stats
            out[name]["link_use"] = round(
                link.bytes_out * 8 / (duration + measure_from) / side_rate.rate_bps, 3
            )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("profiles", nargs="+")
    parser.add_argument("--controllers", default="teleop,trinomial")
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--size", type=int, default=100)
    parser.add_argument(
        "--warmup", type=float, default=1.0, help="seconds not measured (1; 0: the start-up counts)"
    )
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    results: dict[str, Any] = {}
    for profile in args.profiles:
        for controller in args.controllers.split(","):
            runs = [
                run(
                    profile,
                    controller,
                    seed=s,
                    duration=args.duration,
                    rate=args.rate,
                    size=args.size,
                    warmup=args.warmup,
                )
                for s in seeds
            ]
            results.setdefault(profile, {})[controller] = runs
            for way in ("M->S", "S->M"):
                row = []
                for key in (
                    "arrived_per_s",
                    "newest_per_s",
                    "late_per_s",
                    "latency_p50_ms",
                    "latency_p99_ms",
                    "age_p50_ms",
                    "declared_lost",
                    "reordered",
                    "link_use",
                ):
                    values = [r[way][key] for r in runs if key in r[way]]
                    if values:
                        row.append(
                            f"{key}={statistics.median(values):g}[{min(values):g},{max(values):g}]"
                        )
                if not args.json:
                    print(
                        f"{profile!r:32s} {controller:9s} {way} "
                        + " ".join(row)
                        + f" limits={runs[0][way]['limits']} dec={runs[0][way]['decreases']}",
                        flush=True,
                    )
    if args.json:
        json.dump(results, sys.stdout, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
