"""The options of ``tdtp demo``, ``tdtp master``, ``tdtp slave`` and ``tdtp netem-relay``: the parser, the
argument types that turn a bad value into one line of usage error, and the configuration they make."""

from __future__ import annotations

import argparse
from collections.abc import Callable

from tdtp import __version__
from tdtp.cli.control_counter import MAX_CONTROL_RATE
from tdtp.cli.keys import (
    add_key_arguments,
)
from tdtp.cli.parser import CommandParser
from tdtp.config import MAX_PAYLOAD, AckMode, ConnectionConfig, MultipathConfig
from tdtp.control.fixed import FixedConfig
from tdtp.control.registry import DEFAULT_CONTROLLER, available_controllers
from tdtp.errors import (
    InvalidArgumentError,
)
from tdtp.netem import NetemSpec, parse_netem
from tdtp.netem.spec import MAX_SEED
from tdtp.rendezvous.settings import Rendezvous
from tdtp.teleop.deadband import DeadbandConfig, DeadbandSender
from tdtp.teleop.haptic_sample import SAMPLE_SIZE
from tdtp.wire.header import HEADER_SIZE

MAX_RATE = 100_000.0
"""The highest --rate: the rate controllers' ceiling (and far beyond any supermedia loop)."""
MAX_SIZE = MAX_PAYLOAD
"""The largest --size: the largest payload a session may carry (a keyed one has room for its tag)."""
DEFAULT_MAX_PAYLOAD = ConnectionConfig().max_payload
DEFAULT_CONTROL_MAX_RATE = ConnectionConfig().control_max_rate


class UsageError(Exception):
    """A command-line value the library refused; printed as one line, exit status 2."""


def host_port(text: str, *, allow_zero: bool = False) -> tuple[str, int]:
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
    return host_port(text, allow_zero=True)


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


def _control_rate(text: str) -> float:
    value = _number(text)
    if not (0.0 < value <= MAX_CONTROL_RATE):  # also refuses nan and inf
        raise argparse.ArgumentTypeError(
            f"must be a number of control messages per second above 0 and at most "
            f"{MAX_CONTROL_RATE:g}, got {text}"
        )
    return value


def _weber_fraction(text: str) -> float:
    value = _number(text)
    if not 0.0 < value < 10.0:
        raise argparse.ArgumentTypeError(f"must be a fraction above 0 and below 10, got {text}")
    return value


DEADBAND_FLOORS = {"position": 0.0005, "force": 0.05}
"""The deadband's absolute thresholds near zero: half a millimetre, 0.05 N."""


def side_deadband(args: argparse.Namespace, *, master: bool) -> DeadbandSender | None:
    """The deadband ``--deadband K`` asks for on one side (its position or its force), or ``None``."""
    k: float | None = getattr(args, "deadband", None)
    if k is None:
        return None
    floor = DEADBAND_FLOORS["position" if master else "force"]
    return DeadbandSender(groups=[(0, 1, 2)], config=DeadbandConfig(k=k, min_threshold=floor))


def _positive_seconds(text: str) -> float:
    value = _number(text)
    if not (0.0 < value < float("inf")):  # also refuses nan
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def _add_reconnect_arguments(parser: argparse.ArgumentParser, peer: str) -> None:
    parser.add_argument(
        "--reconnect",
        action=argparse.BooleanOptionalAction,
        default=True,
        help=f"when dialing: open a new session when the {peer} restarts (its CLOSE says "
        f"RESTARTING, or a RESET says it restarted), evicts this end (after a back-off), the "
        f"session idles out, or the {peer} is silent for --reconnect-after seconds (default: on)",
    )
    parser.add_argument(
        "--reconnect-after",
        type=_positive_seconds,
        default=3.0,
        metavar="SECONDS",
        help=f"silence from the {peer} after which a dialer that reconnects opens a new session (3)",
    )


def _listen_address(text: str) -> tuple[str, int]:
    """``--listen``: ``PORT``, ``:PORT`` or ``HOST:PORT`` (port 0 picks a free one)."""
    if text.isdigit():
        text = ":" + text
    return _host_port_or_port(text)


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
    common.add_argument(
        "--duration", type=_duration, help="seconds to run (demo: 5; master, slave: until Ctrl-C)"
    )
    common.add_argument(
        "--controller",
        default=DEFAULT_CONTROLLER,
        choices=available_controllers(),
        help=f"rate control ({DEFAULT_CONTROLLER})",
    )
    common.add_argument(
        "--deadband",
        type=_weber_fraction,
        metavar="K",
        help="perceptual deadband: send a sample only when it changed by more than K times its "
        "magnitude (e.g. 0.1; the master's position, the slave's force; a heartbeat every 0.1 s)",
    )
    common.add_argument(
        "--control-rate",
        type=_control_rate,
        metavar="HZ",
        help="also send a counter HZ times a second on the reliable control channel and check "
        "that the peer's arrives in order (control_messages in --json)",
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
    meet = common.add_argument_group(
        "rendezvous", "meet the peer through a relay (tdtp relay) when both sit behind NATs"
    )
    meet.add_argument(
        "--rendezvous",
        type=host_port,
        metavar="HOST:PORT",
        help="the relay to meet at: the session runs on a direct path when the NATs let one "
        "through, else through the relay (docs/NAT.md)",
    )
    meet.add_argument(
        "--rendezvous-name",
        metavar="NAME",
        help="what both sides meet under (keyed: derived from the key unless given; unkeyed: "
        "required, and anyone who knows it can meet you there)",
    )
    common.add_argument(
        "--pcap",
        metavar="FILE",
        help="write what the socket sends and receives to FILE, a pcap for Wireshark "
        "(the demo captures the master's socket; tools/wireshark/tdtp.lua decodes it)",
    )
    common.add_argument(
        "--loop",
        choices=("auto", "uvloop", "asyncio"),
        default="auto",
        help="event loop (auto: uvloop when installed)",
    )
    common.add_argument(
        "--timer",
        choices=("auto", "timerfd", "call_at"),
        default="auto",
        help="pacing timer (auto: timerfd on Linux)",
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
    common.add_argument(
        "--multipath",
        choices=("redundant", "adaptive"),
        help="a session over several paths (master: with --local-address; demo: with --path; "
        "slave: how it sends in such sessions): every sample on every path, or on the best one "
        "while it behaves (default redundant once there are paths)",
    )

    parser = CommandParser(
        prog="tdtp",
        description="TDTP teleoperation transport: master, slave and demo.",
        epilog="Exit status: 0 done, 1 session failed, 2 usage error, 130 interrupted (Ctrl-C), "
        "143 stopped (SIGTERM).",
    )
    parser.add_argument("--version", action="version", version=f"tdtp {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser(
        "demo", parents=[common], help="master and slave on localhost, live statistics"
    )
    demo.set_defaults(duration=None)
    demo.add_argument(
        "--path",
        type=_netem_spec,
        action="append",
        metavar="NETEM",
        help="add a path with its own impairment, both ways (netem syntax; repeat for each path, "
        'e.g. --path "delay 20ms loss 2%%" --path "delay 35ms"): a multipath session',
    )
    add_key_arguments(demo, demo=True)
    slave = commands.add_parser(
        "slave", parents=[common], help="serve masters on a UDP port, or dial one (--connect)"
    )
    slave.add_argument("--host", default="0.0.0.0", help="address to bind (0.0.0.0)")
    where = slave.add_mutually_exclusive_group()
    where.add_argument("--port", type=_integer(0, 65535), help="UDP port (0: any free port)")
    where.add_argument(
        "--connect",
        type=host_port,
        metavar="HOST:PORT",
        help="dial the master listening there (tdtp master --listen PORT) instead of listening: "
        "a robot behind a NAT or firewall reaches its operator without a port forward",
    )
    _add_reconnect_arguments(slave, "master")
    slave.add_argument(
        "--max-peers", type=_integer(1, 1 << 20), default=256, help="masters served at once (256)"
    )
    slave.add_argument(
        "--exclusive",
        action="store_true",
        help="at most one master commands this slave; another one is refused (REJECT IN_USE) "
        "unless the one in control is silent for --takeover-after watchdog periods, or is keyed "
        "and connects with --takeover",
    )
    slave.add_argument(
        "--takeover-after",
        type=_integer(1, 1000),
        default=3,
        metavar="N",
        help="--exclusive: watchdog periods (--silence-timeout each) a master must be silent "
        "before another one takes control (3)",
    )
    slave.add_argument(
        "--on-stop",
        choices=("restart", "shutdown"),
        default="restart",
        help="what the CLOSE tells the masters when Ctrl-C or SIGTERM stops this slave: restart "
        "(it will be back soon: they reopen at once; the default, since a service restart looks "
        "just like this) or shutdown (it is gone for good: they stop); the end of --duration "
        "always says shutdown",
    )
    add_key_arguments(slave)
    master = commands.add_parser(
        "master", parents=[common], help="connect to a slave, or let one dial in (--listen)"
    )
    master.add_argument(
        "address",
        type=host_port,
        nargs="?",
        help="the slave, HOST:PORT (or --listen, --rendezvous)",
    )
    master.add_argument(
        "--listen",
        type=_listen_address,
        metavar="[HOST:]PORT",
        help="listen there for a slave that dials this master (tdtp slave --connect) instead of "
        "dialing one; a bare PORT listens on every interface",
    )
    master.add_argument(
        "--local-address",
        action="append",
        metavar="ADDR",
        help="open a path from this local address (IP, IP:PORT, %%IFACE or IP%%IFACE, optionally "
        "=HOST:PORT for another of the slave's addresses); repeat for each path, the first "
        "carries the session's opening: a multipath session",
    )
    _add_reconnect_arguments(master, "slave")
    master.add_argument(
        "--takeover",
        action="store_true",
        help="take control of an exclusive slave at once, ending the session of the master "
        "that has it (needs --key-file)",
    )
    add_key_arguments(master)
    rendezvous_relay = commands.add_parser(
        "relay",
        help="a rendezvous relay for masters and slaves behind NATs (--rendezvous)",
        description="Meet masters and slaves that register under the same name, tell them each "
        "other's addresses to punch through their NATs, and relay their datagrams while they "
        "cannot (docs/NAT.md).",
    )
    rendezvous_relay.add_argument("--host", default="0.0.0.0", help="address to bind (0.0.0.0)")
    rendezvous_relay.add_argument(
        "--port", type=_integer(0, 65535), required=True, help="UDP port (0: any free port)"
    )
    rendezvous_relay.add_argument("--duration", type=_duration, help="seconds to run")
    rendezvous_relay.add_argument(
        "--max-registrations",
        type=_integer(2, 1 << 20),
        default=4096,
        help="registrations held at once, two per rendezvous (4096)",
    )
    rendezvous_relay.add_argument(
        "--json", action="store_true", help="print one JSON summary at the end"
    )
    rendezvous_relay.add_argument("--loop", choices=("auto", "uvloop", "asyncio"), default="auto")
    relay = commands.add_parser(
        "netem-relay",
        help="an impairing UDP relay for any application",
        description="Relay UDP datagrams from --listen to --forward through emulated links.",
    )
    relay.add_argument("spec", type=_netem_spec, help='netem syntax, e.g. "delay 30ms loss 1%%"')
    relay.add_argument(
        "--listen", type=_host_port_or_port, required=True, help="[HOST]:PORT to listen on"
    )
    relay.add_argument("--forward", type=host_port, required=True, help="HOST:PORT to relay to")
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


def session_config(args: argparse.Namespace) -> ConnectionConfig:
    takeover = bool(getattr(args, "takeover", False))
    if takeover and getattr(args, "key_file", None) is None:
        raise UsageError(
            "--takeover needs --key-file: only a keyed master may take an exclusive slave over "
            "(unkeyed, anyone could)"
        )
    controller_config: object | None = None
    control_rate: float | None = getattr(args, "control_rate", None)
    control_max_rate = DEFAULT_CONTROL_MAX_RATE
    if control_rate is not None:  # room for retransmissions beside the counter
        control_max_rate = max(control_max_rate, 2.0 * control_rate)
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
            takeover=takeover,
            control_max_rate=control_max_rate,
            multipath=multipath_config(args),
        )
    except InvalidArgumentError as exc:
        field = str(exc).split(" ", 1)[0]
        option = _OPTION_OF_FIELD.get(field, "--" + field.replace("_", "-"))
        raise UsageError(f"{option}: {exc}") from None


def multipath_config(args: argparse.Namespace) -> MultipathConfig | None:
    """A multipath session's config when the command line asks for one (``--multipath``,
    ``--path`` or ``--local-address``), else ``None``."""
    scheduler = getattr(args, "multipath", None)
    paths = getattr(args, "path", None)
    local = getattr(args, "local_address", None)
    if scheduler is None and not paths and not local:
        return None
    if args.command == "demo":
        if not paths:
            raise UsageError("--multipath in the demo needs its paths: --path NETEM for each one")
        if any(getattr(args, name, None) is not None for name in ("netem", "netem_ms", "netem_sm")):
            raise UsageError("--path gives each path its impairment: drop --netem/--netem-ms/-sm")
        if args.pcap is not None:
            raise UsageError("--pcap captures one socket: it is not available with --path")
    if args.command == "master" and local and (args.netem or args.netem_ms or args.pcap):
        raise UsageError(
            "--local-address opens one socket per path: --netem, --netem-ms and --pcap work "
            "on one socket only; drop them"
        )
    return MultipathConfig(scheduler=scheduler or "redundant")


_OPTION_OF_FIELD = {"max_payload": "--size", "min_peer_payload": "--size"}
"""Configuration fields set from an option of another name."""


def netem_directions(args: argparse.Namespace) -> tuple[NetemSpec | None, NetemSpec | None]:
    """The impairment master -> slave and slave -> master."""
    both: NetemSpec | None = getattr(args, "netem", None)
    ms = getattr(args, "netem_ms", None) or both
    sm = getattr(args, "netem_sm", None) or both
    return ms, sm


def netem_seed(args: argparse.Namespace, offset: int) -> int | None:
    seed: int | None = getattr(args, "netem_seed", None)
    return None if seed is None else seed + offset


def rendezvous_settings(args: argparse.Namespace) -> Rendezvous | None:
    """The ``--rendezvous`` (and ``--rendezvous-name``) of a run, or None."""
    where: tuple[str, int] | None = getattr(args, "rendezvous", None)
    name: str | None = getattr(args, "rendezvous_name", None)
    if where is None:
        if name is not None:
            raise UsageError("--rendezvous-name needs --rendezvous HOST:PORT")
        return None
    try:
        return Rendezvous(where[0], where[1], name=name)
    except InvalidArgumentError as exc:
        raise UsageError(f"--rendezvous: {exc}") from None
