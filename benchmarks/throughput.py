"""How many samples per second does a tdtp pair carry on loopback, against raw asyncio and uvloop UDP?

Usage: ``python benchmarks/throughput.py [--seconds 1] [--repeat 3] [--json] [--both] [--profile]
[--variants NAME ...]``

Method. Every variant is a *pair of processes*, each pinned to its own CPU (on 2 cores: one each), talking
over 127.0.0.1 with 100-byte payloads:

- the **receiver** binds a UDP socket and counts the samples its application sees;
- the **sender** offers samples as fast as it can: ``batch`` (64) sends, then one ``await
  asyncio.sleep(0)`` so the loop can read what comes back (tdtp's ACKs), and again.

The figure is the **receive rate**: samples delivered to the receiving application per second, counted
over a window of ``--seconds`` that opens ``warmup`` (0.3 s) after the first sample arrived. A sender
faster than its receiver overflows the receiver's socket buffer (the kernel default, the same for
every variant); the receive rate is then what the pair carries, and the sender's own rate, the
delivered fraction and both processes' CPU (``getrusage``, % of one core) show who the bottleneck is.

Variants (all in the same run, interleaved: repetition i runs every variant once):

- ``raw asyncio``: a ``DatagramProtocol`` pair on the stock loop, ``transport.sendto`` / a counter in
  ``datagram_received``;
- ``raw uvloop``: the same protocol classes on uvloop (the baseline of the ratio);
- ``tdtp uvloop`` / ``tdtp asyncio``: ``tdtp.connect`` / ``tdtp.listen`` with flow control out of the way
  (``controller="fixed"``, ``FixedConfig(rate=math.inf)``): the sender calls ``ep.send``, the receiver
  counts in an ``on_data`` callback. Piggybacked-ACK mode; with no reverse data the receiver sends a
  stand-alone ACK every 7 samples (docs/PROTOCOL.md 3.2).
- ``tdtp uvloop, keyed``: the same with a pre-shared key (every datagram sealed with AES-128-GCM,
  payloads encrypted), measured exactly like the unkeyed pair.
- ``tdtp uvloop, pure-Python build``: the same code with ``TDTP_PURE_PYTHON=1`` in both processes, so
  that the compiled core is not used: the speed a machine without a C compiler gets.
- ``tdtp uvloop, loop's transport``: the compiled build on uvloop's own datagram transport
  (``TDTP_DATAGRAM_LAYER=0``) instead of the batched datagram layer (recvmmsg/sendmmsg,
  :mod:`tdtp.aio.datagram`) that ``tdtp uvloop`` runs on by default where its C engine is built.

**Capacity ratio.** The measured ratio compares receive rates, which another tenant taking a share of
either core moves at once. Beside it stands the *capacity ratio*: each process's CPU time
(``getrusage``) per packet, the pair's bottleneck being the process that spends more per packet, and
the ratio raw bottleneck CPU per packet / tdtp's, repetition by repetition. CPU time per packet hardly
changes when a neighbour steals wall time, so it says what the pair would carry with its cores to
itself. One way, the receiver's CPU counts per sample received and the sender's per sample offered;
both ways, each process both sends and receives, and its CPU counts per packet handled (sent plus
received in the window).

A run during which other processes on the machine used more than 20 % of a core (``/proc/[pid]/stat``)
is run again (at most ``--repeat`` reruns in all); if it is still contended, the statistics leave it out
as long as at least two runs are clean (the row says how many were left out).

With ``--both`` the saturated flow runs in both directions at once (each process sends and receives;
the figure is the sum of both directions' receive rates), for raw uvloop and tdtp uvloop (both builds).

**The stock loop is bimodal.** asyncio's selector datagram transport reads every datagram with
``recvfrom(256 KiB)``. glibc serves that from the heap (about 1.4 us here) or through mmap/mremap/munmap
and heap trimming (about 14 us) depending on its *dynamic* mmap and trim thresholds, that is on what the
process happened to allocate and free before. So the same code measures ~210k or ~57k raw samples/s
on this VM from one set of imports to another; within one run every variant shares the same history.
``MALLOC_TOP_PAD_=1048576`` in the environment pins the fast mode (uvloop is not affected).

``--profile`` adds one tdtp uvloop repetition under cProfile in both processes and prints the functions
with the most own time (the profiler slows the run: read shares, not rates).

Targets (issue 23, raising issue 12's 0.8 and 0.7): tdtp uvloop / raw uvloop >= 1.0 one way,
measured or capacity ratio (both are reported), >= 0.9 both ways; the pure-Python build no slower, against raw uvloop, than the whole
library was before the compiled core (the 2026-11-21 run: 0.385 one way, 0.298 both ways).
"""

from __future__ import annotations

import asyncio
import math
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat

from tdtp import ConnectionClosedError, ConnectionConfig, DataReceived, PresharedKey
from tdtp.aio.api import connect, listen
from tdtp.aio.timer import monotonic
from tdtp.control.fixed import FixedConfig

TARGET_RATIO = 1.0
TARGET_RATIO_BOTH = 0.9
"""Issue 23's bars for tdtp uvloop / raw uvloop (issue 12's were 0.8 and 0.7)."""
PURE_BEFORE = {"pure-uvloop": 0.385, "pure-uvloop-both": 0.298}
"""tdtp uvloop / raw uvloop in the suite's run of 2026-11-21, before the compiled core (issue 12's
"no slower than today" for the pure-Python build)."""
BENCH_KEY = PresharedKey(bytes(range(32)), "bench")
PAYLOAD = bytes(range(100))
BATCH = 64
WARMUP = 0.3
UNLIMITED = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))

# variant key -> (implementation, loop, both directions). Implementations: raw sockets, tdtp,
# tdtp keyed, tdtp's pure-Python build.
VARIANTS: dict[str, tuple[str, str, bool]] = {
    "raw-asyncio": ("raw", "asyncio", False),
    "raw-uvloop": ("raw", "uvloop", False),
    "tdtp-uvloop": ("tdtp", "uvloop", False),
    "tdtp-asyncio": ("tdtp", "asyncio", False),
    "keyed-uvloop": ("keyed", "uvloop", False),
    "pure-uvloop": ("pure", "uvloop", False),
    "stock-uvloop": ("stock", "uvloop", False),
    "raw-uvloop-both": ("raw", "uvloop", True),
    "tdtp-uvloop-both": ("tdtp", "uvloop", True),
    "pure-uvloop-both": ("pure", "uvloop", True),
    "stock-uvloop-both": ("stock", "uvloop", True),
}
LABELS = {
    "raw-asyncio": "raw asyncio",
    "raw-uvloop": "raw uvloop",
    "tdtp-uvloop": "tdtp uvloop",
    "tdtp-asyncio": "tdtp asyncio",
    "keyed-uvloop": "tdtp uvloop, keyed (AES-128-GCM)",
    "pure-uvloop": "tdtp uvloop, pure-Python build",
    "raw-uvloop-both": "raw uvloop, both ways",
    "tdtp-uvloop-both": "tdtp uvloop, both ways",
    "pure-uvloop-both": "tdtp uvloop, pure-Python build, both ways",
    "stock-uvloop": "tdtp uvloop, loop's transport",
    "stock-uvloop-both": "tdtp uvloop, loop's transport, both ways",
}


# ---------------------------------------------------------------------------- in the workers


@dataclass
class RxCounter:
    """Samples seen by the receiving application."""

    count: int = 0

    def on_data(self, _: DataReceived) -> None:
        self.count += 1


class RawProtocol(asyncio.DatagramProtocol):
    """The baseline: counts datagrams; remembers the first sender (to answer it in --both mode)."""

    def __init__(self, rx: RxCounter) -> None:
        self.rx = rx
        self.peer: asyncio.Future[Any] = asyncio.get_running_loop().create_future()

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.rx.count += 1
        if not self.peer.done():
            self.peer.set_result(addr)

    def error_received(self, exc: Exception) -> None:
        pass  # ICMP port unreachable once the peer is gone


@dataclass
class Blast:
    sent: int = 0
    elapsed: float = 0.0
    cpu: float = 0.0
    stopped_by: str = ""


@dataclass
class Control:
    """The pipe to the coordinator, polled cheaply from the loop."""

    conn: Any
    stop: bool = False
    extra: Json = field(default_factory=dict)

    def poll(self) -> bool:
        if not self.stop and self.conn.poll():
            message = self.conn.recv()
            self.stop = bool(message.get("stop"))
        return self.stop


async def blast(send: Any, control: Control, cap: float, result: Blast | None = None) -> Blast:
    """Offer samples as fast as possible until told to stop (or ``cap`` seconds, a safety net);
    ``result.sent`` counts them as they go."""
    if result is None:
        result = Blast()
    start, cpu0 = monotonic(), common.cpu_seconds()
    end = start + cap
    payload = PAYLOAD
    sent = 0
    rounds = 0
    try:
        while True:
            for _ in range(BATCH):
                send(payload)
            sent += BATCH
            result.sent = sent
            await asyncio.sleep(0)
            rounds += 1
            if rounds % 16 == 0:
                if control.poll():
                    result.stopped_by = "coordinator"
                    break
                if monotonic() >= end:
                    result.stopped_by = "cap"
                    break
    except ConnectionClosedError:
        result.stopped_by = "peer closed"
    result.sent = sent
    result.elapsed = monotonic() - start
    result.cpu = common.cpu_seconds() - cpu0
    return result


async def receive_window(
    rx: RxCounter, warmup: float, seconds: float, sending: Blast | None = None
) -> Json:
    """Count samples over ``seconds``, starting ``warmup`` after the first one (and what this
    process sent meanwhile, when it sends too)."""
    while rx.count == 0:
        await asyncio.sleep(0.002)
    await asyncio.sleep(warmup)
    n0, t0, c0 = rx.count, monotonic(), common.cpu_seconds()
    s0 = sending.sent if sending is not None else 0
    await asyncio.sleep(seconds)
    n1, t1, c1 = rx.count, monotonic(), common.cpu_seconds()
    s1 = sending.sent if sending is not None else 0
    return {
        "received": n1 - n0,
        "elapsed": t1 - t0,
        "rate": (n1 - n0) / (t1 - t0),
        "sent_rate": (s1 - s0) / (t1 - t0),
        "cpu_percent": 100.0 * (c1 - c0) / (t1 - t0),
    }


def _no_send(payload: bytes) -> None:
    raise AssertionError("this side does not send")


async def _wait_stop(control: Control) -> None:
    while not control.poll():
        await asyncio.sleep(0.01)


async def _peer(
    control: Control,
    impl: str,
    role: str,
    send_too: bool,
    port: int,
    seconds: float,
    warmup: float,
) -> Json:
    loop = asyncio.get_running_loop()
    rx = RxCounter()
    cap = warmup + seconds + 30.0
    report: Json = {"role": role}
    server = None
    ep = None
    transport = None
    send: Callable[[bytes], None] = _no_send
    if impl == "raw":
        if role == "server":
            transport, proto = await loop.create_datagram_endpoint(
                lambda: RawProtocol(rx), local_addr=("127.0.0.1", 0)
            )
            control.conn.send({"port": transport.get_extra_info("sockname")[1]})
            if send_too:
                peer = await proto.peer
                sendto = transport.sendto

                def send_to_peer(payload: bytes) -> None:
                    sendto(payload, peer)

                send = send_to_peer

        else:
            transport, proto = await loop.create_datagram_endpoint(
                lambda: RawProtocol(rx), remote_addr=("127.0.0.1", port)
            )
            send = transport.sendto
    elif role == "server":
        key = BENCH_KEY if impl == "keyed" else None
        server = await listen("127.0.0.1", 0, config=UNLIMITED, on_data=rx.on_data, key=key)
        control.conn.send({"port": server.port})
        if send_too:
            ep = await server.accept()
            send = ep.send
    else:
        key = BENCH_KEY if impl == "keyed" else None
        ep = await connect("127.0.0.1", port, config=UNLIMITED, on_data=rx.on_data, key=key)
        send = ep.send

    receives = role == "server" or send_too
    sends = role == "client" or send_too
    sending = Blast() if sends else None
    window_task = (
        asyncio.create_task(receive_window(rx, warmup, seconds, sending)) if receives else None
    )
    blast_task = (
        asyncio.create_task(blast(send, control, cap, sending)) if sending is not None else None
    )
    if window_task is not None:
        report["window"] = await window_task
        control.conn.send({"window": report["window"]})
    else:
        control.conn.send({"window": None})
    if blast_task is not None:
        b = await blast_task
        report["blast"] = {
            "sent": b.sent,
            "rate": b.sent / b.elapsed if b.elapsed else 0.0,
            "cpu_percent": 100.0 * b.cpu / b.elapsed if b.elapsed else 0.0,
            "stopped_by": b.stopped_by,
        }
    else:
        await _wait_stop(control)
    endpoint = (
        ep if ep is not None else (server.endpoints[0] if server and server.endpoints else None)
    )
    if endpoint is not None:
        stats = endpoint.stats
        report["tdtp"] = {
            "data_sent": stats.sent.data_packets,
            "acks_sent": stats.sent.ack_packets,
            "data_received": stats.received.data_packets,
            "acks_received": stats.received.ack_packets,
            "packets_lost": stats.packets_lost,
            "drops": dict(stats.drops),
            "send_errors": endpoint.send_errors,
        }
    if ep is not None:
        await ep.close()
    if server is not None:
        await server.close()
    if transport is not None:
        transport.close()
    return report


def peer_worker(
    conn: Any,
    *,
    impl: str,
    loop: str,
    role: str,
    send_too: bool,
    port: int,
    seconds: float,
    warmup: float,
    cpu_slot: int,
    profile: bool,
) -> None:
    """One process of a pair (run by :func:`_common.start_worker`)."""
    cpu = common.pin_to_cpu(cpu_slot)
    control = Control(conn)
    if impl == "stock":  # tdtp on the loop's own transport (read by tdtp.listen / tdtp.connect)
        os.environ["TDTP_DATAGRAM_LAYER"] = "0"
        impl = "tdtp"
    profiler = None
    if profile:
        import cProfile  # noqa: PLC0415

        profiler = cProfile.Profile()
        profiler.enable()
    report = common.run_in_loop(
        loop, lambda: _peer(control, impl, role, send_too, port, seconds, warmup)
    )
    if profiler is not None:
        profiler.disable()
        report["profile"] = common.profile_text(profiler, 30)
    report["cpu"] = cpu
    report["build"] = common.tdtp_build()
    conn.send({"final": report})


# ---------------------------------------------------------------------------- coordinator


def drive_pair(
    name: str,
    worker: common.Worker,
    seconds: float,
    warmup: float,
    *,
    pure: bool = False,
    **args: Any,
) -> tuple[tuple[Json, Json | None], Json, Json]:
    """The coordinator's side of a measured pair: start ``worker`` as the receiving ``server`` (CPU
    slot 1), then as the sending ``client`` (slot 0) at the port the server says it bound; wait for
    each one's ``{"window": ...}`` (the server's always, the client's ``None`` unless it receives
    too), stop both and collect their ``{"final": ...}`` reports. Returns the windows (server's,
    client's) and the server's and client's final reports. ``args`` go to both workers, with ``seconds``/``warmup``."""
    args |= {"seconds": seconds, "warmup": warmup}
    server = common.start_worker(
        f"{name}-rx", worker, pure=pure, role="server", port=0, cpu_slot=1, **args
    )
    client = None
    try:
        port = server.recv(timeout=30)["port"]
        client = common.start_worker(
            f"{name}-tx", worker, pure=pure, role="client", port=port, cpu_slot=0, **args
        )
        budget = 30 + warmup + seconds
        windows = (server.recv(budget)["window"], client.recv(budget)["window"])
        server.send({"stop": True})
        client.send({"stop": True})
        rx_final = server.recv(30)["final"]
        tx_final = client.recv(30)["final"]
    finally:
        server.finish()
        if client is not None:
            client.finish()
    return windows, rx_final, tx_final


def run_pair(variant: str, seconds: float, warmup: float, profile: bool = False) -> Json:
    impl, loop, both = VARIANTS[variant]
    pure = impl == "pure"
    others = common.OthersMeter()
    windows, rx_final, tx_final = drive_pair(
        variant,
        peer_worker,
        seconds,
        warmup,
        pure=pure,
        impl=impl,
        loop=loop,
        send_too=both,
        profile=profile,
    )
    builds = {rx_final["build"], tx_final["build"]}
    expected = "pure" if pure else None
    if expected is not None and builds != {expected}:
        raise RuntimeError(f"{variant}: the workers ran the {builds} build, not {expected}")
    received = sum(w["rate"] for w in windows if w is not None)
    sent = sum(f["blast"]["rate"] for f in (rx_final, tx_final) if "blast" in f)
    rx_cpu = windows[0]["cpu_percent"]
    tx_cpu = tx_final["blast"]["cpu_percent"]
    if both:
        # Each process sends and receives: its CPU per packet handled in the window.
        per_packet = [
            _per_packet(w["cpu_percent"], w["rate"] + w["sent_rate"])
            for w in windows
            if w is not None
        ]
    else:
        per_packet = [
            _per_packet(rx_cpu, windows[0]["rate"]),
            _per_packet(tx_cpu, tx_final["blast"]["rate"]),
        ]
    return {
        "variant": variant,
        "build": sorted(builds)[0] if len(builds) == 1 else "mixed",
        "rate": received,
        "sender_rate": sent,
        "delivered_fraction": received / sent if sent else math.nan,
        "rx_cpu_percent": rx_cpu,
        "tx_cpu_percent": tx_cpu,
        "cpu_us_per_packet": per_packet,
        "bottleneck_us": max(per_packet),
        "others_percent": others.percent(),
        "server": rx_final,
        "client": tx_final,
    }


def _per_packet(cpu_percent: float, rate: float) -> float:
    """CPU microseconds per packet; NaN for a window in which nothing moved (a stalled machine: the
    run then reports NaN for that figure instead of failing)."""
    return 1e4 * cpu_percent / rate if rate > 0 else math.nan


def main(argv: list[str] | None = None) -> int:
    p = common.parser(__doc__, seconds=1.0, repeat=3, help_seconds="measurement window per run")
    p.add_argument("--both", action="store_true", help="also saturate both directions at once")
    p.add_argument(
        "--profile", action="store_true", help="one extra tdtp run under cProfile, top functions"
    )
    p.add_argument(
        "--variants",
        nargs="+",
        choices=sorted(VARIANTS),
        help="run only these variants (default: the one-way ones, plus the both-ways ones with --both)",
    )
    args = p.parse_args(argv)
    common.warn_if_loaded()
    variants = args.variants or [k for k, v in VARIANTS.items() if args.both or not v[2]]
    if not common.have_uvloop():
        print("uvloop is not installed: skipping its variants", file=sys.stderr)
        variants = [v for v in variants if VARIANTS[v][1] != "uvloop"]
    warmup = min(WARMUP, args.seconds)
    retrier = common.Retrier(args.repeat)
    runs = retrier.interleaved(
        args.repeat, variants, LABELS.__getitem__, lambda v: run_pair(v, args.seconds, warmup)
    )
    profiles: Json = {}
    if args.profile and "tdtp-uvloop" in VARIANTS and common.have_uvloop():
        print("profiling tdtp uvloop ...", file=sys.stderr, flush=True)
        prof = run_pair("tdtp-uvloop", max(args.seconds, 1.0), warmup, profile=True)
        profiles = {
            "receiver": prof["server"].get("profile", ""),
            "sender": prof["client"].get("profile", ""),
            "rate_under_profiler": prof["rate"],
        }
    rows = build_rows(runs)
    text = describe(runs)
    if profiles:
        text += (
            "\n\ncProfile of one tdtp uvloop run (own time; the profiler slows it: "
            f"{profiles['rate_under_profiler']:,.0f} samples/s under it)\n"
            f"--- receiver process ---\n{profiles['receiver']}\n"
            f"--- sender process ---\n{profiles['sender']}"
        )
    details = {
        "runs": runs,
        "profile": profiles,
        "batch": BATCH,
        "warmup": warmup,
        "contended_reruns": retrier.retried,
    }
    return common.emit("throughput", args, rows, details=details, text=text)


def _rates(runs: list[Json], key: str = "rate") -> list[float]:
    return [float(r[key]) for r in runs]


def _target(variant: str) -> tuple[str, float] | None:
    """The issue's target for a variant's ratio to raw uvloop: its text and its threshold."""
    if variant == "tdtp-uvloop":
        return f"ratio >= {TARGET_RATIO}, measured or capacity", TARGET_RATIO
    if variant == "tdtp-uvloop-both":
        return f"ratio >= {TARGET_RATIO_BOTH}, measured or capacity", TARGET_RATIO_BOTH
    if variant in PURE_BEFORE:
        before = PURE_BEFORE[variant]
        return f"no slower than before the compiled core: ratio >= {before}", before
    return None


def build_rows(runs: dict[str, list[Json]]) -> list[Row]:
    """Medians over the uncontended runs (common.clean), ratios over uncontended pairs; after each
    tdtp variant its capacity row (bottleneck CPU per packet, raw's over tdtp's)."""
    rows: list[Row] = []
    base_key = "raw-uvloop" if "raw-uvloop" in runs else None
    for variant, results in runs.items():
        if not results:
            continue
        value = Stat.of(_rates(common.clean(results)))
        row = Row("throughput", f"{LABELS[variant]}, 100 B, received", "pkt/s", value)
        rows.append(row)
        notes = ["baseline"] if variant.startswith("raw") else []
        if skipped := common.left_out(results):
            notes.append(skipped)
        row.note = ", ".join(notes)
        baseline = "raw-uvloop-both" if VARIANTS[variant][2] else base_key
        if baseline is None or baseline == variant or not runs.get(baseline):
            continue
        mine, theirs = common.clean_pairs(results, runs[baseline])
        row.baseline = LABELS[baseline]
        row.baseline_value = Stat.of(_rates(common.clean(runs[baseline])))
        row.ratio = Stat.of(common.paired_ratios(_rates(mine), _rates(theirs)))
        if variant.startswith("raw"):
            continue
        row.ratio_label = "tdtp/raw"
        capacity = Row(
            "throughput",
            f"{LABELS[variant]}: capacity, bottleneck CPU per packet",
            "us",
            Stat.of(_rates(common.clean(results), "bottleneck_us")),
            baseline=LABELS[baseline],
            baseline_value=Stat.of(_rates(common.clean(runs[baseline]), "bottleneck_us")),
            ratio=Stat.of(
                common.paired_ratios(_rates(theirs, "bottleneck_us"), _rates(mine, "bottleneck_us"))
            ),
            ratio_label="raw/tdtp (capacity ratio)",
            note=common.left_out(results, runs[baseline]),
            digits=2,
        )
        rows.append(capacity)
        target = _target(variant)
        if target is not None:
            text, threshold = target
            assert capacity.ratio is not None
            if variant in PURE_BEFORE:  # the recorded figure is a measured ratio
                row.target, row.meets = text, row.ratio.median >= threshold
            else:
                met = row.ratio.median >= threshold or capacity.ratio.median >= threshold
                for r in (row, capacity):
                    r.target, r.meets = text, met
    return rows


def describe(runs: dict[str, list[Json]]) -> str:
    lines = [
        "Medians over the uncontended repetitions. CPU from getrusage, % of one core; CPU us/pkt = CPU "
        "time per packet (one way, receiver: per sample received, sender: per sample offered; both "
        "ways, each process: per packet sent or received in the window); the bottleneck is the "
        "larger of the two, and raw's over tdtp's is the capacity ratio. Other tenants: CPU time of "
        "every other process on the machine during the run (/proc/[pid]/stat), % of one core.",
        "",
        "| variant | received (pkt/s) | sender offered (pkt/s) | delivered | receiver CPU % "
        "| sender CPU % | receiver (both: first) CPU us/pkt | sender (both: second) CPU us/pkt "
        "| bottleneck CPU us/pkt | other tenants CPU %, max over runs |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for variant, results in runs.items():
        if not results:
            continue

        good = common.clean(results)

        def med(key: str, good: list[Json] = good) -> float:
            return Stat.of(_rates(good, key)).median

        first = Stat.of([r["cpu_us_per_packet"][0] for r in good]).median
        second = Stat.of([r["cpu_us_per_packet"][1] for r in good]).median
        lines.append(
            f"| {LABELS[variant]} | {med('rate'):,.0f} | {med('sender_rate'):,.0f} "
            f"| {med('delivered_fraction'):.1%} | {med('rx_cpu_percent'):.0f} "
            f"| {med('tx_cpu_percent'):.0f} | {first:.2f} | {second:.2f} "
            f"| {med('bottleneck_us'):.2f} "
            f"| {max(_rates(results, 'others_percent')):.0f} "
            f"({sum(bool(r.get('contended')) for r in results)} of {len(results)} contended) |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
