"""Multipath over two recorded cellular paths: redundant and adaptive against each path alone.

Usage: ``python benchmarks/multipath.py [--quick] [--pair A,B ...] [--queue BYTES] [--duration S]
[--offsets S,...] [--static] [--json] [--out DIR]``

**Paths.** Each path is one of Mahimahi's recorded LTE traces (read by path from ``shared/traces``,
never copied here; docs/NETEM.md "Recorded traces"), its ``.down`` trace master to slave and its
``.up`` trace back, 20 ms of propagation after a DropTail queue of ``--queue`` bytes (150 kB), IPv4 +
UDP headers counted (``overhead 28``). The two paths of a pair are independent: different operators'
traces (``verizon,tmobile`` by default; ``--pair`` for others). ``--static`` replaces the traces by two
static netem profiles (``delay 30ms 10ms loss 2%`` and ``delay 40ms 15ms loss 2%``).

**Runs** (virtual time, the unchanged Connection at both ends, each path's links the same sans-IO
netem links the emulator uses; deterministic): ``A`` alone and ``B`` alone (single-path sessions,
the default controller), ``redundant`` and ``adaptive`` (one multipath session over both). Both ends
offer a 100-byte sample every millisecond for ``--duration`` seconds.

**Figures**, each way (tdtp.sim.scenarios.cellular.direction_figures): dropouts (100 ms windows of
the receiver's timeline with no sample), one-way delay p50/p95/p99 from generation to delivery,
samples/s, and bytes on the wire (TDTP datagrams plus 28 bytes of IPv4 + UDP each, every path and
every datagram: copies, ACKs, probes, reports) per sample delivered. ``min(A,B)``: each sample's
lower delay of the two single-path runs (a sample lost in both is lost): the issue's replay of "the
first copy of two independent paths wins". ``ideal(A+B)`` (traces only): each sample's earlier
arrival of the two paths' ideal senders (tdtp.sim.scenarios.cellular.ideal: every delivery
opportunity carries the newest samples, nothing queued; the traces' clocks started as the redundant
run's links started them): what the pair's capacity allows. Where both traces are out at once for
over 100 ms it has dropouts too: a window without a delivery opportunity on either path is a
dropout for any sender.

Issue 33's targets, each way: redundant 0 dropouts (shown beside the ideal's) and p99 within 1.2x of
``min(A,B)``'s;
adaptive at most 1.3x the bytes of one path (the better of A and B) with p99 within 10 % of
redundant's.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import random
import struct
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cellular import TRACES, find_traces

import tdtp
from tdtp import Connection, ConnectionConfig, MultipathConfig, Role
from tdtp.netem import NetemLink, parse_netem
from tdtp.sim.scenarios.cellular import Arrivals, direction_figures, ideal

Json = dict[str, Any]

STATIC = {"static-a": "delay 30ms 10ms loss 2%", "static-b": "delay 40ms 15ms loss 2%"}
DELAY = "20ms"
PROPAGATION = 0.020
RATE = 1000.0
SIZE = 100
IP_UDP = 28
QUEUE = 150_000
DURATION, QUICK_DURATION = 60.0, 10.0
OFFSETS, QUICK_OFFSETS = (0.0, 40.0), (0.0,)
DRAIN = 3.0
STAMP = struct.Struct(">Id")
MASTER = ("192.0.2.1", 40001)
SLAVE = ("192.0.2.2", 40002)
RUNS = ("A", "B", "redundant", "adaptive")
TARGET_REDUNDANT_P99 = 1.2
TARGET_ADAPTIVE_BYTES = 1.3
TARGET_ADAPTIVE_P99 = 1.1


def path_spec(traces: Path | None, name: str, way: str, queue: int, offset: float) -> str:
    """One direction of a path: a trace's ``.down`` (master to slave) or ``.up``, or a profile."""
    if name in STATIC:
        return STATIC[name]
    assert traces is not None
    suffix = "down" if way == "ms" else "up"
    text = f"delay {DELAY} trace {traces / TRACES[name]}.{suffix}"
    if offset:
        text += f" offset {offset:g}s"
    return f"{text} overhead {IP_UDP} limit-bytes {queue}"


@dataclass
class Way:
    """One direction: the links per path, what was sent into them, what the application got."""

    links: list[NetemLink]
    bytes: int = 0
    datagrams: int = 0
    delays: dict[int, float] = field(default_factory=dict)
    """Sample index -> one-way delay (generation to delivery)."""
    arrivals: Arrivals | None = None


def run(job: Json) -> Json:
    """One run: ``job["paths"]`` the specs of the paths it uses (one: single path), each a pair
    (master-to-slave spec, slave-to-master spec); ``job["scheduler"]`` for two."""
    t0 = time.process_time()
    specs = job["paths"]
    duration = job["duration"]
    seed = job["seed"]
    multipath = len(specs) > 1
    config = ConnectionConfig(min_peer_payload=SIZE)
    if multipath:
        config = ConnectionConfig(
            min_peer_payload=SIZE, multipath=MultipathConfig(scheduler=job["scheduler"])
        )
    master = Connection(config, role=Role.MASTER, rng=random.Random(seed))
    slave = Connection(config, role=Role.SLAVE, rng=random.Random(seed + 1))
    ms = Way([NetemLink(parse_netem(a), seed=seed + 10 + i) for i, (a, _) in enumerate(specs)])
    sm = Way([NetemLink(parse_netem(b), seed=seed + 20 + i) for i, (_, b) in enumerate(specs)])
    master_addrs = [("192.0.2.1", 40001 + i) for i in range(len(specs))]
    local_of = {addr: i for i, addr in enumerate(master_addrs)}
    padding = bytes(SIZE - STAMP.size)
    now = 0.0
    start = 1.0  # the opening and the paths' validation before the measured window
    end = start + duration
    generated: dict[str, list[float]] = {"ms": [], "sm": []}
    index = {"ms": 0, "sm": 0}
    opened = False

    def put(way: Way, local: int, data: bytes, src: tuple[str, int], t: float) -> None:
        way.links[local].send(data, t, src)
        way.bytes += len(data) + IP_UDP
        way.datagrams += 1

    def flush(t: float) -> None:
        for data, _addr in master.datagrams_to_send(now=t):
            put(ms, 0, data, master_addrs[0], t)
        paths = master.multipath
        if paths is not None and paths.routed:
            routed, paths.routed = paths.routed, []
            for data, _remote, local in routed:
                put(ms, local, data, master_addrs[local], t)
        for data, addr in slave.datagrams_to_send(now=t):
            put(sm, local_of.get((addr[0], addr[1]), 0), data, SLAVE, t)

    def drain(conn: Connection, way_key: str, t: float) -> None:
        delays = (sm if way_key == "sm" else ms).delays
        while (event := conn.next_event()) is not None:
            if isinstance(event, tdtp.DataReceived) and len(event.payload) >= STAMP.size:
                k, sent = STAMP.unpack_from(event.payload)
                if k not in delays:
                    delays[k] = t - sent

    master.connect(SLAVE, now=now)
    flush(now)
    next_tick = start
    while True:
        times = [next_tick] if now < end else []
        for link in (*ms.links, *sm.links):
            due = link.next_delivery()
            if due is not None:
                times.append(due)
        for conn in (master, slave):
            due = conn.get_timer()
            if due is not None:
                times.append(due)
        if not times:
            break
        now = max(now, min(times))
        if now > end + DRAIN:
            break
        for link in ms.links:
            for data, src in link.deliver(now):
                slave.receive_datagram(data, src, now=now)  # type: ignore[arg-type]
        paths = master.multipath
        for i, link in enumerate(sm.links):
            for data, _src in link.deliver(now):
                if paths is not None:
                    paths.rx_local = i
                master.receive_datagram(data, SLAVE, now=now)
                if paths is not None:
                    paths.rx_local = 0
        for conn in (master, slave):
            due = conn.get_timer()
            if due is not None and due <= now:
                conn.handle_timer(now=now)
        drain(slave, "ms", now)
        drain(master, "sm", now)
        if not opened and master.state is tdtp.State.ESTABLISHED:
            opened = True
            if multipath and master.multipath is not None:
                for local in range(1, len(specs)):
                    master.multipath.open_path(local, SLAVE, now)
        if now >= next_tick and now < end:
            for conn, key in ((master, "ms"), (slave, "sm")):
                if conn.state is tdtp.State.ESTABLISHED:
                    k = index[key]
                    index[key] += 1
                    generated[key].append(now)
                    conn.send(STAMP.pack(k, now) + padding, now=now)
            next_tick += 1.0 / RATE
        flush(now)
    out: Json = {**job, "cpu_seconds": round(time.process_time() - t0, 1)}
    out["origins"] = {  # when each link's trace clock started (the ideal is computed from them)
        key: [q.origin if (q := link.trace_queue) is not None else None for link in way.links]
        for key, way in (("ms", ms), ("sm", sm))
    }
    for key, way in (("ms", ms), ("sm", sm)):
        gens = generated[key]
        out[key] = {
            "generated": gens,
            "delays": {str(k): d for k, d in way.delays.items()},
            "bytes": way.bytes,
            "datagrams": way.datagrams,
        }
        out[key]["figures"] = figures(gens, way.delays, start, end, way.bytes)
    for key, conn in (("master", master), ("slave", slave)):
        paths = conn.multipath
        if paths is not None:
            out[key] = {
                "duplicates": paths.stats.duplicates,
                "single_samples": paths.stats.single_samples,
                "spread_samples": paths.stats.spread_samples,
                "breaches": paths.stats.breaches,
                "paths": [
                    {"id": p.path_id, "state": p.state, "sent": p.sent, "first": p.first_delivered}
                    for p in paths.path_stats(now)
                ],
            }
    return out


def figures(
    generated: list[float], delays: dict[int, float], start: float, end: float, wire: int
) -> Json:
    arrivals = Arrivals(start, end, len(generated))
    pairs = sorted(
        (generated[k] + d, generated[k]) for k, d in delays.items() if k < len(generated)
    )
    arrivals.arrived = [a for a, _ in pairs]
    arrivals.generated = [g for _, g in pairs]
    result = direction_figures(arrivals, propagation=PROPAGATION)
    delivered = result["delivered"]
    result["bytes_per_sample"] = wire / delivered if delivered else math.inf
    result["wire_bytes"] = wire
    return result


def per_sample_minimum(a: Json, b: Json, start: float, end: float) -> Json:
    """Each sample's lower delay of two single-path runs (same generation schedule)."""
    gens = a["generated"]
    delays: dict[int, float] = {}
    for k in range(len(gens)):
        da, db = a["delays"].get(str(k)), b["delays"].get(str(k))
        if da is None and db is None:
            continue
        delays[k] = min(x for x in (da, db) if x is not None)
    return figures(gens, delays, start, end, 0)


def ideal_pair(run: Json, start: float, duration: float) -> Json:
    """Each way: the figures of each sample's earlier arrival over the two ideal senders of the
    paths ``run`` used, their traces' clocks started where its links' started."""
    out: Json = {}
    generated = [start + k / RATE for k in range(round(duration * RATE))]
    for i, key in enumerate(("ms", "sm")):
        delays: dict[int, float] = {}  # sample index -> its lower delay of the two
        for spec, origin in zip(run["paths"], run["origins"][key], strict=True):
            if origin is None:
                return {}  # static profiles: no capacity to compute an ideal from
            arrivals = ideal(spec[i], start=start, duration=duration, rate=RATE, origin=origin)
            for g, a in zip(arrivals.generated, arrivals.arrived, strict=True):
                k = round((g - start) * RATE)
                delays[k] = min(a - g, delays.get(k, math.inf))
        out[key] = figures(generated, delays, start, start + duration, 0)
    return out


def jobs(args: argparse.Namespace, traces: Path | None) -> list[Json]:
    out = []
    for pair in args.pair:
        a, b = pair.split(",")
        for offset in args.offsets:
            pa = [path_spec(traces, a, w, args.queue, offset) for w in ("ms", "sm")]
            pb = [path_spec(traces, b, w, args.queue, offset) for w in ("ms", "sm")]
            base = {"pair": pair, "offset": offset, "duration": args.duration, "seed": 7}
            out.append({**base, "run": "A", "paths": [pa]})
            out.append({**base, "run": "B", "paths": [pb]})
            for scheduler in ("redundant", "adaptive"):
                out.append({**base, "run": scheduler, "paths": [pa, pb], "scheduler": scheduler})
    return out


def summarise(results: list[Json]) -> list[Json]:
    """Per pair and offset, each way: the four runs, min(A,B), and the targets."""
    rows = []
    groups: dict[tuple[str, float], dict[str, Json]] = {}
    for result in results:
        groups.setdefault((result["pair"], result["offset"]), {})[result["run"]] = result
    for (pair, offset), runs in sorted(groups.items()):
        for way in ("ms", "sm"):
            start = 1.0
            end = start + runs["A"]["duration"]
            best = per_sample_minimum(runs["A"][way], runs["B"][way], start, end)
            floor = ideal_pair(runs["redundant"], start, end - start).get(way)
            figs = {name: runs[name][way]["figures"] for name in RUNS}
            one_path = min(figs["A"]["bytes_per_sample"], figs["B"]["bytes_per_sample"])
            red, ada = figs["redundant"], figs["adaptive"]
            rows.append(
                {
                    "pair": pair,
                    "offset": offset,
                    "way": way,
                    "runs": {name: brief(f) for name, f in figs.items()},
                    "min_AB": brief(best),
                    **({"ideal_AB": brief(floor)} if floor is not None else {}),
                    "targets": {
                        "redundant_dropouts": red["dropouts"],
                        "ideal_dropouts": floor["dropouts"] if floor is not None else None,
                        "redundant_p99_over_min": red["delay_ms"]["p99"] / best["delay_ms"]["p99"],
                        "adaptive_bytes_over_one_path": ada["bytes_per_sample"] / one_path,
                        "adaptive_p99_over_redundant": ada["delay_ms"]["p99"]
                        / red["delay_ms"]["p99"],
                    },
                }
            )
    return rows


def brief(f: Json) -> Json:
    return {
        "dropouts": f["dropouts"],
        "p50": round(f["delay_ms"]["p50"], 1),
        "p95": round(f["delay_ms"]["p95"], 1),
        "p99": round(f["delay_ms"]["p99"], 1),
        "samples_per_s": round(f["samples_per_s"], 1),
        "bytes_per_sample": round(f.get("bytes_per_sample", math.nan), 1),
    }


def table(rows: list[Json]) -> str:
    lines = [
        "| pair | offset | way | run | dropouts | p50 ms | p95 ms | p99 ms | samples/s | bytes/sample |",
        "|---|---:|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        extra = [("min(A,B)", row["min_AB"])]
        if "ideal_AB" in row:
            extra.append(("ideal(A+B)", row["ideal_AB"]))
        for name, f in (*row["runs"].items(), *extra):
            lines.append(
                f"| {row['pair']} | {row['offset']:g} | {row['way']} | {name} | {f['dropouts']} | "
                f"{f['p50']} | {f['p95']} | {f['p99']} | {f['samples_per_s']} | "
                f"{f['bytes_per_sample'] if name in row['runs'] else '-'} |"
            )
        t = row["targets"]
        floor = "" if t.get("ideal_dropouts") is None else f" (ideal {t['ideal_dropouts']})"
        lines.append(
            f"| | | | **targets** | red. {t['redundant_dropouts']}{floor} | red. p99/min "
            f"{t['redundant_p99_over_min']:.2f} (<= {TARGET_REDUNDANT_P99}) | adapt. bytes "
            f"{t['adaptive_bytes_over_one_path']:.2f} (<= {TARGET_ADAPTIVE_BYTES}) | adapt. p99/red. "
            f"{t['adaptive_p99_over_redundant']:.2f} (<= {TARGET_ADAPTIVE_P99}) | | |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="10 s, one offset")
    parser.add_argument("--pair", action="append", help="two paths, e.g. verizon,tmobile")
    parser.add_argument("--queue", type=int, default=QUEUE, help="bytes of each link's queue")
    parser.add_argument("--duration", type=float)
    parser.add_argument("--offsets", type=lambda t: [float(x) for x in t.split(",")])
    parser.add_argument("--static", action="store_true", help="two static netem profiles")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args(argv)
    traces = find_traces()
    if args.static:
        args.pair = ["static-a,static-b"]
    elif traces is None:
        print(
            "multipath.py: no shared/traces folder above the checkout; use --static",
            file=sys.stderr,
        )
        return 2
    args.pair = args.pair or ["verizon,tmobile"]
    args.duration = args.duration or (QUICK_DURATION if args.quick else DURATION)
    args.offsets = args.offsets or list(QUICK_OFFSETS if args.quick else OFFSETS)
    work = jobs(args, traces)
    with multiprocessing.get_context("fork").Pool(max(1, args.jobs)) as pool:
        results = pool.map(run, work)
    rows = summarise(results)
    cpu = sum(r["cpu_seconds"] for r in results)
    extras = {
        f"{r['pair']}@{r['offset']:g} {r['run']}": {k: r[k] for k in ("master", "slave") if k in r}
        for r in results
        if r["run"] in ("redundant", "adaptive")
    }
    if args.json:
        print(json.dumps({"rows": rows, "multipath": extras, "cpu_seconds": cpu}, indent=1))
    else:
        print(table(rows))
        print(f"\n(virtual time; {cpu:.0f} s of CPU over {len(results)} runs)")
        for name, extra in extras.items():
            print(name, json.dumps(extra))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "multipath.json").write_text(
            json.dumps({"rows": rows, "multipath": extras}, indent=1)
        )
        (args.out / "multipath.md").write_text(table(rows) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
