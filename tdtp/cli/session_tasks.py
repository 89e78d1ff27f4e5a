"""The tasks a session run is made of: the paced send loop, the once-a-second display tick, the
capture file, the watchdog's log lines, and the settling wait before the final counts are read."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
from collections.abc import Awaitable, Callable, Coroutine, Iterator
from typing import Any

from tdtp.aio.endpoint import Endpoint, WatchdogCallback
from tdtp.aio.ticker import Ticker
from tdtp.aio.timer import monotonic
from tdtp.capture.pcap import PcapWriter
from tdtp.cli.live_stats import (
    LiveDisplay,
)
from tdtp.cli.outcome import Outcome, Side
from tdtp.cli.summary import capture_report
from tdtp.errors import (
    EndpointClosedError,
)
from tdtp.session.events import PeerResumed, PeerSilent
from tdtp.teleop.haptic_sample import master_trajectory, slave_feedback


@contextlib.contextmanager
def open_capture(args: argparse.Namespace, outcome: Outcome) -> Iterator[PcapWriter | None]:
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


async def send_loop(
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
                    values = sample.position
                else:
                    sample = slave_feedback(side.last_position, index, now)
                    values = sample.force
                band = side.deadband
                if band is not None and not band.offer(values, now=now):
                    continue  # not worth a packet: the peer holds the last value
                ep.send(sample.encode(size))


async def every_second(until: float, tick: Callable[[float], None]) -> None:
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


def silence_note(ep: Endpoint, listener: str) -> str | None:
    """``"<listener> hears nothing for 1.2 s"`` while ``ep``'s watchdog finds the peer silent."""
    since = ep.connection.silent_since
    if since is None:
        return None
    return f"SILENT: {listener} hears nothing for {monotonic() - since:.1f} s"


def reconnect_note(ep: Endpoint, start: float) -> str | None:
    """The live display's line about reconnecting: under way, or how often it happened."""
    record = ep.reconnects
    if record.reopening:
        return "RECONNECTING: the session ended; opening a new one"
    if not record.count:
        return None
    causes = ", ".join(f"{cause} {n}" for cause, n in sorted(record.causes.items()))
    last = record.last_at - start if record.last_at is not None else 0.0
    return f"reconnected {record.count} time(s) ({causes}), last at t={last:.1f} s"


def reconnect_report(ep: Endpoint, start: float) -> dict[str, Any]:
    """The summary's ``reconnects`` entry."""
    record = ep.reconnects
    return {
        "count": record.count,
        "causes": dict(record.causes),
        "failed_attempts": record.failed_attempts,
        "last_at_s": None if record.last_at is None else round(record.last_at - start, 3),
        "samples_received_before_last": record.samples_received_before,
        "samples_received_since_last": ep.stats.samples_delivered if record.count else None,
        "samples_dropped_while_reconnecting": record.samples_dropped,
        "reconnecting_at_the_end": record.reopening,
    }


def watchdog_logger(
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
