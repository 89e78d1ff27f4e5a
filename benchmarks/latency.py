"""Ping-pong round-trip time through tdtp against raw uvloop UDP sockets, 100-byte payloads.

Usage: ``python benchmarks/latency.py [--seconds 3] [--repeat 3] [--json] [--variants NAME ...]``

Method. Two processes on loopback, each pinned to its own CPU: an **echo** side that sends back every
payload it receives, and a **client** that sends one 100-byte payload, waits for it to come back, records
the round trip (``time.perf_counter_ns`` from just before the send call to the receive callback) and
sends the next one at once. One payload is in flight at a time, so the figure is the pure path latency:
two socket hops, two process wake-ups and each side's per-packet processing. The first 200 round trips
are a warm-up and are not recorded; then the client runs for ``--seconds``.

- ``raw uvloop``: ``DatagramProtocol`` on uvloop both sides: ``transport.sendto`` from
  ``datagram_received``.
- ``tdtp uvloop``: ``tdtp.connect`` / ``tdtp.listen`` on uvloop, flow control out of the way
  (``controller="fixed"``, ``FixedConfig(rate=math.inf)``: the pacer is not what is measured here), both
  sides send from their ``on_data`` callback with ``ep.send``. Every sample carries the piggybacked ACK of
  the one before it, so no stand-alone ACK packets are sent.
- ``keyed``: ``tdtp uvloop`` with a pre-shared key (AES-128-GCM, payloads encrypted), measured the
  same way.
- ``pure``: ``tdtp uvloop`` on the pure-Python build (``TDTP_PURE_PYTHON=1`` in both processes).
- ``stock``: ``tdtp uvloop`` on the loop's own datagram transport (``TDTP_DATAGRAM_LAYER=0``) instead
  of the batched datagram layer ``tdtp uvloop`` runs on by default where its C engine is built.

Beside the round trips, each side's **CPU per round trip** (``getrusage``): the client's over the
ping-pong, the echo's from its first echo to its last. CPU time per round trip does not grow when a
neighbour takes the core for a while (the wall-clock RTT does), so tdtp's CPU over raw's says how much
of the RTT ratio is tdtp's own work, whatever the other tenants did.

A payload not answered within 50 ms is counted as lost and the next one goes out (none are expected on
loopback). A run during which other processes on the machine used more than 20 % of a core is run
again (at most ``--repeat`` reruns in all); if it is still contended, the statistics leave it out as
long as at least two runs are clean. Reported per variant: RTT p50 / p99 / p99.9 (us), medians over
the repetitions; the ratios are tdtp over raw, repetition by repetition.

Targets (issue 12): tdtp p50 <= 1.2 x raw p50; the pure-Python build no slower than the whole library
was before the compiled core (p50 1.897 x raw in the suite's run of 2026-11-21).
"""

from __future__ import annotations

import asyncio
import math
import os
import struct
import sys
import time
from pathlib import Path
from typing import Any, cast

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat

from tdtp import ConnectionConfig, DataReceived, PresharedKey
from tdtp.aio.api import connect, listen
from tdtp.control.fixed import FixedConfig

TARGET_P50_RATIO = 1.2
PURE_BEFORE_P50_RATIO = 1.897
"""tdtp / raw uvloop RTT p50 in the suite's run of 2026-11-21, before the compiled core."""
PAYLOAD_SIZE = 100
WARMUP_PINGS = 200
LOSS_TIMEOUT = 0.05
UNLIMITED = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))
VARIANTS = {
    "raw-uvloop": "raw uvloop",
    "tdtp-uvloop": "tdtp uvloop",
    "keyed-uvloop": "tdtp uvloop, keyed (AES-128-GCM)",
    "pure-uvloop": "tdtp uvloop, pure-Python build",
    "stock-uvloop": "tdtp uvloop, loop's transport (TDTP_DATAGRAM_LAYER=0)",
}
_COUNTER = struct.Struct("!Q")
BENCH_KEY = PresharedKey(bytes(range(32)), "bench")
"""The pre-shared key of the ``keyed`` implementation (benchmarks/keyed.py runs it)."""


# ---------------------------------------------------------------------------- echo side


class EchoCount:
    """Echoes sent, and this process's CPU time at the first and the latest one."""

    def __init__(self) -> None:
        self.count = 0
        self.first_cpu = math.nan
        self.last_cpu = math.nan

    def note(self) -> None:
        self.count += 1
        if self.count == 1:
            self.first_cpu = common.cpu_seconds()

    def cpu_per_echo_us(self) -> float:
        return (
            1e6 * (self.last_cpu - self.first_cpu) / (self.count - 1)
            if self.count > 1
            else math.nan
        )


class RawEcho(asyncio.DatagramProtocol):
    def __init__(self, counter: EchoCount) -> None:
        self.counter = counter

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.DatagramTransport, transport)  # uvloop's is not a subclass

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.transport.sendto(data, addr)
        self.counter.note()


async def _wait_for_stop(control: Any, counter: EchoCount) -> None:
    """Until the coordinator says stop; the CPU clock is read once the echoes have stopped (the
    client is done before the stop comes), so idle polling adds only its few wake-ups."""
    seen = -1
    while not control.poll():
        await asyncio.sleep(0.02)
        if counter.count != seen:
            seen = counter.count
            counter.last_cpu = common.cpu_seconds()


async def _echo(control: Any, impl: str) -> Json:
    loop = asyncio.get_running_loop()
    report: Json = {}
    counter = EchoCount()
    if impl == "raw":
        transport, _ = await loop.create_datagram_endpoint(
            lambda: RawEcho(counter), local_addr=("127.0.0.1", 0)
        )
        control.send({"port": transport.get_extra_info("sockname")[1]})
        await _wait_for_stop(control, counter)
        transport.close()
        report["echo_cpu_us"] = counter.cpu_per_echo_us()
        return report
    server = await listen(
        "127.0.0.1", 0, config=UNLIMITED, key=BENCH_KEY if impl == "keyed" else None
    )
    control.send({"port": server.port})
    ep = await server.accept()

    def echo(sample: DataReceived) -> None:
        ep.send(sample.payload)
        counter.note()

    ep.set_data_callback(echo)
    await _wait_for_stop(control, counter)
    report["echo_cpu_us"] = counter.cpu_per_echo_us()
    stats = ep.stats
    report["echo_tdtp"] = {
        "data_sent": stats.sent.data_packets,
        "acks_sent": stats.sent.ack_packets,
        "drops": dict(stats.drops),
    }
    await server.close()
    return report


def _use_transport(impl: str) -> str:
    """``stock``: tdtp on the loop's own transport (read by tdtp.listen / tdtp.connect)."""
    if impl == "stock":
        os.environ["TDTP_DATAGRAM_LAYER"] = "0"
        return "tdtp"
    return impl


def echo_worker(conn: Any, *, impl: str, cpu_slot: int) -> None:
    common.pin_to_cpu(cpu_slot)
    impl = _use_transport(impl)
    report = common.run_in_loop("uvloop", lambda: _echo(conn, impl))
    report["build"] = common.tdtp_build()
    conn.send({"final": report})


# ---------------------------------------------------------------------------- client side


class Pinger:
    """Sends payload i, waits for it, records the round trip, sends i + 1."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.send: Any = None
        self.index = 0
        self.sent_at = 0
        self.rtts: list[int] = []
        self.lost = 0
        self.stray = 0
        self.record_from = 0
        self.stop_at = math.inf
        self.done: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self.padding = bytes(PAYLOAD_SIZE - _COUNTER.size)

    def fire(self) -> None:
        self.index += 1
        payload = _COUNTER.pack(self.index) + self.padding
        self.sent_at = time.perf_counter_ns()
        self.send(payload)

    def received(self, payload: bytes) -> None:
        now = time.perf_counter_ns()
        if _COUNTER.unpack_from(payload)[0] != self.index:
            self.stray += 1  # an answer to a payload already given up on
            return
        if self.index > WARMUP_PINGS:
            self.rtts.append(now - self.sent_at)
        elif self.index == WARMUP_PINGS:
            self.stop_at = time.monotonic() + self.seconds
        if time.monotonic() >= self.stop_at:
            if not self.done.done():
                self.done.set_result(None)
            return
        self.fire()

    async def watchdog(self) -> None:
        last = -1
        while not self.done.done():
            await asyncio.sleep(LOSS_TIMEOUT)
            if self.index == last and not self.done.done():
                self.lost += 1
                self.fire()
            last = self.index


class RawClient(asyncio.DatagramProtocol):
    def __init__(self, pinger: Pinger) -> None:
        self.pinger = pinger

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.pinger.received(data)


async def _client(impl: str, port: int, seconds: float) -> Json:
    loop = asyncio.get_running_loop()
    pinger = Pinger(seconds)
    ep = None
    if impl == "raw":
        transport, _ = await loop.create_datagram_endpoint(
            lambda: RawClient(pinger), remote_addr=("127.0.0.1", port)
        )
        pinger.send = transport.sendto
    else:
        ep = await connect(
            "127.0.0.1",
            port,
            config=UNLIMITED,
            on_data=lambda s: pinger.received(s.payload),
            key=BENCH_KEY if impl == "keyed" else None,
        )
        pinger.send = ep.send
    cpu0, t0 = common.cpu_seconds(), time.monotonic()
    watchdog = asyncio.create_task(pinger.watchdog())
    pinger.fire()
    await pinger.done
    watchdog.cancel()
    cpu_spent, wall = common.cpu_seconds() - cpu0, time.monotonic() - t0
    report: Json = {
        "lost": pinger.lost,
        "stray": pinger.stray,
        "client_cpu_percent": 100 * cpu_spent / wall,
        "client_cpu_us": 1e6 * cpu_spent / pinger.index,  # every ping, warm-up included
    }
    if ep is not None:
        stats = ep.stats
        report["client_tdtp"] = {
            "data_sent": stats.sent.data_packets,
            "acks_sent": stats.sent.ack_packets,
            "srtt_us": stats.srtt * 1e6,
        }
        await ep.close()
    else:
        transport.close()
    rtts = sorted(pinger.rtts)
    report["count"] = len(rtts)
    for name, q in (("p50", 0.5), ("p99", 0.99), ("p999", 0.999)):
        report[name] = common.percentile(rtts, q) / 1e3  # us
    report["max"] = rtts[-1] / 1e3 if rtts else math.nan
    return report


def client_worker(conn: Any, *, impl: str, port: int, seconds: float, cpu_slot: int) -> None:
    common.pin_to_cpu(cpu_slot)
    impl = _use_transport(impl)
    report = common.run_in_loop("uvloop", lambda: _client(impl, port, seconds))
    report["build"] = common.tdtp_build()
    conn.send({"final": report})


# ---------------------------------------------------------------------------- coordinator


def run_variant(variant: str, seconds: float) -> Json:
    impl = variant.split("-", maxsplit=1)[0]
    pure = impl == "pure"
    others = common.OthersMeter()
    echo = common.start_worker(f"{variant}-echo", echo_worker, pure=pure, impl=impl, cpu_slot=1)
    client = None
    try:
        port = echo.recv(30)["port"]
        client = common.start_worker(
            f"{variant}-client",
            client_worker,
            pure=pure,
            impl=impl,
            port=port,
            seconds=seconds,
            cpu_slot=0,
        )
        result: Json = client.recv(20 + 3 * seconds)["final"]
        echo.send({"stop": True})
        result["echo"] = echo.recv(30)["final"]
    finally:
        echo.finish()
        if client is not None:
            client.finish()
    if pure and {result["build"], result["echo"]["build"]} != {"pure"}:
        raise RuntimeError(f"{variant}: the workers did not run the pure-Python build")
    result["variant"] = variant
    result["cpu_us"] = result["client_cpu_us"] + result["echo"]["echo_cpu_us"]
    result["others_percent"] = others.percent()
    return result


def rtt_rows(
    runs: dict[str, list[Json]], variant: str, baseline: str, label: str, keys: tuple[str, ...]
) -> list[Row]:
    """RTT rows (p50, p99, p99.9 as ``keys`` picks) of ``variant`` against ``baseline``, paired,
    and its CPU per round trip beside them."""
    mine, theirs = runs[variant], runs[baseline]
    paired_mine, paired_theirs = common.clean_pairs(mine, theirs)
    names = {"p50": "p50", "p99": "p99", "p999": "p99.9"}
    note = common.left_out(mine, theirs)
    rows = []
    for key in keys:
        rows.append(
            Row(
                "latency",
                f"RTT {names[key]}, {VARIANTS[variant]}, 100 B ping-pong",
                "us",
                Stat.of([r[key] for r in common.clean(mine)]),
                baseline=VARIANTS[baseline],
                baseline_value=Stat.of([r[key] for r in common.clean(theirs)]),
                ratio=Stat.of(
                    common.paired_ratios(
                        [r[key] for r in paired_mine], [r[key] for r in paired_theirs]
                    )
                ),
                ratio_label=label,
                note=note,
                digits=1,
            )
        )
    rows.append(
        Row(
            "latency",
            f"CPU per round trip (client + echo), {VARIANTS[variant]}",
            "us",
            Stat.of([r["cpu_us"] for r in common.clean(mine)]),
            baseline=VARIANTS[baseline],
            baseline_value=Stat.of([r["cpu_us"] for r in common.clean(theirs)]),
            ratio=Stat.of(
                common.paired_ratios(
                    [r["cpu_us"] for r in paired_mine], [r["cpu_us"] for r in paired_theirs]
                )
            ),
            ratio_label=label + " CPU",
            note=note,
            digits=1,
        )
    )
    return rows


def main(argv: list[str] | None = None) -> int:
    p = common.parser(__doc__, seconds=3.0, repeat=3, help_seconds="ping-pong time per run")
    p.add_argument(
        "--variants",
        nargs="+",
        choices=sorted(VARIANTS),
        help="run only these (default: all; raw-uvloop is always run, as the baseline)",
    )
    args = p.parse_args(argv)
    common.warn_if_loaded()
    if not common.have_uvloop():
        missing = "uvloop is not installed: nothing to compare (every variant runs on it); skipped"
        print(missing, file=sys.stderr)
        return common.emit("latency", args, [], details={"skipped": missing}, text=missing)
    chosen = set(args.variants or VARIANTS) | {"raw-uvloop"}
    runs = common.Retrier(args.repeat).interleaved(
        args.repeat,
        [v for v in VARIANTS if v in chosen],
        VARIANTS.__getitem__,
        lambda v: run_variant(v, args.seconds),
    )
    rows: list[Row] = []
    if "tdtp-uvloop" in runs:
        tdtp_rows = rtt_rows(runs, "tdtp-uvloop", "raw-uvloop", "tdtp/raw", ("p50", "p99", "p999"))
        assert tdtp_rows[0].ratio is not None
        tdtp_rows[0].target = f"ratio <= {TARGET_P50_RATIO}"
        tdtp_rows[0].meets = tdtp_rows[0].ratio.median <= TARGET_P50_RATIO
        rows.extend(tdtp_rows)
    if "keyed-uvloop" in runs:
        rows.extend(rtt_rows(runs, "keyed-uvloop", "raw-uvloop", "keyed/raw", ("p50", "p99")))
        if "tdtp-uvloop" in runs:
            rows.extend(
                rtt_rows(runs, "keyed-uvloop", "tdtp-uvloop", "keyed/unkeyed", ("p50",))[:1]
            )
    if "stock-uvloop" in runs and "tdtp-uvloop" in runs:
        rows.extend(
            rtt_rows(runs, "tdtp-uvloop", "stock-uvloop", "layer/loop's transport", ("p50",))
        )
    if "pure-uvloop" in runs:
        pure_rows = rtt_rows(runs, "pure-uvloop", "raw-uvloop", "pure/raw", ("p50",))
        assert pure_rows[0].ratio is not None
        pure_rows[0].target = f"no slower than before the compiled core: <= {PURE_BEFORE_P50_RATIO}"
        pure_rows[0].meets = pure_rows[0].ratio.median <= PURE_BEFORE_P50_RATIO
        rows.extend(pure_rows)
    lines = [
        "Other tenants: CPU time of every other process on the machine during the run "
        "(/proc/[pid]/stat), % of one core. CPU per round trip from getrusage: the client's per "
        "ping (warm-up included), the echo's per echo.",
        "",
        "| variant | round trips | RTT p50 / p99 / p99.9 / max (us) | lost | client CPU % "
        "| CPU us per round trip, client + echo | other tenants CPU % |",
        "| --- | ---: | --- | ---: | ---: | --- | ---: |",
    ]
    for variant, results in runs.items():
        for r in results:
            lines.append(
                f"| {VARIANTS[variant]} | {r['count']:,} | {r['p50']:.1f} / {r['p99']:.1f} / "
                f"{r['p999']:.1f} / {r['max']:.1f} | {r['lost']} | {r['client_cpu_percent']:.0f} "
                f"| {r['client_cpu_us']:.1f} + {r['echo']['echo_cpu_us']:.1f} "
                f"| {r['others_percent']:.0f}{' (contended)' if r.get('contended') else ''} |"
            )
    return common.emit("latency", args, rows, details={"runs": runs}, text="\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
