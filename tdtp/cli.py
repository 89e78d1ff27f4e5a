"""The ``tdtp`` command: ``tdtp demo``, ``tdtp master HOST:PORT``, ``tdtp slave --port N``.

A master sends position samples (a circle traced at 0.5 Hz) at ``--rate`` per second; the slave answers
each period with force feedback from a virtual spring wall. Both print a live status block once per second,
or with ``--json`` one JSON object at the end. Ctrl-C ends a run early and still prints the summary.

Exit status: 0 when the run ended as asked, 1 when the session failed (no slave, refused, lost after a
silence longer than the outage limit), 2 for a usage error (one line on stderr saying what to change),
130 after Ctrl-C.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import sys
from collections import deque
from collections.abc import Awaitable, Callable, Coroutine, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from tdtp import __version__
from tdtp._build import build_info
from tdtp.aio.api import Server, connect, listen
from tdtp.aio.endpoint import Endpoint, WatchdogCallback, format_address
from tdtp.aio.relay import start_relay
from tdtp.aio.ticker import Ticker
from tdtp.aio.timer import check_timer_preference, monotonic
from tdtp.bandwidth_cli import bandwidth_main
from tdtp.cli_keys import (
    KeyArgumentError,
    SessionKeys,
    add_key_arguments,
    keygen_main,
    session_keys,
    warn_if_exposed,
)
from tdtp.cli_parser import EXIT_USAGE, CommandParser
from tdtp.cli_summary import LatencyCounts, capture_report, direction_report
from tdtp.config import MAX_UDP_PAYLOAD, AckMode, ConnectionConfig
from tdtp.control.fixed import FixedConfig
from tdtp.control.registry import DEFAULT_CONTROLLER, available_controllers
from tdtp.errors import (
    AddressError,
    ArgumentTypeError,
    ConnectError,
    EndpointClosedError,
    InvalidArgumentError,
    PayloadTooLargeError,
    TdtpError,
)
from tdtp.events import CloseCause, DataReceived, PeerResumed, PeerSilent
from tdtp.haptic_sample import SAMPLE_SIZE, HapticSample, master_trajectory, slave_feedback
from tdtp.live_stats import (
    DirectionMeter,
    LatencyRecorder,
    LiveDisplay,
    receive_line,
)
from tdtp.netem import NetemSpec, parse_netem
from tdtp.netem.spec import MAX_SEED
from tdtp.pcap import CaptureError, PcapWriter
from tdtp.sim.cli import simulate_main
from tdtp.wire.header import HEADER_SIZE

MAX_LATENCY = 10.0
"""Latencies above this are not recorded (the clocks of two hosts are not comparable)."""
MAX_RATE = 100_000.0
"""The highest --rate: the rate controllers' ceiling (and far beyond any supermedia loop)."""
MAX_SIZE = MAX_UDP_PAYLOAD - HEADER_SIZE
DEFAULT_MAX_PAYLOAD = ConnectionConfig().max_payload
SESSIONS_KEPT = 256
"""Finished sessions a long-running slave remembers for its summary."""

EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED = 0, 1, 130


class UsageError(Exception):
    """A command-line value the library refused; printed as one line, exit status 2."""


# ---------------------------------------------------------------------------- arguments


def _host_port(text: str, *, allow_zero: bool = False) -> tuple[str, int]:
    """``HOST:PORT``, ``[IPv6]:PORT`` or ``IPv6-without-brackets:PORT`` (last colon splits)."""
    if text.startswith("["):
        host, sep, port = text[1:].partition("]:")
    else:
        host, sep, port = text.rpartition(":")
    low = 0 if allow_zero else 1
    if not sep or not host or not port.isdigit() or not low <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(
            f"expected HOST:PORT with a port in {low}..65535 (e.g. 127.0.0.1:7000), got {text!r}"
        )
    return host, int(port)


def _host_port_or_port(text: str) -> tuple[str, int]:
    """``:PORT`` (all interfaces) or ``HOST:PORT``; port 0 picks a free one."""
    if text.startswith(":"):
        text = "0.0.0.0" + text
    return _host_port(text, allow_zero=True)


def _netem_spec(text: str) -> NetemSpec:
    try:
        return parse_netem(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def _integer(low: int, high: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be in {low}..{high}, got {value}")
        return value

    return parse


def _rate(text: str) -> float:
    value = _number(text)
    if not (0.0 < value <= MAX_RATE):  # also refuses nan and inf
        raise argparse.ArgumentTypeError(
            f"must be a number of samples per second above 0 and at most {MAX_RATE:g}, got {text}"
        )
    return value


def _duration(text: str) -> float:
    value = _number(text)
    if not value > 0.0:  # also refuses nan; inf means "until Ctrl-C"
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    common = CommandParser(add_help=False)
    common.add_argument(
        "--rate", type=_rate, default=1000.0, help=f"samples/s, up to {MAX_RATE:g} (1000)"
    )
    common.add_argument(
        "--size",
        type=_integer(SAMPLE_SIZE, MAX_SIZE),
        default=100,
        help=f"payload bytes, {SAMPLE_SIZE}..{MAX_SIZE} (100)",
    )
    common.add_argument("--duration", type=_duration, help="seconds to run")
    common.add_argument(
        "--controller",
        default=DEFAULT_CONTROLLER,
        choices=available_controllers(),
        help="rate control",
    )
    common.add_argument(
        "--separate-acks",
        action="store_true",
        help="Trinomial mode: one ACK packet per data packet instead of piggybacked ACKs",
    )
    common.add_argument(
        "--ack-size",
        type=_integer(HEADER_SIZE, HEADER_SIZE + MAX_SIZE),
        default=HEADER_SIZE,
        help=f"bytes of a stand-alone ACK datagram, {HEADER_SIZE} or more (5)",
    )
    common.add_argument(
        "--silence-timeout",
        type=_duration,
        default=ConnectionConfig().silence_timeout,
        help="seconds without a datagram before the peer is reported silent (0.1)",
    )
    common.add_argument(
        "--idle-timeout",
        type=_duration,
        default=ConnectionConfig().idle_timeout,
        help="seconds of silence after which the session is given up (30)",
    )
    common.add_argument("--json", action="store_true", help="print one JSON summary at the end")
    common.add_argument(
        "--pcap",
        metavar="FILE",
        help="write what the socket sends and receives to FILE, a pcap for Wireshark "
        "(the demo captures the master's socket; tools/wireshark/tdtp.lua decodes it)",
    )
    common.add_argument(
        "--loop", choices=("auto", "uvloop", "asyncio"), default="auto", help="event loop"
    )
    common.add_argument(
        "--timer", choices=("auto", "timerfd", "call_at"), default="auto", help="pacing timer"
    )
    netem = common.add_argument_group(
        "impairment", 'emulated in-process with tc-netem\'s syntax, e.g. "delay 20ms 5ms loss 2%"'
    )
    netem.add_argument("--netem", type=_netem_spec, help="both directions")
    netem.add_argument("--netem-ms", type=_netem_spec, help="master -> slave (overrides --netem)")
    netem.add_argument("--netem-sm", type=_netem_spec, help="slave -> master (overrides --netem)")
    netem.add_argument(
        "--netem-seed", type=_integer(0, MAX_SEED - 1), help="seed for reproducible impairment"
    )

    parser = CommandParser(
        prog="tdtp",
        description="TDTP teleoperation transport: master, slave and demo.",
        epilog="Exit status: 0 done, 1 session failed, 2 usage error, 130 interrupted.",
    )
    parser.add_argument("--version", action="version", version=f"tdtp {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser(
        "demo", parents=[common], help="master and slave on localhost, live statistics"
    )
    demo.set_defaults(duration=None)
    add_key_arguments(demo, demo=True)
    slave = commands.add_parser("slave", parents=[common], help="serve masters on a UDP port")
    slave.add_argument("--host", default="0.0.0.0", help="address to bind (0.0.0.0)")
    slave.add_argument(
        "--port", type=_integer(0, 65535), required=True, help="UDP port (0: any free port)"
    )
    slave.add_argument(
        "--max-peers", type=_integer(1, 1 << 20), default=256, help="masters served at once"
    )
    add_key_arguments(slave)
    master = commands.add_parser("master", parents=[common], help="connect to a slave")
    master.add_argument("address", type=_host_port, help="the slave, HOST:PORT")
    add_key_arguments(master)
    relay = commands.add_parser(
        "netem-relay",
        help="an impairing UDP relay for any application",
        description="Relay UDP datagrams from --listen to --forward through emulated links.",
    )
    relay.add_argument("spec", type=_netem_spec, help='netem syntax, e.g. "delay 30ms loss 1%%"')
    relay.add_argument(
        "--listen", type=_host_port_or_port, required=True, help="[HOST]:PORT to listen on"
    )
    relay.add_argument("--forward", type=_host_port, required=True, help="HOST:PORT to relay to")
    relay.add_argument("--return-spec", type=_netem_spec, help="the way back (default: spec)")
    relay.add_argument(
        "--seed", type=_integer(0, MAX_SEED - 1), help="seed for reproducible impairment"
    )
    relay.add_argument("--duration", type=_duration, help="seconds to run")
    relay.add_argument("--max-clients", type=_integer(1, 1 << 20), default=256)
    relay.add_argument("--json", action="store_true", help="print one JSON summary at the end")
    relay.add_argument("--loop", choices=("auto", "uvloop", "asyncio"), default="auto")
    commands.add_parser(
        "keygen",
        add_help=False,
        help="write new pre-shared keys to a file (tdtp keygen --help)",
    ).add_argument("arguments", nargs=argparse.REMAINDER)
    simulate = commands.add_parser(
        "simulate",
        add_help=False,
        help="reproduce the paper's experiments in virtual time (tdtp simulate --help)",
    )
    simulate.add_argument("arguments", nargs=argparse.REMAINDER)
    bandwidth = commands.add_parser(
        "bandwidth",
        add_help=False,
        help="the paper's figure-5 bandwidth model: table, CSV, PNG (tdtp bandwidth --help)",
    )
    bandwidth.add_argument("arguments", nargs=argparse.REMAINDER)
    return parser


def _config(args: argparse.Namespace) -> ConnectionConfig:
    controller_config: object | None = None
    if args.controller == "fixed":
        controller_config = FixedConfig(rate=args.rate)
    try:
        return ConnectionConfig(
            max_payload=max(DEFAULT_MAX_PAYLOAD, args.size),
            ack_mode=AckMode.SEPARATE if args.separate_acks else AckMode.BIDIRECTIONAL,
            ack_size=args.ack_size,
            controller=args.controller,
            controller_config=controller_config,
            silence_timeout=args.silence_timeout,
            idle_timeout=args.idle_timeout,
            # A peer that cannot take our samples is refused at the open, not on the first send.
            min_peer_payload=args.size,
            encrypt=not getattr(args, "no_encrypt", False),
        )
    except InvalidArgumentError as exc:
        option = str(exc).split(" ", 1)[0].replace("_", "-")
        raise UsageError(f"--{option}: {exc}") from None


# ---------------------------------------------------------------------------- application loops


@dataclass
class Side:
    """One end's application: what it sends, what it received, how late it arrived."""

    name: str
    latency: LatencyRecorder = field(default_factory=LatencyRecorder)
    received: int = 0
    last_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    not_haptic: int = 0
    clock_mismatch: int = 0
    started: float = 0.0

    def on_data(self, event: DataReceived) -> None:
        self.received += 1
        sample = HapticSample.decode(event.payload)
        if sample is None:
            self.not_haptic += 1
            return
        self.last_position = sample.position
        latency = event.received_at - sample.sent_at
        if 0.0 <= latency < MAX_LATENCY:
            self.latency.add(latency)
        else:
            self.clock_mismatch += 1

    def latency_counts(self) -> LatencyCounts:
        return LatencyCounts(self.latency, self.not_haptic, self.clock_mismatch)


@dataclass
class Outcome:
    """What a run leaves behind, even when Ctrl-C cuts it short."""

    summary: dict[str, Any] | None = None
    status: int = EXIT_OK
    failure: str | None = None


@contextlib.contextmanager
def _capture(args: argparse.Namespace, outcome: Outcome) -> Iterator[PcapWriter | None]:
    """The ``--pcap`` file of a run, if asked for: closed when the run ends, however it ends, and
    described in the run's summary."""
    capture = PcapWriter(args.pcap) if args.pcap is not None else None
    try:
        yield capture
    finally:
        if capture is not None:
            capture.close()
            if outcome.summary is not None:
                outcome.summary["pcap"] = capture_report(capture)


async def _send_loop(
    ep: Endpoint, side: Side, rate: float, size: int, until: float, *, master: bool
) -> None:
    """Offer a sample per tick until ``until`` (however slow the rate) or the session ends."""
    start = monotonic()
    remaining = until - start
    with contextlib.suppress(TimeoutError, EndpointClosedError):
        async with asyncio.timeout(None if math.isinf(remaining) else max(0.0, remaining)):
            async for index in Ticker(rate):  # the loop's tick group: one wake-up for all
                now = monotonic()
                if now >= until or ep.is_closed:
                    return
                if master:
                    sample = master_trajectory(now - start, index, now)
                else:
                    sample = slave_feedback(side.last_position, index, now)
                ep.send(sample.encode(size))


async def _every_second(until: float, tick: Callable[[float], None]) -> None:
    """Call ``tick(interval)`` on whole seconds from now until ``until`` (a last, shorter interval
    only if it is worth showing)."""
    start = last = monotonic()
    mark = 1
    while True:
        due = min(start + mark, until)
        if due - last < 0.25:
            return
        await asyncio.sleep(max(0.0, due - monotonic()))
        now = monotonic()
        tick(now - last)
        last = now
        mark += 1


async def _with_display(work: Awaitable[Any], display: Coroutine[Any, Any, None]) -> None:
    """Run ``work`` with the live display beside it; the display stops when the work does."""
    shown = asyncio.create_task(display)
    try:
        await work
    finally:
        shown.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await shown


def _silence_note(ep: Endpoint, listener: str) -> str | None:
    """``"<listener> hears nothing for 1.2 s"`` while ``ep``'s watchdog finds the peer silent."""
    since = ep.connection.silent_since
    if since is None:
        return None
    return f"SILENT: {listener} hears nothing for {monotonic() - since:.1f} s"


def _watchdog_log(
    display: LiveDisplay | None, start: float, listener: str, peer: str
) -> WatchdogCallback | None:
    """Lines that stay in the display's log when ``listener`` loses and regains its ``peer``."""
    if display is None:
        return None

    def on_watchdog(event: PeerSilent | PeerResumed) -> None:
        assert display is not None
        at = f"t={monotonic() - start:6.1f} s"
        if isinstance(event, PeerSilent):
            display.message(f"{at}  {listener} hears nothing from the {peer} (watchdog)")
        else:
            display.message(
                f"{at}  {listener} hears the {peer} again after {event.silent_for:.2f} s"
            )

    return on_watchdog


def _header(args: argparse.Namespace, ep: Endpoint) -> str:
    mode = "separate ACKs" if args.separate_acks else "piggybacked ACKs"
    loop = type(asyncio.get_running_loop()).__module__.split(".")[0]
    conn = ep.connection
    security = "unkeyed"
    if conn.keyed:
        key = conn.key
        security = f"keyed ({key.label if key else '?'}, {conn.config.cipher_suite.name}, " + (
            "encrypted)" if conn.encrypted else "authenticated only)"
        )
    return (
        f"tdtp {args.command}: {args.rate:g} samples/s of {args.size} B each way, "
        f"{args.controller}, {mode}, {security}, loop {loop}, timer {ep.timer_kind}, "
        f"core {build_info().describe()}"
    )


def _close_info(ep: Endpoint) -> dict[str, str] | None:
    event = ep.close_event
    return None if event is None else {"cause": event.cause.value, "detail": event.detail}


async def run_demo(args: argparse.Namespace, outcome: Outcome) -> None:
    config = _config(args)
    keys: SessionKeys = args.session_keys
    master_side, slave_side = Side("master"), Side("slave")
    with _capture(args, outcome) as capture:
        await _demo(args, outcome, config, keys, master_side, slave_side, capture)


async def _demo(
    args: argparse.Namespace,
    outcome: Outcome,
    config: ConnectionConfig,
    keys: SessionKeys,
    master_side: Side,
    slave_side: Side,
    capture: PcapWriter | None,
) -> None:
    duration = args.duration if args.duration is not None else 5.0
    ms_spec, sm_spec = _directions(args)
    async with (
        listen(
            "127.0.0.1",
            0,
            config=config,
            timer=args.timer,
            on_data=slave_side.on_data,
            netem=sm_spec,
            netem_seed=_seed(args, 1),
            keys=keys.slave,
        ) as server,
        connect(
            "127.0.0.1",
            server.port,
            config=config,
            timer=args.timer,
            on_data=master_side.on_data,
            netem=ms_spec,
            netem_seed=_seed(args, 0),
            key=keys.master,
            pcap=capture,
        ) as master,
    ):
        slave = await server.accept()
        start = monotonic()
        until = start + duration
        elapsed: float | None = None
        display = None if args.json else LiveDisplay()
        meters = (DirectionMeter("M->S"), DirectionMeter("S->M"))
        if display is not None:
            display.message(_header(args, master))
        master.set_watchdog_callback(_watchdog_log(display, start, "master", "slave"))
        slave.set_watchdog_callback(_watchdog_log(display, start, "slave", "master"))

        def show(interval: float) -> None:
            assert display is not None
            lines = [f"t={monotonic() - start:6.1f} s"]
            lines.append(
                meters[0].line(
                    master.stats,
                    slave.stats.received.data_packets,
                    interval,
                    slave_side.latency.take_window(),
                    _silence_note(slave, "slave"),
                )
            )
            lines.append(
                meters[1].line(
                    slave.stats,
                    master.stats.received.data_packets,
                    interval,
                    master_side.latency.take_window(),
                    _silence_note(master, "master"),
                )
            )
            display.update(lines)

        def summarize() -> None:
            spent = elapsed if elapsed is not None else monotonic() - start
            both = ["master", "slave"]
            outcome.summary = {
                "command": "demo",
                "duration_s": round(spent, 3),
                **_settings(args, master),
                "master_to_slave": direction_report(
                    sender=master.stats,
                    receiver=slave.stats,
                    observed_at=both,
                    duration=spent,
                    latency=slave_side.latency_counts(),
                ),
                "slave_to_master": direction_report(
                    sender=slave.stats,
                    receiver=master.stats,
                    observed_at=both,
                    duration=spent,
                    latency=master_side.latency_counts(),
                ),
            }

        try:
            sending = asyncio.gather(
                _send_loop(master, master_side, args.rate, args.size, until, master=True),
                _send_loop(slave, slave_side, args.rate, args.size, until, master=False),
            )
            if display is None:
                await sending
            else:
                await _with_display(sending, _every_second(until, show))
            elapsed = monotonic() - start  # the sending window: rates are per second of it
            await _settle(master, slave)  # let the last samples land before counting
        finally:
            summarize()


SETTLE_PATIENCE = 2.0
"""Longest the demo waits for its last samples to land before it counts."""


async def _settle(*endpoints: Endpoint) -> None:
    """Wait until every sample offered has left and arrived, or nothing has moved for a while (an
    emulated loss leaves some never to arrive); a fixed pause would undercount on a loaded machine."""

    def figures() -> tuple[int, ...]:
        return tuple(
            n
            for ep in endpoints
            for n in (ep.stats.sent.data_packets, ep.stats.received.data_packets)
        )

    def done() -> bool:
        for ep in endpoints:
            stats = ep.stats
            if stats.sent.data_packets + stats.samples_superseded != stats.samples_offered:
                return False  # a sample is still held by the pacer
        sent = sum(ep.stats.sent.data_packets for ep in endpoints)
        return sent == sum(ep.stats.received.data_packets for ep in endpoints)

    start = last_change = monotonic()
    last = figures()
    while not done():
        now = monotonic()
        quiet = max(0.1, 4 * max(ep.stats.srtt for ep in endpoints))
        if now - start > SETTLE_PATIENCE or now - last_change > quiet:
            return
        await asyncio.sleep(0.01)
        current = figures()
        if current != last:
            last, last_change = current, monotonic()


def _directions(args: argparse.Namespace) -> tuple[NetemSpec | None, NetemSpec | None]:
    """The impairment master -> slave and slave -> master."""
    both: NetemSpec | None = getattr(args, "netem", None)
    ms = getattr(args, "netem_ms", None) or both
    sm = getattr(args, "netem_sm", None) or both
    return ms, sm


def _seed(args: argparse.Namespace, offset: int) -> int | None:
    seed: int | None = getattr(args, "netem_seed", None)
    return None if seed is None else seed + offset


def _settings(args: argparse.Namespace, ep: Endpoint) -> dict[str, Any]:
    ms, sm = _directions(args)
    return {
        "rate": args.rate,
        "size": args.size,
        "controller": args.controller,
        "ack_mode": "separate" if args.separate_acks else "bidirectional",
        "loop": type(asyncio.get_running_loop()).__module__.split(".")[0],
        "timer": ep.timer_kind,
        "core": build_info().as_dict(),
        "keyed": ep.connection.keyed,
        "encrypted": ep.connection.encrypted,
        "netem_ms": None if ms is None else str(ms),
        "netem_sm": None if sm is None else str(sm),
    }


async def run_master(args: argparse.Namespace, outcome: Outcome) -> None:
    with _capture(args, outcome) as capture:
        await _master(args, outcome, capture)


async def _master(args: argparse.Namespace, outcome: Outcome, capture: PcapWriter | None) -> None:
    host, port = args.address
    side = Side("master")
    ms_spec, _ = _directions(args)
    async with connect(
        host,
        port,
        config=_config(args),
        timer=args.timer,
        on_data=side.on_data,
        netem=ms_spec,
        netem_seed=_seed(args, 0),
        key=args.session_keys.master,
        pcap=capture,
    ) as ep:
        start = monotonic()
        until = start + (args.duration or math.inf)
        display = None if args.json else LiveDisplay()
        meter = DirectionMeter("M->S")
        reverse_meter = DirectionMeter("S->M")
        if display is not None:
            display.message(_header(args, ep) + f", slave {format_address((host, port))}")
        ep.set_watchdog_callback(_watchdog_log(display, start, "master", "slave"))

        def show(interval: float) -> None:
            assert display is not None
            lines = [
                f"t={monotonic() - start:6.1f} s",
                meter.line(ep.stats, ep.stats.packets_acked, interval, None),
                receive_line("S->M", side.received, reverse_meter, interval, side.latency),
            ]
            note = _silence_note(ep, "master")
            if note is not None:
                lines.append(note)
            display.update(lines)

        try:
            sending = _send_loop(ep, side, args.rate, args.size, until, master=True)
            if display is None:
                await sending
            else:
                await _with_display(sending, _every_second(until, show))
        finally:
            elapsed = monotonic() - start
            outcome.summary = {
                "command": "master",
                "duration_s": round(elapsed, 3),
                **_settings(args, ep),
                "master_to_slave": direction_report(
                    sender=ep.stats,
                    receiver=None,
                    observed_at=["master"],
                    duration=elapsed,
                    latency=None,
                ),
                "slave_to_master": direction_report(
                    sender=None,
                    receiver=ep.stats,
                    observed_at=["master"],
                    duration=elapsed,
                    latency=side.latency_counts(),
                ),
                "peer_silences": ep.stats.peer_silences,
                "longest_silence_s": round(ep.stats.longest_silence, 3),
                "close": _close_info(ep),
            }
            event = ep.close_event
            if event is not None and event.cause is not CloseCause.PEER_CLOSE:
                outcome.status = EXIT_FAILED
                outcome.failure = f"session lost ({event.cause.value}): {event.detail}"


async def run_slave(args: argparse.Namespace, outcome: Outcome) -> None:
    keys: SessionKeys = args.session_keys
    with _capture(args, outcome) as capture:
        await _slave(args, outcome, keys, capture)


async def _slave(
    args: argparse.Namespace, outcome: Outcome, keys: SessionKeys, capture: PcapWriter | None
) -> None:
    until = math.inf if args.duration is None else monotonic() + args.duration
    sides: dict[int, Side] = {}
    finished: deque[dict[str, Any]] = deque(maxlen=SESSIONS_KEPT)
    _, sm_spec = _directions(args)
    async with listen(
        args.host,
        args.port,
        config=_config(args),
        max_peers=args.max_peers,
        timer=args.timer,
        netem=sm_spec,
        netem_seed=_seed(args, 1),
        keys=keys.slave,
        pcap=capture,
    ) as server:
        warn_if_exposed(args.host, keys)  # once bound: a slave that failed to start exposes nothing
        display = None if args.json else LiveDisplay()
        if display is not None:
            keyed = f", keyed ({len(keys.slave)} key(s))" if keys.slave is not None else ", unkeyed"
            display.message(f"tdtp slave listening on {format_address(server.sockname)}{keyed}")
        tasks: set[asyncio.Task[None]] = set()
        acceptor = asyncio.create_task(
            _accept_loop(server, sides, args, until, tasks, finished, display)
        )
        try:
            await _every_second(until, lambda interval: _show_slave(display, server, sides))
        finally:
            acceptor.cancel()
            for task in tasks:
                task.cancel()
            sessions = list(finished) + [_session(ep, sides.get(id(ep))) for ep in server.endpoints]
            outcome.summary = {
                "command": "slave",
                "masters_served": server.stats.peers_accepted,
                "masters_refused": server.stats.peers_refused,
                "datagrams_unattached": server.stats.datagrams_unattached,
                "admission": asdict(server.stats.admission),
                "sessions": sessions,
            }


def _session(ep: Endpoint, side: Side | None) -> dict[str, Any]:
    """One master's session as the slave saw it: both directions from this end."""
    duration = monotonic() - side.started if side is not None else 0.0
    key = ep.connection.key
    return {
        "master": format_address(ep.peer),
        "key": None if key is None else key.label,
        "duration_s": round(duration, 3),
        "closed": ep.is_closed,
        "samples_received": side.received if side else ep.stats.samples_delivered,
        "samples_sent": ep.stats.sent.data_packets,
        "peer_silences": ep.stats.peer_silences,
        "longest_silence_s": round(ep.stats.longest_silence, 3),
        "close": _close_info(ep),
        "master_to_slave": direction_report(
            sender=None,
            receiver=ep.stats,
            observed_at=["slave"],
            duration=duration,
            latency=side.latency_counts() if side is not None else None,
        ),
        "slave_to_master": direction_report(
            sender=ep.stats, receiver=None, observed_at=["slave"], duration=duration, latency=None
        ),
    }


async def _accept_loop(
    server: Server,
    sides: dict[int, Side],
    args: argparse.Namespace,
    until: float,
    tasks: set[asyncio.Task[None]],
    finished: deque[dict[str, Any]],
    display: LiveDisplay | None,
) -> None:
    start = monotonic()
    async for ep in server:
        side = Side(f"master {format_address(ep.peer)}", started=monotonic())
        sides[id(ep)] = side
        ep.set_data_callback(side.on_data)
        ep.set_watchdog_callback(
            _watchdog_log(display, start, "slave", f"master {format_address(ep.peer)}")
        )
        task = asyncio.create_task(_serve_one(ep, side, args, until, sides, finished))
        tasks.add(task)
        task.add_done_callback(tasks.discard)


async def _serve_one(
    ep: Endpoint,
    side: Side,
    args: argparse.Namespace,
    until: float,
    sides: dict[int, Side],
    finished: deque[dict[str, Any]],
) -> None:
    await _send_loop(ep, side, args.rate, args.size, until, master=False)
    if ep.is_closed:
        finished.append(_session(ep, side))
        sides.pop(id(ep), None)


def _show_slave(display: LiveDisplay | None, server: Server, sides: dict[int, Side]) -> None:
    if display is None:
        return
    lines = [f"{len(server.endpoints)} master(s) connected"]
    for ep in server.endpoints:
        side = sides.get(id(ep))
        stats = ep.stats
        line = (
            f"  {format_address(ep.peer)}:  received {side.received if side else 0} samples"
            f"  sent {stats.sent.data_packets}  srtt {stats.srtt * 1e3:.3f} ms"
            f"  lost {stats.packets_lost}  allowed {stats.rate:.0f}/s"
        )
        note = _silence_note(ep, "slave")
        if note is not None:
            line += "  " + note
        lines.append(line)
    display.update(lines)


async def run_relay(args: argparse.Namespace, outcome: Outcome) -> None:
    relay = await start_relay(
        args.listen,
        args.forward,
        args.spec,
        return_spec=args.return_spec,
        seed=args.seed,
        max_clients=args.max_clients,
    )
    display = None if args.json else LiveDisplay()
    if display is not None:
        display.message(
            f"relaying {format_address(relay.address)} -> {format_address(args.forward)}"
            f" with forward '{args.spec}', return '{args.return_spec or args.spec}'"
        )

    def show(interval: float) -> None:
        if display is None:
            return
        fwd, back = relay.forward.link.stats, relay.back.link.stats
        display.update(
            [
                f"clients {relay.stats.clients}  forwarded {relay.stats.forwarded}"
                f"  returned {relay.stats.returned}  not forwarded {relay.stats.forward_errors}",
                f"  forward: {_link_line(fwd)}",
                f"  return:  {_link_line(back)}",
            ]
        )

    try:
        until = math.inf if args.duration is None else monotonic() + args.duration
        await _every_second(until, show)
    finally:
        await relay.close()
        outcome.summary = {
            "command": "netem-relay",
            "relay": asdict(relay.stats),
            "forward": asdict(relay.forward.link.stats),
            "return": asdict(relay.back.link.stats),
        }


def _link_line(stats: Any) -> str:
    return "  ".join(f"{name} {value}" for name, value in asdict(stats).items())


# ---------------------------------------------------------------------------- entry point


def _loop_factory(choice: str) -> Callable[[], asyncio.AbstractEventLoop] | None:
    if choice == "asyncio":
        return None
    try:
        import uvloop  # noqa: PLC0415 -- optional (the "fast" extra): imported only when wanted
    except ImportError:
        if choice == "uvloop":
            raise UsageError(
                "--loop uvloop: uvloop is not installed (pip install 'tdtp[fast]')"
            ) from None
        return None
    factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
    return factory


Runner = Callable[[argparse.Namespace, Outcome], Coroutine[Any, Any, None]]
RUNNERS: dict[str, Runner] = {
    "demo": run_demo,
    "master": run_master,
    "slave": run_slave,
    "netem-relay": run_relay,
}

_USAGE_ERRORS = (
    UsageError,
    KeyArgumentError,
    CaptureError,
    InvalidArgumentError,
    ArgumentTypeError,
    AddressError,
    PayloadTooLargeError,
)
"""Errors that a different command line fixes: exit status 2."""


def _fail(message: object, status: int) -> int:
    print(f"tdtp: {message}", file=sys.stderr)
    return status


def main(argv: Sequence[str] | None = None) -> int:
    arguments = list(sys.argv[1:] if argv is None else argv)
    if arguments[:1] == ["simulate"]:
        # Its own parser (tdtp.sim.cli); the subcommand below only lists it in --help.
        return simulate_main(arguments[1:])
    if arguments[:1] == ["keygen"]:
        return keygen_main(arguments[1:])
    if arguments[:1] == ["bandwidth"]:
        return bandwidth_main(arguments[1:])
    args = build_parser().parse_args(arguments)  # exits 2 with argparse's message on its own
    try:
        if args.command in ("demo", "master", "slave"):
            args.session_keys = session_keys(args)
        if hasattr(args, "timer"):
            check_timer_preference(args.timer)
        if hasattr(args, "controller"):
            _config(args)
        loop_factory = _loop_factory(args.loop)
    except (*_USAGE_ERRORS, TdtpError) as exc:
        return _fail(exc, EXIT_USAGE)
    outcome = Outcome()
    interrupted = False
    try:
        with asyncio.Runner(loop_factory=loop_factory) as runner:
            runner.run(RUNNERS[args.command](args, outcome))
    except KeyboardInterrupt:
        interrupted = True
    except _USAGE_ERRORS as exc:
        return _fail(exc, EXIT_USAGE)
    except (ConnectError, TdtpError, OSError) as exc:
        return _fail(exc, EXIT_FAILED)
    if outcome.summary is not None:
        if args.json or args.command != "demo":
            print(json.dumps(outcome.summary, indent=2))
        else:
            print(_demo_table(outcome.summary))
    if interrupted:
        return EXIT_INTERRUPTED
    if outcome.failure is not None:
        return _fail(outcome.failure, outcome.status)
    return outcome.status


def _demo_table(summary: dict[str, Any]) -> str:
    rows = []
    for key, label in (("master_to_slave", "M->S"), ("slave_to_master", "S->M")):
        d = summary[key]
        latency = d.get("latency_ms") or {}
        rows.append(
            f"{label}: offered {d['samples_offered']}, sent {d['packets_sent']}, "
            f"received {d['packets_received']} ({d['delivery_ratio'] * 100:.2f} %), "
            f"lost {d['losses']}, {d['mean_rate']:.1f} pkt/s, srtt {d['srtt_ms']:.3f} ms, "
            f"latency p50 {latency.get('p50', math.nan):.3f} ms p99 "
            f"{latency.get('p99', math.nan):.3f} ms, header bytes {d['header_bytes']}, "
            f"ACK packets {d['ack_packets_sent_back']}"
        )
    return "\n".join(rows)


if __name__ == "__main__":
    sys.exit(main())
