"""The operator's station of a 7-joint arm teleoperation: a keyed TDTP master with a live status line.

    python examples/arm/operator_station.py 127.0.0.1:7000 --key-file arm.keys --seconds 30 \\
        --mode-at 5=compliant --estop-at 10 --resume-at 12

A stand-in for the operator's hand moves the seven joints along slow sine waves; every millisecond
the joint command is offered to a perceptual deadband, and only a change the robot would notice is
sent (typed with SampleCodec). Mode changes, the emergency stop and the resume go on the session's
reliable control channel, which delivers them exactly once and in order, however the network
behaves; the robot confirms each. The session reconnects on its own when the robot restarts or goes
quiet for 3 s. The status line shows the link (and the watchdog's verdict), the round trip, what the
deadband saved, the robot's mode and state, and the tracking error. Ctrl-C (or SIGTERM) stops it;
``--json FILE`` writes what the run did there.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import signal
import sys
from dataclasses import dataclass, field

from arm_messages import (
    COMMAND,
    ESTOP,
    JOINTS,
    MODES,
    RESUME,
    STATE,
    JointCommand,
    mode_message,
)

import tdtp
from tdtp.teleop.deadband import DeadbandConfig, DeadbandSender


def hand(t: float) -> tuple[float, ...]:
    """The operator's hand, as joint angles: slow sine waves of different periods (radians)."""
    return tuple(0.6 * math.sin(2 * math.pi * t / (4.0 + joint)) for joint in range(JOINTS))


@dataclass
class OperatorRecord:
    """What the run did, for the summary (``--json``)."""

    commands_offered: int = 0
    commands_sent: int = 0
    states_received: int = 0
    control_sent: list[str] = field(default_factory=list)
    control_done: list[str] = field(default_factory=list)
    """The robot's confirmations, in the order they came."""
    silences: int = 0
    reconnects: int = 0
    tracking_error: float = math.nan
    """The largest joint error (command minus robot) in the last state received, radians."""


def parse_script(args: argparse.Namespace) -> list[tuple[float, bytes]]:
    """The scripted control messages, by time from the start."""
    events = [(t, ESTOP) for t in args.estop_at] + [(t, RESUME) for t in args.resume_at]
    for item in args.mode_at:
        at, _, mode = item.partition("=")
        if mode not in MODES:
            raise SystemExit(f"--mode-at takes SECONDS=MODE with MODE one of {', '.join(MODES)}")
        events.append((float(at), mode_message(mode)))
    return sorted(events, key=lambda event: event[0])


def status(ep: tdtp.Endpoint, record: OperatorRecord, robot: str, saving: float) -> str:
    if ep.reconnects.reopening:
        link = "RECONNECTING"
    elif ep.peer_silent:
        link = "ROBOT SILENT"
    else:
        link = "ok"
    return (
        f"link {link:<12} rtt {ep.stats.srtt * 1e3:6.2f} ms  deadband saved {saving:5.1%}  "
        f"robot {robot:<24} error {record.tracking_error:5.3f} rad  "
        f"reconnects {ep.reconnects.count}"
    )


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("robot", help="HOST:PORT")
    parser.add_argument("--key-file", required=True, help="this operator's key (tdtp keygen)")
    parser.add_argument("--key-name", help="which key of the file (default: the first)")
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--deadband", type=float, default=0.02, help="Weber fraction k")
    parser.add_argument("--mode-at", action="append", default=[], metavar="SECONDS=MODE")
    parser.add_argument("--estop-at", action="append", default=[], type=float, metavar="SECONDS")
    parser.add_argument("--resume-at", action="append", default=[], type=float, metavar="SECONDS")
    parser.add_argument("--json", help="write what the run did to this file at the end")
    args = parser.parse_args()
    script = parse_script(args)
    host, _, port = args.robot.rpartition(":")
    record = OperatorRecord()
    robot = "-"
    deadband = DeadbandSender(
        groups=[range(JOINTS)],  # the seven joints together, as one vector
        config=DeadbandConfig(k=args.deadband, min_threshold=0.002, max_hold=0.05),
    )

    def on_control(event: tdtp.ControlReceived) -> None:
        record.control_done.append(event.payload.decode(errors="replace"))

    def on_watchdog(event: tdtp.PeerSilent | tdtp.PeerResumed) -> None:
        record.silences += isinstance(event, tdtp.PeerSilent)

    stopping = asyncio.Event()  # Ctrl-C or SIGTERM: stop, then say what the run did
    for sig in (signal.SIGINT, signal.SIGTERM):
        asyncio.get_running_loop().add_signal_handler(sig, stopping.set)
    key = tdtp.load_key(args.key_file, name=args.key_name)
    policy = tdtp.ReconnectPolicy(backoff=0.2, after_silence=3.0)
    live = sys.stdout.isatty()
    async with tdtp.connect(
        host.strip("[]"), int(port), key=key, reconnect=policy, on_watchdog=on_watchdog
    ) as ep:
        ep.set_control_callback(on_control)
        print(f"connected to the robot at {ep.peer}", flush=True)
        start = last_print = tdtp.monotonic()
        async for _ in tdtp.Ticker(args.rate):
            now = tdtp.monotonic()
            t = now - start
            if t >= args.seconds or stopping.is_set():
                break
            command = JointCommand(now, hand(t), 128)
            record.commands_offered += 1
            try:
                while script and script[0][0] <= t:
                    message = script.pop(0)[1]
                    ep.send_control(message)
                    record.control_sent.append(message.decode())
                if deadband.offer(command.q, now=now):  # sent only when the change would be felt
                    ep.send(COMMAND.encode(command))
                    record.commands_sent += 1
            except tdtp.EndpointClosedError as exc:  # the robot closed the session for good
                print(f"\nthe robot ended the session: {exc}", flush=True)
                break
            sample = ep.latest()
            if sample is not None:
                state = STATE.decode(sample.payload)
                record.states_received = ep.stats.samples_delivered
                record.tracking_error = max(
                    abs(a - b) for a, b in zip(command.q, state.q, strict=True)
                )
                flags = "E-STOP" if state.stopped else "holding" if state.holding else "moving"
                robot = f"{MODES[state.mode]}, {flags}"
            if now - last_print >= (0.1 if live else 1.0):
                line = status(ep, record, robot, deadband.stats.saving)
                print(f"\r{line}" if live else line, end="" if live else "\n", flush=True)
                last_print = now
        with contextlib.suppress(TimeoutError):  # the robot's last confirmations, 5 s at most
            async with asyncio.timeout(5.0):
                while len(record.control_done) < len(record.control_sent) and not ep.is_closed:
                    await asyncio.sleep(0.01)
        record.reconnects = ep.reconnects.count
    if live:
        print()
    print(
        f"sent {record.commands_sent} of {record.commands_offered} commands "
        f"({deadband.stats.saving:.1%} saved by the deadband), control {record.control_sent}, "
        f"confirmed {record.control_done}, reconnects {record.reconnects}",
        flush=True,
    )
    if args.json:
        with open(args.json, "w", encoding="utf-8") as out:
            json.dump(record.__dict__, out, indent=2)


if __name__ == "__main__":
    asyncio.run(main())
