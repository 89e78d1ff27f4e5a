"""The ``tdtp`` command: ``tdtp demo``, ``tdtp master HOST:PORT``, ``tdtp slave --port N``.

A master sends position samples (a circle traced at 0.5 Hz) at ``--rate`` per second; the slave answers
each period with force feedback from a virtual spring wall. Both print a live status block once per second,
or with ``--json`` one JSON object at the end.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import sys
from collections.abc import Callable, Coroutine, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from tdtp.aio.api import ConnectError, Server, connect, listen
from tdtp.aio.endpoint import Endpoint
from tdtp.aio.relay import start_relay
from tdtp.aio.ticker import Ticker
from tdtp.aio.timer import monotonic
from tdtp.bandwidth_cli import bandwidth_main
from tdtp.config import AckMode, ConnectionConfig
from tdtp.control.fixed import FixedConfig
from tdtp.control.registry import available_controllers
from tdtp.events import DataReceived
from tdtp.haptic_sample import SAMPLE_SIZE, HapticSample, master_trajectory, slave_feedback
from tdtp.live_stats import (
    DirectionMeter,
    LatencyRecorder,
    LiveDisplay,
    direction_summary,
    receive_line,
)
from tdtp.netem import NetemSpec, parse_netem
from tdtp.sim.cli import simulate_main

MAX_LATENCY = 10.0
"""Latencies above this are not recorded (the clocks of two hosts are not comparable)."""


# ---------------------------------------------------------------------------- arguments


def _host_port(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``[IPv6]:PORT`` or ``IPv6-without-brackets:PORT`` (last colon splits)."""
    if text.startswith("["):
        host, sep, port = text[1:].partition("]:")
    else:
        host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT (e.g. 127.0.0.1:7000), got {text!r}")
    return host, int(port)


def _host_port_or_port(text: str) -> tuple[str, int]:
    """``:PORT`` (all interfaces) or ``HOST:PORT``."""
    if text.startswith(":"):
        text = "0.0.0.0" + text
    return _host_port(text)


def _netem_spec(text: str) -> NetemSpec:
    try:
        return parse_netem(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _positive(kind: Callable[[str], float]) -> Callable[[str], float]:
    def parse(text: str) -> float:
        value = kind(text)
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value

    return parse


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--rate", type=_positive(float), default=1000.0, help="samples/s (1000)")
    common.add_argument(
        "--size", type=int, default=100, help=f"payload bytes, >= {SAMPLE_SIZE} (100)"
    )
    common.add_argument("--duration", type=_positive(float), help="seconds to run")
    common.add_argument(
        "--controller", default="trinomial", choices=available_controllers(), help="rate control"
    )
    common.add_argument(
        "--separate-acks",
        action="store_true",
        help="Trinomial mode: one ACK packet per data packet instead of piggybacked ACKs",
    )
    common.add_argument(
        "--ack-size", type=int, default=5, help="bytes of a stand-alone ACK datagram (5)"
    )
    common.add_argument("--json", action="store_true", help="print one JSON summary at the end")
    common.add_argument(
        "--loop", choices=("auto", "uvloop", "asyncio"), default="auto", help="event loop"
    )
    common.add_argument(
        "--timer", choices=("auto", "timerfd", "call_at"), default="auto", help="pacing timer"
    )
    netem = common.add_argument_group(
        "impairment", 'emulated in-process with tc-netem\'s syntax, e.g. "delay 20ms 5ms loss 2%%"'
    )
    netem.add_argument("--netem", type=_netem_spec, help="both directions")
    netem.add_argument("--netem-ms", type=_netem_spec, help="master -> slave (overrides --netem)")
    netem.add_argument("--netem-sm", type=_netem_spec, help="slave -> master (overrides --netem)")
    netem.add_argument("--netem-seed", type=int, help="seed for reproducible impairment")

    parser = argparse.ArgumentParser(
        prog="tdtp", description="TDTP teleoperation transport: master, slave and demo."
    )
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser(
        "demo", parents=[common], help="master and slave on localhost, live statistics"
    )
    demo.set_defaults(duration=None)
    slave = commands.add_parser("slave", parents=[common], help="serve masters on a UDP port")
    slave.add_argument("--host", default="0.0.0.0", help="address to bind (0.0.0.0)")
    slave.add_argument("--port", type=int, required=True, help="UDP port")
    slave.add_argument("--max-peers", type=int, default=256, help="masters served at once")
    master = commands.add_parser("master", parents=[common], help="connect to a slave")
    master.add_argument("address", type=_host_port, help="the slave, HOST:PORT")
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
    relay.add_argument("--seed", type=int, help="seed for reproducible impairment")
    relay.add_argument("--duration", type=_positive(float), help="seconds to run")
    relay.add_argument("--max-clients", type=int, default=256)
    relay.add_argument("--json", action="store_true", help="print one JSON summary at the end")
    relay.add_argument("--loop", choices=("auto", "uvloop", "asyncio"), default="auto")
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
    return ConnectionConfig(
        ack_mode=AckMode.SEPARATE if args.separate_acks else AckMode.BIDIRECTIONAL,
        ack_size=args.ack_size,
        controller=args.controller,
        controller_config=controller_config,
    )


# ---------------------------------------------------------------------------- application loops


@dataclass
class Side:
    """One end's application: what it sends, what it received, how late it arrived."""

    name: str
    latency: LatencyRecorder = field(default_factory=LatencyRecorder)
    received: int = 0
    last_position: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def on_data(self, event: DataReceived) -> None:
        self.received += 1
        sample = HapticSample.decode(event.payload)
        if sample is None:
            return
        self.last_position = sample.position
        latency = event.received_at - sample.sent_at
        if 0.0 <= latency < MAX_LATENCY:
            self.latency.add(latency)


async def _send_loop(
    ep: Endpoint, side: Side, rate: float, size: int, until: float, *, master: bool
) -> None:
    start = monotonic()
    async for index in Ticker(rate, start=start):
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


def _header(args: argparse.Namespace, ep: Endpoint) -> str:
    mode = "separate ACKs" if args.separate_acks else "piggybacked ACKs"
    loop = type(asyncio.get_running_loop()).__module__.split(".")[0]
    return (
        f"tdtp {args.command}: {args.rate:g} samples/s of {args.size} B each way, "
        f"{args.controller}, {mode}, loop {loop}, timer {ep.timer_kind}"
    )


async def run_demo(args: argparse.Namespace) -> dict[str, Any]:
    config = _config(args)
    duration = args.duration if args.duration is not None else 5.0
    master_side, slave_side = Side("master"), Side("slave")
    ms_spec, sm_spec = _directions(args)
    async with (
        await listen(
            "127.0.0.1",
            0,
            config=config,
            on_data=slave_side.on_data,
            netem=sm_spec,
            netem_seed=_seed(args, 1),
        ) as server,
        await connect(
            "127.0.0.1",
            server.port,
            config=config,
            on_data=master_side.on_data,
            netem=ms_spec,
            netem_seed=_seed(args, 0),
        ) as master,
    ):
        slave = await server.accept()
        start = monotonic()
        until = start + duration
        display = None if args.json else LiveDisplay()
        meters = (DirectionMeter("M->S"), DirectionMeter("S->M"))
        if display is not None:
            display.message(_header(args, master))

        def show(interval: float) -> None:
            assert display is not None
            display.update(
                [
                    f"t={monotonic() - start:6.1f} s",
                    meters[0].line(
                        master.stats,
                        slave.stats.received.data_packets,
                        interval,
                        slave_side.latency.take_window(),
                    ),
                    meters[1].line(
                        slave.stats,
                        master.stats.received.data_packets,
                        interval,
                        master_side.latency.take_window(),
                    ),
                ]
            )

        tasks = [
            _send_loop(master, master_side, args.rate, args.size, until, master=True),
            _send_loop(slave, slave_side, args.rate, args.size, until, master=False),
        ]
        if display is not None:
            tasks.append(_every_second(until, show))
        await asyncio.gather(*tasks)
        elapsed = monotonic() - start  # the sending window: rates are per second of it
        await asyncio.sleep(0.05)  # let the last samples land before counting
        summary = {
            "command": "demo",
            "duration_s": round(elapsed, 3),
            **_settings(args, master),
            "master_to_slave": direction_summary(
                master.stats, slave.stats, elapsed, slave_side.latency
            ),
            "slave_to_master": direction_summary(
                slave.stats, master.stats, elapsed, master_side.latency
            ),
        }
    return summary


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
        "netem_ms": None if ms is None else str(ms),
        "netem_sm": None if sm is None else str(sm),
    }


async def run_master(args: argparse.Namespace) -> dict[str, Any]:
    host, port = args.address
    side = Side("master")
    until = math.inf if args.duration is None else monotonic() + args.duration
    ms_spec, _ = _directions(args)
    async with await connect(
        host,
        port,
        config=_config(args),
        on_data=side.on_data,
        netem=ms_spec,
        netem_seed=_seed(args, 0),
    ) as ep:
        start = monotonic()
        until = min(until, start + (args.duration or math.inf))
        display = None if args.json else LiveDisplay()
        meters = (DirectionMeter("M->S"),)
        reverse_meter = DirectionMeter("S->M")
        if display is not None:
            display.message(_header(args, ep) + f", slave {host}:{port}")

        def show(interval: float) -> None:
            assert display is not None
            display.update(
                [
                    f"t={monotonic() - start:6.1f} s",
                    meters[0].line(ep.stats, ep.stats.packets_acked, interval, None),
                    receive_line("S->M", side.received, reverse_meter, interval, side.latency),
                ]
            )

        tasks = [_send_loop(ep, side, args.rate, args.size, until, master=True)]
        if display is not None:
            tasks.append(_every_second(until, show))
        await asyncio.gather(*tasks)
        elapsed = monotonic() - start
        return {
            "command": "master",
            "duration_s": round(elapsed, 3),
            **_settings(args, ep),
            "master_to_slave": direction_summary(ep.stats, None, elapsed),
            "slave_to_master": {
                "packets_received": side.received,
                "mean_rate": round(side.received / elapsed, 2) if elapsed else 0.0,
                "latency_ms": side.latency.summary_ms(),
            },
            "close": None if not ep.is_closed else "closed by the slave",
        }


async def _serve_one(ep: Endpoint, side: Side, args: argparse.Namespace, until: float) -> None:
    await _send_loop(ep, side, args.rate, args.size, until, master=False)


async def run_slave(args: argparse.Namespace) -> dict[str, Any]:
    until = math.inf if args.duration is None else monotonic() + args.duration
    sides: dict[int, Side] = {}
    _, sm_spec = _directions(args)
    async with await listen(
        args.host,
        args.port,
        config=_config(args),
        max_peers=args.max_peers,
        netem=sm_spec,
        netem_seed=_seed(args, 1),
    ) as server:
        display = None if args.json else LiveDisplay()
        if display is not None:
            display.message(f"tdtp slave listening on {args.host}:{server.port}")
        tasks: set[asyncio.Task[None]] = set()
        acceptor = asyncio.create_task(_accept_loop(server, sides, args, until, tasks))
        try:
            await _every_second(until, lambda interval: _show_slave(display, server, sides))
        finally:
            acceptor.cancel()
            for task in tasks:
                task.cancel()
        return {
            "command": "slave",
            "masters_served": server.stats.peers_accepted,
            "masters_refused": server.stats.peers_refused,
            "datagrams_unattached": server.stats.datagrams_unattached,
        }


async def _accept_loop(
    server: Server,
    sides: dict[int, Side],
    args: argparse.Namespace,
    until: float,
    tasks: set[asyncio.Task[None]],
) -> None:
    async for ep in server:
        side = Side(f"master {ep.peer}")
        sides[id(ep)] = side
        ep.set_data_callback(side.on_data)
        task = asyncio.create_task(_serve_one(ep, side, args, until))
        tasks.add(task)
        task.add_done_callback(tasks.discard)


def _show_slave(display: LiveDisplay | None, server: Server, sides: dict[int, Side]) -> None:
    if display is None:
        return
    lines = [f"{len(server.endpoints)} master(s) connected"]
    for ep in server.endpoints:
        side = sides.get(id(ep))
        stats = ep.stats
        lines.append(
            f"  {ep.peer}: received {side.received if side else 0} samples, "
            f"sent {stats.sent.data_packets}, srtt {stats.srtt * 1e3:.3f} ms, "
            f"lost {stats.packets_lost}, allowed {stats.rate:.0f}/s"
        )
    display.update(lines)


async def run_relay(args: argparse.Namespace) -> dict[str, Any]:
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
            f"relaying {relay.address[0]}:{relay.address[1]} -> {args.forward[0]}:{args.forward[1]}"
            f" with forward '{args.spec}', return '{args.return_spec or args.spec}'"
        )

    def show(interval: float) -> None:
        if display is None:
            return
        fwd, back = relay.forward.link.stats, relay.back.link.stats
        display.update(
            [
                f"clients {relay.stats.clients}  forwarded {relay.stats.forwarded}"
                f"  returned {relay.stats.returned}",
                f"  forward: {_link_line(fwd)}",
                f"  return:  {_link_line(back)}",
            ]
        )

    try:
        until = math.inf if args.duration is None else monotonic() + args.duration
        await _every_second(until, show)
    finally:
        await relay.close()
    return {
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
            raise SystemExit("uvloop is not installed: pip install 'tdtp[fast]'") from None
        return None
    factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
    return factory


def main(argv: Sequence[str] | None = None) -> int:
    arguments = list(sys.argv[1:] if argv is None else argv)
    if arguments[:1] == ["simulate"]:
        # Its own parser (tdtp.sim.cli); the subcommand below only lists it in --help.
        return simulate_main(arguments[1:])
    if arguments[:1] == ["bandwidth"]:
        return bandwidth_main(arguments[1:])
    args = build_parser().parse_args(arguments)
    if getattr(args, "size", SAMPLE_SIZE) < SAMPLE_SIZE:
        print(f"tdtp: --size must be at least {SAMPLE_SIZE} bytes", file=sys.stderr)
        return 2
    runners: dict[str, Callable[[argparse.Namespace], Coroutine[Any, Any, dict[str, Any]]]] = {
        "demo": run_demo,
        "master": run_master,
        "slave": run_slave,
        "netem-relay": run_relay,
    }
    try:
        with asyncio.Runner(loop_factory=_loop_factory(args.loop)) as runner:
            summary = runner.run(runners[args.command](args))
    except ConnectError as exc:
        print(f"tdtp: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(_demo_table(summary) if args.command == "demo" else json.dumps(summary, indent=2))
    return 0


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
