"""``tdtp relay --port N``: a rendezvous relay for masters and slaves behind NATs (docs/NAT.md)."""

from __future__ import annotations

import argparse
import math
import os
import resource
import sys
from dataclasses import asdict

from tdtp.aio.endpoint import format_address
from tdtp.aio.rendezvous_relay import relay
from tdtp.aio.timer import monotonic
from tdtp.cli.live_stats import LiveDisplay
from tdtp.cli.outcome import Outcome
from tdtp.cli.session_tasks import every_second
from tdtp.rendezvous.settings import RelayConfig


async def run_rendezvous_relay(args: argparse.Namespace, outcome: Outcome) -> None:
    config = RelayConfig(max_registrations=args.max_registrations)
    start = monotonic()
    cpu_start = _cpu()
    async with relay(args.host, args.port, config=config) as running:
        display = None if args.json else LiveDisplay()
        if display is not None:
            display.message(f"tdtp relay on {format_address(running.address)}")
        else:
            # Machine-readable readiness for scripts: the bound port, on stderr.
            print(
                f"tdtp relay listening on {format_address(running.address)}",
                file=sys.stderr,
                flush=True,
            )

        def show(interval: float) -> None:
            if display is None:
                return
            stats = running.stats
            display.update(
                [
                    f"registrations {stats.registrations}  paired {stats.rendezvous_paired}"
                    f"  forwarded {stats.forwarded}  over rate {stats.forward_dropped}"
                    f"  cookies {stats.cookies_sent}  unknown sources {stats.unknown_sent}"
                ]
            )

        try:
            until = math.inf if args.duration is None else start + args.duration
            await every_second(until, show)
        finally:
            elapsed = monotonic() - start
            outcome.summary = {
                "command": "relay",
                "address": format_address(running.address),
                "duration_s": round(elapsed, 3),
                "cpu_s": round(_cpu() - cpu_start, 4),
                "pid": os.getpid(),
                "stats": asdict(running.stats),
            }


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime
