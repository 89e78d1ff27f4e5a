"""How precisely can an asyncio loop pace a 1 kHz stream? The figures behind tdtp's timer choice.

Usage: ``python benchmarks/pacing.py [--seconds 5] [--json] [--only VARIANT ...]``
(variants: ``timerfd``, ``call_at``, ``call_at-spin``, ``naive``)

Each variant runs a loop that "departs" once per period on an absolute schedule
(``deadline_i = start + i * period``, i.e. ``deadline += period``, never "now + period", so lateness
never accumulates into drift) for ``--seconds`` and reports:

- schedule deviation: ``|departure_i - deadline_i|`` (us), p50/p99/max, and how many departures were
  *early* (before their deadline);
- interval deviation: ``|(departure_i - departure_{i-1}) - period|`` (us), p99;
- the achieved rate (departures per second between the first and the last);
- CPU: user+sys time from ``getrusage(RUSAGE_SELF)`` over wall time, in % of one core.

Variants: tdtp's :class:`~tdtp.aio.timer.TimerfdTimer`, :class:`~tdtp.aio.timer.CallAtTimer` with
its default (no spin) and with the precise 1.2 ms spin window, and the baseline, naive
``loop.call_at`` with absolute deadlines converted to ``loop.time()`` (which is ``time.monotonic()``
on the stock loop), each on the stock asyncio loop and on uvloop. Variants run one after the other
in this process; nothing else runs meanwhile, so the process's CPU time is the pacer's.

Targets (printed beside the figures): p99 schedule deviation <= 150 us at <= 10 % CPU, and a
rate of 1000 +- 0.1 %.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.metadata
import itertools
import json
import math
import os
import platform
import resource
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout, uninstalled

from tdtp.aio.timer import (
    PRECISE_SPIN_WINDOW,
    CallAtTimer,
    DeadlineTimer,
    TimerfdTimer,
    monotonic,
    timerfd_unavailable_reason,
)

TARGET_P99_US = 150.0
TARGET_CPU_PERCENT = 10.0
TARGET_RATE_TOLERANCE = 0.001  # +- 0.1 %
LEAD_IN = 0.1  # seconds between starting the loop and the first deadline

LoopFactory = Callable[[], asyncio.AbstractEventLoop]


@dataclass
class Result:
    variant: str
    loop: str
    departures: int
    dev_p50_us: float
    dev_p99_us: float
    dev_max_us: float
    early: int
    interval_dev_p99_us: float
    rate_hz: float
    cpu_percent: float
    meets_target: bool


def percentile(sorted_values: list[float], q: float) -> float:
    """Nearest-rank percentile of an ascending list."""
    rank = max(1, math.ceil(q * len(sorted_values)))
    return sorted_values[rank - 1]


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


class Pacer:
    """Records departures at ``start + i * period``; ``schedule(i)`` arms the chosen mechanism."""

    def __init__(self, loop: asyncio.AbstractEventLoop, count: int, period: float) -> None:
        self.loop = loop
        self.count = count
        self.period = period
        self.departures = [0.0] * count
        self.index = 0
        self.start = monotonic() + LEAD_IN
        self.done: asyncio.Future[None] = loop.create_future()
        self.cpu = [0.0, 0.0]
        self.schedule: Callable[[float], None] = lambda deadline: None
        self.stop: Callable[[], None] = lambda: None

    def depart(self) -> None:
        """The paced action: runs once per period (here it only records the time)."""
        now = monotonic()
        i = self.index
        self.departures[i] = now
        if i == 0:
            self.cpu[0] = cpu_seconds()
        i += 1
        self.index = i
        if i == self.count:
            self.cpu[1] = cpu_seconds()
            self.stop()
            self.done.set_result(None)
        else:
            self.schedule(self.start + i * self.period)


def with_timer(
    make: Callable[[asyncio.AbstractEventLoop, Callable[[], None]], DeadlineTimer],
) -> Callable[[Pacer], None]:
    def install(pacer: Pacer) -> None:
        timer = make(pacer.loop, pacer.depart)
        pacer.schedule = timer.arm
        pacer.stop = timer.close

    return install


def with_naive_call_at(pacer: Pacer) -> None:
    loop = pacer.loop

    def schedule(deadline: float) -> None:
        loop.call_at(deadline - monotonic() + loop.time(), pacer.depart)

    pacer.schedule = schedule


# --only key -> (label in the table, how to pace)
VARIANTS: dict[str, tuple[str, Callable[[Pacer], None]]] = {
    "timerfd": ("TimerfdTimer", with_timer(TimerfdTimer)),
    "call_at": ("CallAtTimer (default: no spin)", with_timer(CallAtTimer)),
    "call_at-spin": (
        "CallAtTimer, spin 1.2 ms",
        with_timer(
            lambda loop, callback: CallAtTimer(loop, callback, spin_window=PRECISE_SPIN_WINDOW)
        ),
    ),
    "naive": ("naive call_at", with_naive_call_at),
}


def loop_factories() -> dict[str, LoopFactory]:
    factories: dict[str, LoopFactory] = {"asyncio": asyncio.new_event_loop}
    try:
        import uvloop  # noqa: PLC0415 - optional
    except ImportError:
        print("uvloop is not installed: skipping its rows", file=sys.stderr)
    else:
        factories["uvloop"] = uvloop.new_event_loop
    return factories


async def pace(install: Callable[[Pacer], None], seconds: float, rate: float) -> Pacer:
    loop = asyncio.get_running_loop()
    pacer = Pacer(loop, max(2, round(seconds * rate)), 1.0 / rate)
    install(pacer)
    pacer.schedule(pacer.start)
    await pacer.done
    return pacer


def run_variant(
    variant: str, loop_name: str, factory: LoopFactory, seconds: float, rate: float
) -> Result:
    with asyncio.Runner(loop_factory=factory) as runner:
        pacer = runner.run(pace(VARIANTS[variant][1], seconds, rate))
    period = pacer.period
    departures = pacer.departures
    signed = [t - (pacer.start + i * period) for i, t in enumerate(departures)]
    deviation = sorted(abs(d) for d in signed)
    intervals = sorted(abs(b - a - period) for a, b in itertools.pairwise(departures))
    wall = departures[-1] - departures[0]
    achieved = (len(departures) - 1) / wall
    cpu = 100.0 * (pacer.cpu[1] - pacer.cpu[0]) / wall
    p99 = percentile(deviation, 0.99) * 1e6
    meets = (
        p99 <= TARGET_P99_US
        and cpu <= TARGET_CPU_PERCENT
        and abs(achieved - rate) <= TARGET_RATE_TOLERANCE * rate
    )
    return Result(
        variant=VARIANTS[variant][0],
        loop=loop_name,
        departures=len(departures),
        dev_p50_us=round(percentile(deviation, 0.50) * 1e6, 1),
        dev_p99_us=round(p99, 1),
        dev_max_us=round(deviation[-1] * 1e6, 1),
        early=sum(1 for d in signed if d < 0),
        interval_dev_p99_us=round(percentile(intervals, 0.99) * 1e6, 1),
        rate_hz=round(achieved, 2),
        cpu_percent=round(cpu, 1),
        meets_target=meets,
    )


def environment() -> dict[str, object]:
    try:
        slack_ns: int | None = int(Path("/proc/self/timerslack_ns").read_text())
    except OSError:
        slack_ns = None
    try:
        uvloop_version: str | None = importlib.metadata.version("uvloop")
    except importlib.metadata.PackageNotFoundError:
        uvloop_version = None
    return {
        "python": platform.python_version(),
        "uvloop": uvloop_version,
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "timerslack_ns": slack_ns,
        "timerfd": timerfd_unavailable_reason() or "available",
        "loadavg_1min": round(os.getloadavg()[0], 2),
    }


def markdown(results: list[Result], rate: float) -> str:
    mark = {True: "yes", False: "no"}
    lines = [
        f"Targets: p99 deviation <= {TARGET_P99_US:.0f} us at <= {TARGET_CPU_PERCENT:.0f} % CPU, "
        f"rate {rate:.0f} +- {TARGET_RATE_TOLERANCE:.1%}.",
        "",
        "| variant | loop | deviation p50 / p99 / max (us) | early | interval dev p99 (us) "
        "| rate (Hz) | CPU (% of a core) | meets target |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in results:
        lines.append(
            f"| {r.variant} | {r.loop} "
            f"| {r.dev_p50_us:.1f} / {r.dev_p99_us:.1f} / {r.dev_max_us:.1f} "
            f"| {r.early} | {r.interval_dev_p99_us:.1f} | {r.rate_hz:.2f} | {r.cpu_percent:.1f} "
            f"| {mark[r.meets_target]} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument(
        "--seconds", type=float, default=5.0, help="run time per variant (default 5)"
    )
    parser.add_argument("--rate", type=float, default=1000.0, help="departures per second (1000)")
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object (table to stderr)"
    )
    parser.add_argument(
        "--only",
        nargs="+",
        choices=sorted(VARIANTS),
        metavar="VARIANT",
        help=f"run only these variants ({', '.join(VARIANTS)})",
    )
    args = parser.parse_args(argv)
    factories = loop_factories()
    load, cpus = os.getloadavg()[0], os.cpu_count() or 1
    if load > cpus / 2:
        print(
            f"warning: load average {load:.2f} on {cpus} CPUs; other processes will preempt the "
            "pacer and inflate the tails (spinning variants suffer most)",
            file=sys.stderr,
        )
    results: list[Result] = []
    for variant in args.only or VARIANTS:
        label = VARIANTS[variant][0]
        if variant == "timerfd" and (reason := timerfd_unavailable_reason()) is not None:
            print(f"skipping {label}: {reason}", file=sys.stderr)
            continue
        for loop_name, factory in factories.items():
            print(f"{label} on {loop_name} for {args.seconds:g} s ...", file=sys.stderr, flush=True)
            results.append(run_variant(variant, loop_name, factory, args.seconds, args.rate))
    table = markdown(results, args.rate)
    if args.json:
        print(table, file=sys.stderr)
        targets = {
            "p99_deviation_us": TARGET_P99_US,
            "cpu_percent": TARGET_CPU_PERCENT,
            "rate_hz": args.rate,
            "rate_tolerance": TARGET_RATE_TOLERANCE,
        }
        report = {
            "seconds": args.seconds,
            "rate_hz": args.rate,
            "environment": environment(),
            "targets": targets,
            "results": [asdict(r) for r in results],
        }
        print(json.dumps(report))
    else:
        env = ", ".join(f"{k} {v}" for k, v in environment().items())
        print(f"{env}\n\n{table}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
