"""``tdtp netem-relay``: a UDP relay that impairs what passes through it, both ways, with netem's options."""

from __future__ import annotations

import argparse
import math
from dataclasses import asdict
from typing import Any

from tdtp.aio.endpoint import format_address
from tdtp.aio.relay import start_relay
from tdtp.aio.timer import monotonic
from tdtp.cli.live_stats import (
    LiveDisplay,
)
from tdtp.cli.outcome import Outcome
from tdtp.cli.session_tasks import every_second


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
        await every_second(until, show)
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
