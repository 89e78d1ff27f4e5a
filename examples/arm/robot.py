"""The robot of a 7-joint arm teleoperation: a keyed TDTP slave that follows one operator.

    tdtp keygen arm.keys --name operator-1
    python examples/arm/robot.py --key-file arm.keys --port 7000
    python examples/arm/operator_station.py 127.0.0.1:7000 --key-file arm.keys   # another terminal

Every millisecond the robot takes the newest joint command (typed with SampleCodec), moves its joints
toward it as the mode allows (``position``: stiffly; ``compliant``: slowly) and answers with its joint
state. It applies the control channel's messages in the order sent: ``ESTOP`` freezes the joints and
makes it ignore commands until ``RESUME``; ``MODE ...`` switches the mode; it answers each with
``DONE ...``. When the watchdog finds the operator silent (100 ms without a datagram) the joints hold
where they are until it is heard again. One operator commands the arm at a time (``exclusive=True``).
Ctrl-C (or SIGTERM) stops it; ``--json FILE`` writes what the run did there.

Listening on 0.0.0.0 lets operators on other machines in (the default, 127.0.0.1, only this one).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
from dataclasses import dataclass, field

from arm_messages import COMMAND, ESTOP, JOINTS, MODES, RESUME, STATE, JointState, done_message

import tdtp

MAX_SPEED = {"position": 2.0, "compliant": 0.3}
"""Joint speed limits per mode, radians per second."""


@dataclass
class ArmRecord:
    """What the run did, for the summary (``--json``)."""

    sessions: int = 0
    commands_received: int = 0
    commands_applied: int = 0
    ignored_while_stopped: int = 0
    ignored_while_holding: int = 0
    holds: int = 0
    control: list[str] = field(default_factory=list)
    """The control messages applied, in the order they were applied."""
    stops: list[list[list[float]]] = field(default_factory=list)
    """Per emergency stop: the joints when it began and when it ended (the same: nothing moved)."""
    q: list[float] = field(default_factory=lambda: [0.0] * JOINTS)


class Arm:
    """A simulated arm: joint angles that move toward a target at the mode's speed limit."""

    def __init__(self, record: ArmRecord) -> None:
        self.record = record
        self.q = [0.0] * JOINTS
        self.target = [0.0] * JOINTS
        self.mode = "position"
        self.stopped = False
        self.holding = False

    def command(self, target: tuple[float, ...]) -> None:
        """A new command: followed unless stopped or holding."""
        record = self.record
        if self.stopped:
            record.ignored_while_stopped += 1
        elif self.holding:
            record.ignored_while_holding += 1
        else:
            self.target = list(target)
            record.commands_applied += 1

    def step(self, dt: float) -> None:
        if self.stopped or self.holding:
            return  # the joints stay where they are
        limit = MAX_SPEED[self.mode] * dt
        self.q = [
            q + max(-limit, min(limit, t - q)) for q, t in zip(self.q, self.target, strict=True)
        ]
        self.record.q = self.rounded()

    def rounded(self) -> list[float]:
        return [round(q, 6) for q in self.q]

    def control(self, message: bytes) -> bool:
        """Apply a control message; whether it was understood."""
        if message == ESTOP:
            self.stopped = True
            self.target = list(self.q)  # resume from where it stopped, not toward an old target
            self.record.stops.append([self.rounded()])
        elif message == RESUME:
            self.stopped = False
            if self.record.stops and len(self.record.stops[-1]) == 1:
                self.record.stops[-1].append(self.rounded())
        elif message.startswith(b"MODE ") and message[5:].decode(errors="replace") in MODES:
            self.mode = message[5:].decode()
        else:
            return False
        self.record.control.append(message.decode(errors="replace"))
        return True

    def state(self, now: float) -> bytes:
        return STATE.encode(
            JointState(now, tuple(self.q), MODES.index(self.mode), self.stopped, self.holding)
        )


async def serve(ep: tdtp.Endpoint, arm: Arm, rate: float) -> None:
    """One operator's session: commands in, state out, control messages applied in order."""
    record = arm.record
    record.sessions += 1
    last_seq = -1

    def on_control(event: tdtp.ControlReceived) -> None:
        if arm.control(event.payload):
            ep.send_control(done_message(event.payload))

    def on_watchdog(event: tdtp.PeerSilent | tdtp.PeerResumed) -> None:
        arm.holding = isinstance(event, tdtp.PeerSilent)
        record.holds += arm.holding
        print("operator silent: holding" if arm.holding else "operator back: following", flush=True)

    ep.set_control_callback(on_control)
    ep.set_watchdog_callback(on_watchdog)
    last = tdtp.monotonic()
    async for _ in tdtp.Ticker(rate):
        if ep.is_closed:
            break
        now = tdtp.monotonic()
        arm.step(now - last)  # the joints move for the time that really passed
        last = now
        sample = ep.latest()
        if sample is not None and sample.seq != last_seq:
            last_seq = sample.seq
            try:
                command = COMMAND.decode(sample.payload)
            except tdtp.InvalidArgumentError:
                continue  # not a joint command: ignored, never applied
            record.commands_received += 1
            arm.command(command.q)
        ep.send(arm.state(now))
    arm.holding = False


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: all)")
    parser.add_argument("--port", type=int, default=7000)
    parser.add_argument("--key-file", required=True, help="the operators' keys (tdtp keygen)")
    parser.add_argument("--rate", type=float, default=1000.0)
    parser.add_argument("--json", help="write what the run did to this file at the end")
    args = parser.parse_args()
    record = ArmRecord()
    arm = Arm(record)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    keys = tdtp.load_keys(args.key_file)
    async with tdtp.listen(args.host, args.port, keys=keys, exclusive=True) as server:
        print(f"robot listening on {args.host}:{server.port}", flush=True)

        async def accept() -> None:
            async with asyncio.TaskGroup() as group:
                async for ep in server:
                    key = ep.connection.key
                    print(f"operator {key.name if key else '?'} connected", flush=True)
                    group.create_task(serve(ep, arm, args.rate))

        task = asyncio.create_task(accept())
        await stop.wait()
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    if args.json:
        with open(args.json, "w", encoding="utf-8") as out:
            json.dump(record.__dict__, out, indent=2)
    print("robot stopped", flush=True)


if __name__ == "__main__":
    asyncio.run(main())
