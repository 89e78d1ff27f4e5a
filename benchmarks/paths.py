"""What each rate controller delivers on the paths teleoperation runs on, beside Zenoh and raw UDP.

Usage: ``python benchmarks/paths.py [--duration 10] [--quick] [--profiles NAME ...]
[--controllers NAME ...] [--seed N] [--json]``

**Load.** Every cell is a master/slave pair on loopback, each end offering one 100-byte sample per tick
of a 1 kHz ``tdtp.Ticker`` for ``--duration`` seconds (default 10), both ends in one process on uvloop
(when installed), the process spawned fresh for the cell. Progress goes to stderr, one line per cell.

**Paths** (``--profiles``, the table below lists them): tc-netem specs, the same one applied to both
directions. tdtp rows impair with the library's in-process netem (``tdtp.connect(..., netem=...)`` and
``tdtp.listen(..., netem=...)``, seeded: ``--seed`` for master -> slave, ``--seed + 1`` back); the other
rows go through ``tdtp netem-relay`` (the same emulator in its own process, seeded the same way),
which the pair reaches over loopback.

**Rows** (``--controllers``): every controller registered in ``tdtp.control`` (so one registered
later is picked up without editing this file; the library's default is marked), each on both ends
with its default config; and two baselines through the relay:

- ``zenoh``: eclipse-zenoh (the ``bench`` extra), two peer sessions in the process, UDP unicast only
  (``udp/`` endpoints, no scouting), one publisher and one subscriber each way, ``BEST_EFFORT``,
  ``CongestionControl.DROP``, ``express=True`` (no batching: what a 1 kHz control loop would choose).
  The measurement starts once each side has received the other's probes.
- ``udp``: two plain asyncio datagram sockets, fixed 1 kHz each way, no header, no feedback.

**Figures**, each way (M->S, S->M), over the samples *sent* in the window ``[start, start + duration)``:

- *samples/s*: samples that reached the receiving application by ``start + duration + D + 10 ms``,
  over ``duration``, where D is the path's longest delay without queueing (netem's ``delay`` plus its
  uniform ``jitter``). A bottleneck queue's backlog at the end of the window is not delivery (it is
  in ``received_after_deadline``); after the window the run waits until nothing has arrived for
  0.3 s (at most 5 s), and the latency figures count every sample that arrived;
- *latency p50 / p99*: the sample's arrival at the receiving application (``DataReceived.received_at``
  for tdtp, ``monotonic()`` in the callback for the others) minus the moment the sending application
  offered it (written in the payload; one process, one clock);
- *age p99*: the staleness a controller acting on the newest sample sees. The receiver samples, every
  4.7 ms of the window (a cadence that does not lock to the 1 ms tick), ``now - sent_at(newest)``,
  where newest is the sample with the latest send time received so far; sampling starts with the
  first arrival of the window. It grows with latency *and* with gaps (losses, a throttled rate);
- *wire kbit/s*: what the sender put on the socket, each datagram counted with 28 bytes of IPv4 + UDP
  headers, over the whole session (tdtp: ``stats.sent``, ACKs and handshakes included; relayed rows:
  the relay's link counters), divided by ``duration``.

Issue 19's targets (default controller, 10 s) are checked where a profile has one.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import signal
import socket
import struct
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat

import tdtp
import tdtp.control
from tdtp.netem import parse_netem

RATE = 1000.0
SIZE = 100
UDP_IP = 28
AGE_CADENCE = 0.0047
QUIET = 0.3
SLACK = 0.01
PATIENCE = 5.0
OPEN_PATIENCE = 20.0
BASELINES = ("zenoh", "udp")
SPS, WIRE = "samples_per_s", "wire_bytes"
STAMP = struct.Struct("<dI")
PROBE = 0xFFFFFFFF


@dataclass(frozen=True)
class Profile:
    name: str
    spec: str | None
    what: str
    target_rate: float | None = None
    """Issue 19: samples/s each way the default controller must deliver here (at least)."""
    target_p99_ms: float | None = None
    """Issue 19: latency p99 at most (ms)."""


PROFILES: tuple[Profile, ...] = (
    Profile("clean", None, "loopback, no impairment"),
    Profile("loss1", "loss 1%", "random loss 1 %"),
    Profile("loss2", "loss 2%", "random loss 2 %"),
    Profile("loss5", "loss 5%", "random loss 5 %", target_rate=930.0),
    Profile("loss10", "loss 10%", "random loss 10 %"),
    Profile(
        "jitter",
        "delay 20ms 5ms rate 100mbit",
        "jitter, in order (a 100 Mbit/s rate keeps netem's queue FIFO)",
    ),
    Profile(
        "jitter-reorder",
        "delay 20ms 5ms",
        "jitter that reorders (+-5 ms against 1 ms spacing)",
        target_rate=970.0,
    ),
    Profile("wan", "delay 20ms 5ms loss 2%", "an ordinary WAN path", target_rate=900.0),
    Profile("wan-40", "delay 40ms 10ms loss 1%", "issue 19's second WAN path", target_rate=900.0),
    Profile("wan-far", "delay 80ms 10ms loss 1%", "a far WAN path"),
    Profile(
        "bn500k-shallow",
        "rate 500kbit limit 10",
        "bottleneck below the stream, 10-packet queue",
    ),
    Profile(
        "bn500k-deep",
        "rate 500kbit",
        "bottleneck below the stream, netem's default 1000-packet queue",
        target_p99_ms=150.0,
    ),
    Profile(
        "bn500k-delay",
        "delay 20ms rate 500kbit",
        "the same bottleneck 20 ms away",
        target_p99_ms=190.0,
    ),
    Profile(
        "bn2m-shallow",
        "rate 2mbit limit 10",
        "2 Mbit/s, 10-packet queue (above one direction's 0.84 Mbit/s)",
    ),
    Profile("bn2m-deep", "rate 2mbit", "2 Mbit/s, 1000-packet queue"),
    Profile(
        "wifi",
        "delay 3ms 2ms loss gemodel 1% 30% 70% 0.1% rate 100mbit",
        "bursty Wi-Fi-like loss (Gilbert-Elliott, ~2.4 % in bursts of ~3), in order",
    ),
)
PROFILE_NAMES = tuple(p.name for p in PROFILES)
QUICK_PROFILES = ("clean", "loss5", "bn500k-shallow")
QUICK_DURATION = 1.0


# ---------------------------------------------------------------------------- the receiving side


@dataclass
class Meter:
    """One direction at the receiving application: arrivals, latency, and the newest sample's age."""

    start: float = math.inf
    until: float = math.inf
    deadline: float = math.inf
    """Arrivals after this do not count as delivered (a queue's backlog after the window)."""
    received: int = 0
    received_late: int = 0
    probes: int = 0
    latencies: list[float] = field(default_factory=list)
    newest_sent: float = -math.inf
    ages: list[float] = field(default_factory=list)
    last_arrival: float = 0.0
    sent_times: list[float] = field(default_factory=list)
    """Send time of each sample of the window that arrived, in arrival order (cellular.py)."""
    arrival_times: list[float] = field(default_factory=list)

    def arrived(self, payload: bytes, now: float) -> None:
        self.last_arrival = now
        if len(payload) < STAMP.size:
            return
        sent_at, index = STAMP.unpack_from(payload)
        if index == PROBE:
            self.probes += 1
            return
        if not (self.start <= sent_at < self.until):
            return
        if now <= self.deadline:
            self.received += 1
        else:
            self.received_late += 1
        self.latencies.append(now - sent_at)
        self.sent_times.append(sent_at)
        self.arrival_times.append(now)
        if sent_at > self.newest_sent:
            self.newest_sent = sent_at

    async def sample_ages(self) -> None:
        """Every AGE_CADENCE of the window: now - send time of the newest sample received so far."""
        k = 1
        while True:
            due = self.start + k * AGE_CADENCE
            if due >= self.until:
                return
            await asyncio.sleep(max(0.0, due - tdtp.monotonic()))
            now = tdtp.monotonic()
            if self.newest_sent > -math.inf:
                self.ages.append(now - self.newest_sent)
            k += 1

    def report(self, duration: float) -> Json:
        lat = sorted(self.latencies)
        ages = sorted(self.ages)
        return {
            "received": self.received,
            "received_after_deadline": self.received_late,
            "samples_per_s": self.received / duration,
            "latency_ms": {
                "p50": 1e3 * common.percentile(lat, 0.5),
                "p99": 1e3 * common.percentile(lat, 0.99),
                "max": 1e3 * lat[-1] if lat else math.nan,
            },
            "age_ms": {
                "p50": 1e3 * common.percentile(ages, 0.5),
                "p99": 1e3 * common.percentile(ages, 0.99),
                "n": len(ages),
            },
        }


def stamp(index: int) -> bytes:
    return STAMP.pack(tdtp.monotonic(), index).ljust(SIZE, b"\0")


async def send_loop(send: Callable[[bytes], None], until: float) -> int:
    """One sample per 1 kHz tick until ``until``; returns how many were offered."""
    offered = 0
    async for _ in tdtp.Ticker(RATE):
        if tdtp.monotonic() >= until:
            break
        send(stamp(offered))
        offered += 1
    return offered


async def settle(meters: Sequence[Meter], *, running: Callable[[], bool] = lambda: True) -> None:
    """After the window: wait until nothing has arrived for QUIET seconds (at most PATIENCE)."""
    stop = tdtp.monotonic() + PATIENCE
    while tdtp.monotonic() < stop and running():
        last = max(m.last_arrival for m in meters)
        if tdtp.monotonic() - last > QUIET:
            return
        await asyncio.sleep(0.02)


def propagation(spec: str | None) -> float:
    """The longest one-way delay the spec gives without queueing: delay + jitter (uniform jitter;
    for the other distributions, 4 x jitter, their tables' clip)."""
    if spec is None:
        return 0.0
    delay = parse_netem(spec).delay
    if delay is None:
        return 0.0
    spread = delay.jitter if delay.distribution == "uniform" else 4.0 * delay.jitter
    return delay.delay + spread


async def measure(
    meters: tuple[Meter, Meter],
    senders: tuple[Callable[[bytes], None], Callable[[bytes], None]],
    duration: float,
    spec: str | None,
    *,
    running: Callable[[], bool] = lambda: True,
) -> tuple[float, list[int]]:
    """Both ends send for ``duration``; returns the window's start and what each end offered."""
    start = tdtp.monotonic() + 0.01
    for m in meters:
        m.start, m.until = start, start + duration
        m.deadline = m.until + propagation(spec) + SLACK
    await asyncio.sleep(max(0.0, start - tdtp.monotonic()))
    offered = await asyncio.gather(
        send_loop(senders[0], start + duration),
        send_loop(senders[1], start + duration),
        meters[0].sample_ages(),
        meters[1].sample_ages(),
    )
    await settle(meters, running=running)
    return start, [int(offered[0]), int(offered[1])]


def directions(meters: tuple[Meter, Meter], offered: list[int], duration: float) -> Json:
    """``{"ms": ..., "sm": ...}``: meters[0] receives master -> slave at the slave."""
    out: Json = {}
    for key, meter, n in zip(("ms", "sm"), meters, offered, strict=True):
        out[key] = {"offered": n, **meter.report(duration)}
    return out


# ---------------------------------------------------------------------------- tdtp cells


async def tdtp_pair(
    stack: contextlib.AsyncExitStack,
    controller: str,
    meters: tuple[Meter, Meter],
    *,
    ms: str | None,
    sm: str | None,
    seed: int,
    via: Callable[[int], Awaitable[int]] | None = None,
) -> tuple[tdtp.Endpoint, tdtp.Endpoint]:
    """A master and a slave on loopback with ``controller``, on ``stack``, the samples each receives
    counted by ``meters`` (the slave's, the master's): the slave impairs what it sends with ``sm``
    (seed + 1), the master with ``ms`` (seed); ``via(port)`` puts something in between (a relay) and
    returns the port the master is to reach."""
    config = tdtp.ConnectionConfig(controller=controller, min_peer_payload=SIZE)  # type: ignore[arg-type]
    at_slave, at_master = meters
    server = await stack.enter_async_context(
        tdtp.listen(
            "127.0.0.1",
            0,
            config=config,
            on_data=lambda e: at_slave.arrived(e.payload, e.received_at),
            netem=sm,
            netem_seed=None if sm is None else seed + 1,
        )
    )
    port = server.port if via is None else await via(server.port)
    master = await stack.enter_async_context(
        tdtp.connect(
            "127.0.0.1",
            port,
            config=config,
            on_data=lambda e: at_master.arrived(e.payload, e.received_at),
            netem=ms,
            netem_seed=None if ms is None else seed,
        )
    )
    return master, await server.accept()


async def tdtp_cell(
    controller: str, spec: str | None, duration: float, seed: int, via_relay: bool
) -> Json:
    meters = (Meter(), Meter())
    in_process = None if via_relay else spec
    async with contextlib.AsyncExitStack() as stack:

        async def through_relay(port: int) -> int:
            relay = Relay(spec, port, seed)
            stack.callback(relay.close)
            await relay.ready()
            return relay.port

        master, slave = await tdtp_pair(
            stack,
            controller,
            meters,
            ms=in_process,
            sm=in_process,
            seed=seed,
            via=through_relay if via_relay else None,
        )

        def running() -> bool:
            return not (master.is_closed or slave.is_closed)

        _, offered = await measure(
            meters, (master.send, slave.send), duration, spec, running=running
        )
        result = directions(meters, offered, duration)
        for key, ep in (("ms", master), ("sm", slave)):
            stats = ep.stats
            sent = stats.sent
            result[key]["wire_bytes"] = sent.bytes + UDP_IP * sent.datagrams
            result[key]["sender"] = {
                "offered": stats.samples_offered,
                "sent_data": sent.data_packets,
                "superseded": stats.samples_superseded,
                "blocked": stats.samples_blocked,
                "packets_lost": stats.packets_lost,
                "reordered": stats.reordered,
                "rate_at_end": None if math.isinf(stats.rate) else stats.rate,
                "srtt_ms": 1e3 * stats.srtt,
                "min_rtt_ms": 1e3 * stats.min_rtt,
            }
        for key, ep in (("ms", slave), ("sm", master)):
            stats = ep.stats
            result[key]["receiver"] = {
                "data_packets": stats.received.data_packets,
                "samples_delivered": stats.samples_delivered,
                "drops": dict(stats.drops),
            }
        result["closed_early"] = not running()
        result["build"] = tdtp.build_info().build
        result["netem"] = "relay" if via_relay else "in-process"
    return result


# ---------------------------------------------------------------------------- the relay


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


class Relay:
    """``tdtp netem-relay`` in its own process: listen on a fresh port, forward to ``target``."""

    def __init__(
        self, spec: str | None, target: int, seed: int, return_spec: str | None = None
    ) -> None:
        """``spec`` forward (client -> target), ``return_spec`` back (default: ``spec``)."""
        self.port = free_udp_port()
        # "delay 0ms" impairs nothing: a relay with no impairment keeps the rows comparable.
        command = [
            sys.executable,
            "-m",
            "tdtp",
            "netem-relay",
            spec or "delay 0ms",
            "--listen",
            f"127.0.0.1:{self.port}",
            "--forward",
            f"127.0.0.1:{target}",
            "--json",
        ]
        if spec is not None:
            command += ["--seed", str(seed)]  # the way back: seed + 1, as tdtp's rows
        if return_spec is not None:
            command += ["--return-spec", return_spec]
        if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
            # Started in the background by a shell, this process ignores SIGINT and so would the
            # relay, which then never prints its summary when close() asks: give it the default.
            signal.signal(signal.SIGINT, signal.default_int_handler)
        self.process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )

    async def ready(self, patience: float = 30.0) -> None:
        """Until the relay has bound its port (its interpreter takes a while to start on a loaded
        machine, and a datagram sent before would meet an ICMP port unreachable)."""
        deadline = time.monotonic() + patience
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"netem-relay exited with {self.process.returncode}")
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
                try:
                    probe.bind(("127.0.0.1", self.port))
                except OSError:
                    return  # taken: the relay listens
            await asyncio.sleep(0.05)
        raise RuntimeError(f"netem-relay did not listen within {patience:.0f} s")

    def close(self) -> Json:
        """Stop it (SIGINT: it prints its JSON summary) and return that summary."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            out, err = self.process.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()  # our own child, by its handle
            out, err = self.process.communicate()
        try:
            summary: Json = json.loads(out)
        except json.JSONDecodeError as exc:
            raise RuntimeError(f"netem-relay printed no summary: {err.strip()[-300:]}") from exc
        return summary


async def wait_for_probes(
    meters: Sequence[Meter], senders: Sequence[Callable[[bytes], None]], what: str
) -> None:
    """Send probes every 10 ms from both ends until each end has heard the other."""
    stop = tdtp.monotonic() + OPEN_PATIENCE
    while not all(m.probes for m in meters):
        if tdtp.monotonic() > stop:
            raise RuntimeError(f"{what}: no probe crossed the relay within {OPEN_PATIENCE:.0f} s")
        for send in senders:
            send(STAMP.pack(tdtp.monotonic(), PROBE).ljust(SIZE, b"\0"))
        await asyncio.sleep(0.01)


def relayed_result(
    meters: tuple[Meter, Meter], offered: list[int], duration: float, relay: Json
) -> Json:
    result = directions(meters, offered, duration)
    for key, link in (("ms", relay["forward"]), ("sm", relay["return"])):
        result[key]["wire_bytes"] = link["bytes_in"] + UDP_IP * link["sent"]
        result[key]["relay_link"] = link
    return result


# ---------------------------------------------------------------------------- zenoh cells


def zenoh_missing() -> str | None:
    try:
        import zenoh  # noqa: F401, PLC0415
    except ImportError:
        return "eclipse-zenoh is not installed (pip install 'tdtp[bench]'): zenoh rows skipped"
    return None


def zenoh_config(listen: list[str], connect: list[str]) -> Any:
    import zenoh  # noqa: PLC0415

    config = zenoh.Config()
    for key, value in (
        ("mode", '"peer"'),
        ("listen/endpoints", json.dumps(listen)),
        ("connect/endpoints", json.dumps(connect)),
        ("scouting/multicast/enabled", "false"),
        ("scouting/gossip/enabled", "false"),
        # Over a lossy UDP path the open handshake can lose a message: retry it after 1.5 s (two
        # round trips of the slowest path and then some) instead of the default 10 s.
        ("transport/unicast/open_timeout", "1500"),
        ("transport/unicast/accept_timeout", "1500"),
        ("connect/timeout_ms", "-1"),
        (
            "connect/retry",
            '{"period_init_ms": 100, "period_max_ms": 200, "period_increase_factor": 1.5}',
        ),
    ):
        config.insert_json5(key, value)
    return config


@dataclass
class BaselinePair:
    """A baseline's two ends talking through ``tdtp netem-relay``: what each sends with, when they
    started opening (the relay's links start their traces at its first datagram, just after), and,
    once closed, the relay's summary."""

    senders: tuple[Callable[[bytes], None], Callable[[bytes], None]] = (print, print)
    opened_at: float = math.nan
    relay_summary: Json = field(default_factory=dict)


@contextlib.asynccontextmanager
async def baseline_pair(
    kind: str,
    spec: str | None,
    seed: int,
    on_slave: Callable[[bytes, float], None],
    on_master: Callable[[bytes, float], None],
    *,
    return_spec: str | None = None,
) -> AsyncIterator[BaselinePair]:
    """``zenoh`` or ``udp``: the slave's end, the relay in front of it (``spec`` forward,
    ``return_spec`` back, default the same), the master's end through the relay. Each arriving
    payload goes to ``on_slave``/``on_master`` with its arrival time; ``pair.senders`` send from the
    master and from the slave."""
    pair = BaselinePair()
    if kind == "zenoh":
        async with _zenoh_ends(pair, spec, seed, on_slave, on_master, return_spec):
            yield pair
    else:
        async with _udp_ends(pair, spec, seed, on_slave, on_master, return_spec):
            yield pair


@contextlib.asynccontextmanager
async def _zenoh_ends(
    pair: BaselinePair,
    spec: str | None,
    seed: int,
    on_slave: Callable[[bytes, float], None],
    on_master: Callable[[bytes, float], None],
    return_spec: str | None,
) -> AsyncIterator[None]:
    import zenoh  # noqa: PLC0415

    slave_port = free_udp_port()
    relay = Relay(spec, slave_port, seed, return_spec)
    sessions: list[Any] = []
    try:
        await relay.ready()
        pair.opened_at = tdtp.monotonic()
        slave = zenoh.open(zenoh_config([f"udp/127.0.0.1:{slave_port}"], []))
        sessions.append(slave)
        master = zenoh.open(zenoh_config([], [f"udp/127.0.0.1:{relay.port}"]))
        sessions.append(master)

        def on(arrived: Callable[[bytes, float], None]) -> Callable[[Any], None]:
            def callback(sample: Any) -> None:
                arrived(sample.payload.to_bytes(), tdtp.monotonic())

            return callback

        subscribers = [
            slave.declare_subscriber("tdtp-bench/ms", on(on_slave)),
            master.declare_subscriber("tdtp-bench/sm", on(on_master)),
        ]
        options: Json = {
            "congestion_control": zenoh.CongestionControl.DROP,
            "reliability": zenoh.Reliability.BEST_EFFORT,
            "express": True,
        }
        pubs = (
            master.declare_publisher("tdtp-bench/ms", **options),
            slave.declare_publisher("tdtp-bench/sm", **options),
        )
        pair.senders = (pubs[0].put, pubs[1].put)
        yield
        for s in subscribers:
            s.undeclare()
        for p in pubs:
            p.undeclare()
    finally:
        for s in reversed(sessions):
            s.close()
        pair.relay_summary = relay.close()


class UdpReceiver(asyncio.DatagramProtocol):
    """A plain socket's end: each datagram to ``arrived(payload, now)``; remembers its last peer."""

    def __init__(self, arrived: Callable[[bytes, float], None]) -> None:
        self.arrived = arrived
        self.peer: tuple[str, int] | None = None

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.peer = addr
        self.arrived(data, tdtp.monotonic())


@contextlib.asynccontextmanager
async def _udp_ends(
    pair: BaselinePair,
    spec: str | None,
    seed: int,
    on_slave: Callable[[bytes, float], None],
    on_master: Callable[[bytes, float], None],
    return_spec: str | None,
) -> AsyncIterator[None]:
    loop = asyncio.get_running_loop()
    slave_t, slave_p = await loop.create_datagram_endpoint(
        lambda: UdpReceiver(on_slave), local_addr=("127.0.0.1", 0)
    )
    relay = Relay(spec, slave_t.get_extra_info("sockname")[1], seed, return_spec)
    master_t = None
    try:
        await relay.ready()
        pair.opened_at = tdtp.monotonic()
        master_t, _ = await loop.create_datagram_endpoint(
            lambda: UdpReceiver(on_master), remote_addr=("127.0.0.1", relay.port)
        )

        def sender_s(data: bytes) -> None:
            if slave_p.peer is not None:  # the relay's socket for this client
                slave_t.sendto(data, slave_p.peer)

        pair.senders = (master_t.sendto, sender_s)
        yield
    finally:
        if master_t is not None:
            master_t.close()
        slave_t.close()
        pair.relay_summary = relay.close()


async def baseline_cell(kind: str, spec: str | None, duration: float, seed: int) -> Json:
    """``zenoh`` or ``udp`` through the relay: both ways for ``duration`` once probes crossed."""
    at_slave, at_master = Meter(), Meter()
    meters = (at_slave, at_master)
    async with baseline_pair(kind, spec, seed, at_slave.arrived, at_master.arrived) as pair:
        await wait_for_probes(meters, pair.senders, kind)
        _, offered = await measure(meters, pair.senders, duration, spec)
    result = relayed_result(meters, offered, duration, pair.relay_summary)
    if kind == "zenoh":
        result["zenoh"] = importlib_version("eclipse-zenoh")
    return result


def importlib_version(name: str) -> str | None:
    import importlib.metadata  # noqa: PLC0415

    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


# ---------------------------------------------------------------------------- cells in workers


def cell_worker(
    conn: Any, *, row: str, spec: str | None, duration: float, seed: int, via_relay: bool
) -> None:
    loop = "uvloop" if common.have_uvloop() else "asyncio"

    async def run() -> Json:
        if row in BASELINES:
            return await baseline_cell(row, spec, duration, seed)
        return await tdtp_cell(row, spec, duration, seed, via_relay)

    t0 = time.monotonic()
    result: Json = common.run_in_loop(loop, run)
    result["loop"] = loop
    result["cell_seconds"] = round(time.monotonic() - t0, 2)
    conn.send(result)


def run_cell(row: str, profile: Profile, duration: float, seed: int, via_relay: bool) -> Json:
    others = common.OthersMeter()
    handle = common.start_worker(
        f"paths-{profile.name}-{row}",
        cell_worker,
        row=row,
        spec=profile.spec,
        duration=duration,
        seed=seed,
        via_relay=via_relay,
    )
    try:
        result = handle.recv(timeout=duration + PATIENCE + OPEN_PATIENCE + 30.0)
    finally:
        handle.finish()
    result["others_percent"] = others.percent()  # the worker and its relay joined: ours
    result["ticks_run"] = min(w["offered"] for w in (result["ms"], result["sm"])) / (
        RATE * duration
    )
    return result


# ---------------------------------------------------------------------------- report


def row_label(row: str, default: str) -> str:
    if row in BASELINES:
        return {"zenoh": "Zenoh (UDP, best effort)", "udp": "raw UDP, fixed 1 kHz"}[row]
    return f"tdtp {row}" + (" (default)" if row == default else "")


def judge(profile: Profile, cell: Json) -> tuple[str, bool | None]:
    """Issue 19's target for this profile, and whether the cell meets it (both directions)."""
    parts, ok = [], True
    ways = (cell["ms"], cell["sm"])
    if profile.target_rate is not None:
        parts.append(f">= {profile.target_rate:.0f}/s each way")
        ok = ok and all(w["samples_per_s"] >= profile.target_rate for w in ways)
    if profile.target_p99_ms is not None:
        parts.append(f"p99 <= {profile.target_p99_ms:.0f} ms, >= 80 % of the link")
        ok = ok and all(w["latency_ms"]["p99"] <= profile.target_p99_ms for w in ways)
        capacity = link_capacity(profile)
        if capacity is not None:
            ok = ok and all(w["samples_per_s"] >= 0.8 * capacity for w in ways)
    if not parts:
        return "", None
    return "issue 19: " + ", ".join(parts), ok


def link_capacity(profile: Profile) -> float | None:
    """tdtp samples/s a netem ``rate`` link carries: 105-byte datagrams (the 5-byte header), netem
    counting UDP payloads. (The piggybacked ACKs ride in the header: no extra datagrams.)"""
    if profile.spec is None or "rate" not in profile.spec.split():
        return None
    rate = parse_netem(profile.spec).rate
    if rate is None:
        return None
    return rate.rate_bps / ((SIZE + tdtp.HEADER_SIZE) * 8)


def fmt_ms(value: float) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:,.0f}" if value >= 100 else f"{value:.1f}" if value >= 1 else f"{value:.2f}"


STARVED = 0.98
"""A cell whose sending application ran fewer of its 1 kHz ticks than this was short of CPU."""


def health(cell: Json) -> str:
    """Ticks the sending applications ran (the lower end) and the other tenants' CPU meanwhile."""
    ran = f"{100 * cell['ticks_run']:.0f} %"
    if cell["ticks_run"] < STARVED:
        ran = f"**{ran}**"
    return f"{ran}, {cell['others_percent']:.0f} %"


def markdown(cells: list[Json], default: str) -> str:
    lines = [
        "Each cell: M->S / S->M. Latency and age in ms; wire kbit/s is what each sender put on the "
        "socket with IPv4 + UDP headers. *Ticks run*: the share of its 1 kHz ticks the sending "
        f"application ran (bold below {STARVED:.0%}: the process was short of CPU and the row says "
        "more about the machine than the transport); *others*: CPU the other tenants used meanwhile, "
        "in % of one core.",
        "",
        "| path | netem | row | samples/s | latency p50 | latency p99 | age p99 | wire kbit/s "
        "| ticks run, others | issue 19 target |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for cell in cells:
        if "error" in cell:
            lines.append(
                f"| {cell['profile']} | `{cell['spec'] or '-'}` | {row_label(cell['row'], default)} "
                f"| failed: {cell['error'].splitlines()[-1][:80]} | | | | | | |"
            )
            continue
        ms, sm = cell["ms"], cell["sm"]
        duration = float(cell["duration"])

        def pair(get: Callable[[Json], str], ms: Json = ms, sm: Json = sm) -> str:
            return f"{get(ms)} / {get(sm)}"

        target = "-"
        if cell.get("target"):
            target = f"{cell['target']}: {'yes' if cell['meets'] else '**no**'}"
        lines.append(
            f"| {cell['profile']} | `{cell['spec'] or '-'}` | {row_label(cell['row'], default)} "
            f"| {pair(lambda w: f'{w[SPS]:,.0f}')} "
            f"| {pair(lambda w: fmt_ms(w['latency_ms']['p50']))} "
            f"| {pair(lambda w: fmt_ms(w['latency_ms']['p99']))} "
            f"| {pair(lambda w: fmt_ms(w['age_ms']['p99']))} "
            f"| {pair(lambda w, d=duration: f'{8 * w[WIRE] / d / 1e3:,.0f}')} "
            f"| {health(cell)} | {target} |"
        )
    return "\n".join(lines)


def rows_of(cells: list[Json], default: str) -> list[Row]:
    """One suite row per cell: the worse direction's samples/s, the rest in the note."""
    rows = []
    for cell in cells:
        if "error" in cell:
            continue
        ways = (cell["ms"], cell["sm"])
        worse = min(ways, key=lambda w: w["samples_per_s"])
        note = (
            f"`{cell['spec'] or 'no impairment'}`; latency p99 "
            f"{fmt_ms(max(w['latency_ms']['p99'] for w in ways))} ms, age p99 "
            f"{fmt_ms(max(w['age_ms']['p99'] for w in ways))} ms"
        )
        rows.append(
            Row(
                "paths",
                f"{cell['profile']}, {row_label(cell['row'], default)}: samples/s, worse direction",
                "/s",
                Stat.of([worse["samples_per_s"]]),
                target=cell.get("target", ""),
                meets=cell.get("meets"),
                note=note,
                digits=0,
            )
        )
    return rows


# ---------------------------------------------------------------------------- command line


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    doc = __doc__ or ""
    p = common.OneLineParser(prog="paths.py", description=doc.splitlines()[0])
    p.add_argument("--duration", type=float, default=None, help="seconds per cell (10)")
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"{QUICK_DURATION:g} s per cell, profiles {', '.join(QUICK_PROFILES)} unless given",
    )
    p.add_argument("--profiles", nargs="+", metavar="NAME", help=f"of: {', '.join(PROFILE_NAMES)}")
    p.add_argument(
        "--controllers",
        nargs="+",
        metavar="NAME",
        help="tdtp controllers (every registered one) and/or the baselines zenoh, udp",
    )
    p.add_argument("--seed", type=int, default=1, help="netem seed (1)")
    p.add_argument(
        "--tdtp-via-relay",
        action="store_true",
        help="impair the tdtp rows with tdtp netem-relay too (default: the in-process netem)",
    )
    p.add_argument("--json", action="store_true", help="one JSON report on stdout")
    args = p.parse_args(argv)
    if args.duration is not None and not (0.0 < args.duration <= 3600.0):
        p.error(f"--duration: give seconds between 0 and 3600, got {args.duration:g}")
    if args.duration is None:
        args.duration = QUICK_DURATION if args.quick else 10.0
    if not (0 <= args.seed < 2**63):
        p.error(f"--seed: give a number from 0 to 2^63 - 1, got {args.seed}")
    unknown = [n for n in args.profiles or () if n not in PROFILE_NAMES]
    if unknown:
        p.error(f"--profiles: unknown {', '.join(unknown)}; known: {', '.join(PROFILE_NAMES)}")
    known_rows = (*tdtp.control.available_controllers(), *BASELINES)
    unknown = [n for n in args.controllers or () if n not in known_rows]
    if unknown:
        p.error(f"--controllers: unknown {', '.join(unknown)}; known: {', '.join(known_rows)}")
    if args.profiles is None:
        args.profiles = list(QUICK_PROFILES if args.quick else PROFILE_NAMES)
    if args.controllers is None:
        args.controllers = list(known_rows)
    args.seconds, args.repeat = args.duration, 1  # what common.emit reports
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    default = tdtp.control.DEFAULT_CONTROLLER
    rows_wanted: list[str] = list(dict.fromkeys(args.controllers))
    skipped: Json = {}
    if "zenoh" in rows_wanted and (why := zenoh_missing()):
        print(why, file=sys.stderr)
        skipped["zenoh"] = why
        rows_wanted.remove("zenoh")
    profiles = [p for p in PROFILES if p.name in args.profiles]
    common.warn_if_loaded()
    others = common.OthersMeter()
    cells: list[Json] = []
    total = len(profiles) * len(rows_wanted)
    for profile in profiles:
        for row in rows_wanted:
            label = f"[{len(cells) + 1}/{total}] {profile.name} x {row}"
            print(f"{label} ({profile.spec or 'no impairment'}) ...", file=sys.stderr, flush=True)
            base: Json = {
                "profile": profile.name,
                "spec": profile.spec,
                "row": row,
                "duration": args.duration,
                "default": row == default,
            }
            try:
                cell = {
                    **base,
                    **run_cell(row, profile, args.duration, args.seed, args.tdtp_via_relay),
                }
            except RuntimeError as exc:
                print(f"{label}: failed: {exc}", file=sys.stderr, flush=True)
                cells.append({**base, "error": str(exc)})
                continue
            if row == default:
                cell["target"], cell["meets"] = judge(profile, cell)
            ms, sm = cell["ms"], cell["sm"]
            print(
                f"{label}: {ms['samples_per_s']:.0f} / {sm['samples_per_s']:.0f} samples/s, "
                f"latency p99 {fmt_ms(ms['latency_ms']['p99'])} / "
                f"{fmt_ms(sm['latency_ms']['p99'])} ms, age p99 {fmt_ms(ms['age_ms']['p99'])} / "
                f"{fmt_ms(sm['age_ms']['p99'])} ms; ticks run {100 * cell['ticks_run']:.0f} %, "
                f"other tenants {cell['others_percent']:.0f} % of a core",
                file=sys.stderr,
                flush=True,
            )
            cells.append(cell)
    busy = others.percent()
    text = (
        f"{len(rows_wanted)} rows x {len(profiles)} paths, {args.duration:g} s per cell, "
        f"100-byte samples at 1 kHz each way; default controller: {default}; other tenants used "
        f"{busy:.0f} % of a core meanwhile.\n\n{markdown(cells, default)}"
    )
    details: Json = {
        "default_controller": default,
        "cells": cells,
        "profiles": {p.name: p.spec for p in profiles},
        "skipped": skipped,
        "others_percent": busy,
    }
    return common.emit("paths", args, rows_of(cells, default), details=details, text=text)


if __name__ == "__main__":
    sys.exit(main())
