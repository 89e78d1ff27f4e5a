"""How many concurrent 1 kHz bidirectional sessions does one tdtp slave process serve on uvloop?

Usage: ``python benchmarks/scale.py [--seconds 2] [--repeat 2] [--ramp 2,5,10,15,20,30,50,100,150]
[--controller trinomial|tfrc|fixed] [--json]``

Method. Two processes on loopback, each pinned to its own CPU (on 2 cores the slave has one to itself):

- the **slave**: ``tdtp.listen`` on uvloop, default connection config (trinomial flow control,
  piggybacked ACKs). Each accepted master gets its own task, written as an application would (see
  ``examples/slave.py``): an ``on_data`` callback takes the master's samples, and a ``tdtp.Ticker(1000)``
  loop sends one 100-byte sample per tick with ``ep.send``.
- the **masters**: N ``tdtp.connect`` endpoints in one process on uvloop; one shared 1 kHz ticker sends a
  100-byte sample to every endpoint per tick (one wake-up per period for all N, to keep the load
  generator cheap), and an ``on_data`` callback per endpoint takes the slave's samples.

Every payload carries its send time (``time.monotonic``, one system-wide clock for both processes). Once
all N sessions are up and a 0.5 s warm-up has passed, each side measures a window of ``--seconds``.

**Late**, the figure judged: a slave sample is late when the slave's ``Ticker`` hands it to ``ep.send``
more than one period (1 ms) after its deadline, or when the ticker skipped its tick altogether (a stall
longer than 10 periods). This is what the slave process controls: whether it keeps every session's 1 kHz
schedule while also taking in N x 1000 samples/s. It does not depend on the masters' process or on the
path, so a busy load generator cannot make the slave look late. A step **passes** when at most 1 % of the
slave's samples in the window are late and the load was really offered: the slave received at least 99 %
of the N x 1000 samples/s the masters were meant to send. A step whose slave kept up but received
less than that is *master-limited*: the masters' process could not offer the load, and the ramp stops
there. A step that fails while other processes on the machine used more than 20 % of a core is
*contended* (inconclusive) and run again, at most twice. The masters' own ticker lateness is reported
beside it.

Reported per step: slave late %, p99 tick lateness, slave CPU % of its core (``getrusage``), samples/s
received by the slave, for information the one-way lateness of samples at arrival (arrival - send
time > 1 ms) in each direction, and how much CPU other tenants of the machine used meanwhile (the CPU
time of every other process, from ``/proc/[pid]/stat``, over the step, % of one core): on a shared
machine a step can fail because a neighbour took the slave's core, and this column says so. The ramp
stops after the first step that does not pass. The figure is the largest N that passed, median over
``--repeat`` ramps.

Target (issue 6): >= 100 sessions.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import resource
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat

from tdtp import ConnectionClosedError, ConnectionConfig, DataReceived, Endpoint, Ticker
from tdtp.aio.api import connect, listen
from tdtp.aio.timer import monotonic
from tdtp.control.fixed import FixedConfig

TARGET_SESSIONS = 100
DEFAULT_RAMP = "2,5,8,10,12,15,20,30,50,100,150"
CONTENDED_RETRIES = 2
"""Reruns of a step that failed while other processes used > common.CONTENDED_PERCENT of a core."""
RATE = 1000.0
PERIOD = 1.0 / RATE
LATE = PERIOD  # more than one period behind
MAX_LATE_FRACTION = 0.01
MIN_OFFERED_FRACTION = 0.99
WARMUP = 0.5
PAYLOAD_SIZE = 100
_STAMP = struct.Struct("!dQ")
_PADDING = bytes(PAYLOAD_SIZE - _STAMP.size)


def session_config(controller: str) -> ConnectionConfig:
    """The slave's and masters' config: the default, or another controller (``fixed`` = unpaced)."""
    if controller == "fixed":
        return ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))
    return ConnectionConfig(controller=controller)


def _raise_fd_limit() -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < hard:
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))


@dataclass
class Window:
    """The measurement window, once every session is up."""

    start: float = math.inf
    end: float = math.inf
    cpu: list[float] = field(default_factory=list)

    def covers(self, t: float) -> bool:
        return self.start <= t < self.end


@dataclass
class Arrivals:
    """Samples received in the window, and how many arrived more than one period after they left."""

    window: Window
    count: int = 0
    late: int = 0

    def on_data(self, sample: DataReceived) -> None:
        now = sample.received_at
        if self.window.covers(now):
            self.count += 1
            if now - _STAMP.unpack_from(sample.payload)[0] > LATE:
                self.late += 1


@dataclass
class Ticks:
    """A ticker's deadlines in the window: how many, how many late or skipped, their lateness."""

    total: int = 0
    late: int = 0
    skipped: int = 0
    lateness: list[float] = field(default_factory=list)
    late_at: list[float] = field(default_factory=list)
    """When late ticks were due, seconds into the window (the first 100)."""


async def _measure(window: Window, seconds: float) -> None:
    window.start = monotonic() + WARMUP
    window.end = window.start + seconds
    await asyncio.sleep(window.start - monotonic())
    window.cpu.append(common.cpu_seconds())
    await asyncio.sleep(window.end - monotonic())
    window.cpu.append(common.cpu_seconds())
    await asyncio.sleep(0.05)  # let the last ticks of the window be recorded


def _payload(index: int) -> bytes:
    return _STAMP.pack(monotonic(), index) + _PADDING


def _record_tick(ticks: Ticks, window: Window, deadline: float, now: float, gap: int) -> None:
    if not window.covers(deadline):
        return
    ticks.total += 1 + gap
    ticks.skipped += gap
    ticks.late += gap
    lateness = now - deadline
    ticks.lateness.append(lateness)
    if lateness > LATE or gap:
        ticks.late += lateness > LATE
        if len(ticks.late_at) < 100:
            ticks.late_at.append(round(deadline - window.start, 4))


# ---------------------------------------------------------------------------- slave


async def _serve(ep: Endpoint, window: Window, ticks: Ticks, arrivals: Arrivals) -> None:
    ep.set_data_callback(arrivals.on_data)
    start = monotonic()
    last = -1
    with contextlib.suppress(ConnectionClosedError):
        async for index in Ticker(RATE, start=start):
            now = monotonic()
            _record_tick(ticks, window, start + index * PERIOD, now, index - last - 1)
            last = index
            if ep.is_closed or now > window.end + 0.2:
                return
            ep.send(_payload(index))


async def _slave(control: Any, sessions: int, seconds: float, controller: str) -> Json:
    window = Window()
    ticks = Ticks()
    arrivals = Arrivals(window)
    config = session_config(controller)
    server = await listen("127.0.0.1", 0, max_peers=sessions + 8, config=config)
    control.send({"port": server.port})
    tasks = []
    for _ in range(sessions):
        ep = await server.accept()
        tasks.append(asyncio.create_task(_serve(ep, window, ticks, arrivals)))
    await _measure(window, seconds)
    span = window.end - window.start
    stats = [ep.stats for ep in server.endpoints]
    report = {
        "ticks": ticks.total,
        "late": ticks.late,
        "skipped": ticks.skipped,
        "late_fraction": ticks.late / ticks.total if ticks.total else math.nan,
        "tick_lateness_p99_us": 1e6 * common.percentile(sorted(ticks.lateness), 0.99),
        "late_at": ticks.late_at,
        "cpu_percent": 100.0 * (window.cpu[1] - window.cpu[0]) / span,
        "received_rate": arrivals.count / span,
        "arrival_late_fraction": arrivals.late / arrivals.count if arrivals.count else math.nan,
        "superseded": sum(s.samples_superseded for s in stats),
        "lost": sum(s.packets_lost for s in stats),
        "ack_packets_sent": sum(s.sent.ack_packets for s in stats),
    }
    control.send({"window": report})
    while not control.poll():
        await asyncio.sleep(0.02)
    for task in tasks:
        task.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    await server.close()
    return report


def slave_worker(
    conn: Any, *, sessions: int, seconds: float, controller: str, cpu_slot: int
) -> None:
    common.pin_to_cpu(cpu_slot)
    _raise_fd_limit()
    common.run_in_loop("uvloop", lambda: _slave(conn, sessions, seconds, controller))
    conn.send({"final": True})


# ---------------------------------------------------------------------------- masters


async def _masters(control: Any, port: int, sessions: int, seconds: float, controller: str) -> Json:
    window = Window()
    arrivals = Arrivals(window)
    ticks = Ticks()
    config = session_config(controller)
    endpoints = [
        await connect("127.0.0.1", port, config=config, on_data=arrivals.on_data)
        for _ in range(sessions)
    ]
    measure = asyncio.create_task(_measure(window, seconds))
    start = monotonic()
    last = -1
    async for index in Ticker(RATE, start=start):
        now = monotonic()
        _record_tick(ticks, window, start + index * PERIOD, now, index - last - 1)
        last = index
        payload = _payload(index)
        for ep in endpoints:
            with contextlib.suppress(ConnectionClosedError):
                ep.send(payload)
        if measure.done() and control.poll():
            break
    span = window.end - window.start
    report = {
        "ticks": ticks.total,
        "late_fraction": ticks.late / ticks.total if ticks.total else math.nan,
        "tick_lateness_p99_us": 1e6 * common.percentile(sorted(ticks.lateness), 0.99),
        "late_at": ticks.late_at,
        "cpu_percent": 100.0 * (window.cpu[1] - window.cpu[0]) / span,
        "received_rate": arrivals.count / span,
        "arrival_late_fraction": arrivals.late / arrivals.count if arrivals.count else math.nan,
    }
    for ep in endpoints:
        await ep.close()
    return report


def masters_worker(
    conn: Any, *, port: int, sessions: int, seconds: float, controller: str, cpu_slot: int
) -> None:
    common.pin_to_cpu(cpu_slot)
    _raise_fd_limit()
    report = common.run_in_loop(
        "uvloop", lambda: _masters(conn, port, sessions, seconds, controller)
    )
    conn.send({"final": report})


# ---------------------------------------------------------------------------- coordinator


def run_step(sessions: int, seconds: float, controller: str = "trinomial") -> Json:
    others = common.OthersMeter()
    slave = common.start_worker(
        f"slave-{sessions}",
        slave_worker,
        sessions=sessions,
        seconds=seconds,
        controller=controller,
        cpu_slot=1,
    )
    masters = None
    try:
        port = slave.recv(30)["port"]
        masters = common.start_worker(
            f"masters-{sessions}",
            masters_worker,
            port=port,
            sessions=sessions,
            seconds=seconds,
            controller=controller,
            cpu_slot=0,
        )
        s = slave.recv(60 + 2 * seconds)["window"]
        masters.send({"stop": True})
        m = masters.recv(60)["final"]
        slave.send({"stop": True})
        slave.recv(30)
    finally:
        slave.finish()
        if masters is not None:
            masters.finish()
    s["others_percent"] = others.percent()  # the whole step, start-up included
    offered = sessions * RATE
    slave_ok = s["late_fraction"] <= MAX_LATE_FRACTION
    load_ok = s["received_rate"] >= MIN_OFFERED_FRACTION * offered
    if slave_ok and load_ok:
        verdict = "pass"
    elif slave_ok:
        verdict = "master-limited"  # the slave kept up, but the masters did not offer the load
    else:
        verdict = "fail"  # the slave's own ticks were late, whatever the masters did
    return {"sessions": sessions, "verdict": verdict, "slave": s, "masters": m}


def ramp(steps: list[int], seconds: float, rep: int, repeat: int, controller: str) -> list[Json]:
    results = []
    for n in steps:
        for attempt in range(1 + CONTENDED_RETRIES):
            print(f"ramp {rep + 1}/{repeat}: {n} sessions ...", file=sys.stderr, flush=True)
            step = run_step(n, seconds, controller)
            step["attempt"] = attempt + 1
            others = step["slave"]["others_percent"]
            print(
                f"  {step['verdict']}: slave late {step['slave']['late_fraction']:.2%}, "
                f"CPU {step['slave']['cpu_percent']:.0f} %, other tenants {others:.0f} %",
                file=sys.stderr,
            )
            if step["verdict"] == "pass" or not others > common.CONTENDED_PERCENT:
                break
            step["verdict"] = "contended"  # a neighbour took a core: inconclusive, try again
        results.append(step)
        if step["verdict"] != "pass":
            break
    return results


def largest_passing(results: list[Json]) -> int:
    passed = [r["sessions"] for r in results if r["verdict"] == "pass"]
    return max(passed) if passed else 0


def main(argv: list[str] | None = None) -> int:
    p = common.parser(__doc__, seconds=2.0, repeat=2, help_seconds="measurement window per step")
    p.add_argument(
        "--ramp",
        default=DEFAULT_RAMP,
        help=f"session counts to try in order (default {DEFAULT_RAMP})",
    )
    p.add_argument(
        "--controller",
        default="trinomial",
        choices=["trinomial", "tfrc", "fixed"],
        help="flow control on both sides (default trinomial, the library default; fixed = unpaced)",
    )
    args = p.parse_args(argv)
    common.warn_if_loaded()
    if not common.have_uvloop():
        print("uvloop is not installed: this benchmark measures the slave on uvloop; skipped")
        return common.emit("scale", args, [], details={"skipped": "uvloop missing"})
    steps = common.as_list(args.ramp)
    ramps = [
        ramp(steps, args.seconds, rep, args.repeat, args.controller) for rep in range(args.repeat)
    ]
    best = [largest_passing(r) for r in ramps]
    limited = any(r[-1]["verdict"] == "master-limited" for r in ramps if r)
    contended = any(r[-1]["verdict"] == "contended" for r in ramps if r)
    row = Row(
        "scale",
        "1 kHz bidirectional sessions one slave serves, <= 1 % late",
        "sessions",
        Stat.of([float(b) for b in best]),
        target=f">= {TARGET_SESSIONS}",
        meets=Stat.of([float(b) for b in best]).median >= TARGET_SESSIONS,
        note=f"{args.controller}, ramp {args.ramp}"
        + (", stopped by the masters' process" if limited else "")
        + (", stopped by other tenants: inconclusive" if contended else ""),
        digits=0,
    )
    lines = [
        "| ramp | N | verdict (attempt) | slave late % | slave tick lateness p99 (us) | slave CPU % "
        "| slave rx (samples/s) | M->S arrivals > 1 ms | S->M arrivals > 1 ms | masters late % "
        "| masters CPU % | other tenants CPU % |",
        "| ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for i, results in enumerate(ramps):
        for r in results:
            s, m = r["slave"], r["masters"]
            lines.append(
                f"| {i + 1} | {r['sessions']} | {r['verdict']} ({r.get('attempt', 1)}) "
                f"| {100 * s['late_fraction']:.2f} "
                f"| {s['tick_lateness_p99_us']:.0f} | {s['cpu_percent']:.0f} "
                f"| {s['received_rate']:,.0f} | {100 * s['arrival_late_fraction']:.2f} % "
                f"| {100 * m['arrival_late_fraction']:.2f} % | {100 * m['late_fraction']:.2f} "
                f"| {m['cpu_percent']:.0f} | {s['others_percent']:.0f} |"
            )
    details = {"ramps": ramps, "largest_passing": best, "controller": args.controller}
    return common.emit("scale", args, [row], details=details, text="\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
