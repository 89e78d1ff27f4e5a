"""``--control-rate HZ``: a counter on the reliable control channel, checked on arrival.

Each side sends the next value of a counter (8 bytes, big-endian, then its send time on the monotonic
clock as a double) as a control message HZ times a second beside its samples, and checks that the peer's counter arrives without a gap, a repeat or a
swap: ``out_of_order`` counts every arrival that is not the previous value plus one, so it must stay 0
however the network loses, duplicates or reorders datagrams. A tick that finds the channel's window
full (``control_window`` messages not yet acknowledged, e.g. during an outage) sends nothing and is
counted as ``blocked``; the counter is not advanced, so a blocked tick is no gap. On one host (the
demo) the receiver also records each message's delivery latency, from ``send_control`` to the
application, retransmissions and waiting for an earlier lost message included.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import struct
from dataclasses import dataclass, field
from typing import Any, Final

from tdtp.aio.endpoint import Endpoint
from tdtp.aio.ticker import Ticker
from tdtp.aio.timer import monotonic
from tdtp.cli.live_stats import LatencyRecorder
from tdtp.errors import (
    ConnectionStateError,
    ControlChannelFailedError,
    ControlQueueFullError,
    EndpointClosedError,
)
from tdtp.session.events import ControlExpired, ControlReceived

MAX_CONTROL_RATE: Final = 1000.0
"""The highest ``--control-rate``: control messages are commands and mode changes, not a stream."""
CONTROL_SETTLE_PATIENCE: Final = 5.0
"""Longest a run waits, after sending stopped, for its last control messages to be acknowledged
(a retransmission backs off to at most a second apart)."""

_COUNTER: Final = struct.Struct(">Qd")  # the counter, its send time (monotonic seconds)
MAX_CONTROL_LATENCY: Final = 60.0
"""Delivery latencies above this are not recorded (the clocks of two hosts are not comparable)."""


@dataclass
class ControlCounter:
    """One side's counter: what it sent, and what it received of the peer's."""

    sent: int = 0
    blocked: int = 0
    """Ticks that found the channel's window full (nothing sent, the counter not advanced)."""
    delivered: int = 0
    out_of_order: int = 0
    """Arrivals that were not the previous value plus one (a gap, a repeat or a swap)."""
    expected: int = 0
    given_up: int = 0
    """Own messages the channel gave up on (``control_timeout``)."""
    latency: LatencyRecorder = field(default_factory=LatencyRecorder)
    """Delivery latencies of the peer's messages (meaningful when both ends share a clock)."""

    def on_control(self, event: ControlReceived | ControlExpired) -> None:
        if isinstance(event, ControlExpired):
            self.given_up += len(event.payloads)
            return
        self.delivered += 1
        payload = event.payload
        value, sent_at = _COUNTER.unpack(payload) if len(payload) == _COUNTER.size else (-1, -1.0)
        if 0.0 <= event.received_at - sent_at < MAX_CONTROL_LATENCY:
            self.latency.add(event.received_at - sent_at)
        if event.index == 0 and value >= 0:
            self.expected = value  # a new session (a reconnected master) goes on from its count
        if value != self.expected:
            self.out_of_order += 1
        self.expected = value + 1

    def next_message(self) -> bytes:
        return _COUNTER.pack(self.sent, monotonic())


async def control_loop(ep: Endpoint, counter: ControlCounter, rate: float, until: float) -> None:
    """Send the counter ``rate`` times a second until ``until`` or the session ends."""
    remaining = until - monotonic()
    with contextlib.suppress(TimeoutError, EndpointClosedError, ControlChannelFailedError):
        async with asyncio.timeout(None if math.isinf(remaining) else max(0.0, remaining)):
            async for _ in Ticker(rate):
                if monotonic() >= until or ep.is_closed:
                    return
                try:
                    ep.send_control(counter.next_message())
                except (ControlQueueFullError, ConnectionStateError) as exc:
                    if isinstance(exc, ControlChannelFailedError | EndpointClosedError):
                        raise
                    counter.blocked += 1  # window full, or no session while reconnecting
                    continue
                counter.sent += 1


async def settle_control(*endpoints: Endpoint) -> None:
    """Wait until every control message sent is acknowledged (so delivered), or the patience ends."""
    start = monotonic()
    while any(ep.connection.control_unacked and not ep.is_closed for ep in endpoints):
        if monotonic() - start > CONTROL_SETTLE_PATIENCE:
            return
        await asyncio.sleep(0.01)


def control_report(
    sender: ControlCounter | None, receiver: ControlCounter | None, ep: Endpoint | None
) -> dict[str, Any]:
    """One direction's ``control_messages``: the sending side's counts and the receiving side's
    (``None`` for an end this process does not see); ``ep`` is the sending endpoint."""
    stats = ep.stats if ep is not None else None
    return {
        "sent": sender.sent if sender is not None else None,
        "delivered": receiver.delivered if receiver is not None else None,
        "out_of_order": receiver.out_of_order if receiver is not None else None,
        "blocked": sender.blocked if sender is not None else None,
        "given_up": sender.given_up if sender is not None else None,
        "retransmits": stats.control_retransmits if stats is not None else None,
        "latency_ms": receiver.latency.summary_ms() if receiver is not None else None,
    }


def control_line(label: str, sender: ControlCounter, receiver: ControlCounter, ep: Endpoint) -> str:
    """The live display's words for one direction of the control channel."""
    return (
        f"{label} control: sent {sender.sent}, delivered {receiver.delivered}, "
        f"out of order {receiver.out_of_order}, retransmits {ep.stats.control_retransmits}, "
        f"unacked {ep.connection.control_unacked}"
    )
