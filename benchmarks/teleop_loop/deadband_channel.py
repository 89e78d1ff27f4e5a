"""tdtp with perceptual deadband (:mod:`tdtp.teleop.deadband`): a :class:`Channel` that sends a sample
only when the change would be felt, and reconstructs the held value at the receiver.

Each side's control loop still offers a sample per tick; the channel decides which go:

* **master -> slave, the position command**: the deadband watches the device's *velocity* (the
  difference of consecutive offered positions over their timestamps), as Hinterseer et al. do for the
  command channel: a sample goes when the velocity changed by more than ``k`` times its magnitude
  (at least ``COMMAND_FLOOR`` m/s), or ``max_hold`` passed. A Weber fraction of a *position* would
  depend on where the frame's origin lies (10 % of the arm's 0.4 m reach is 4 cm). The slave
  extrapolates the command along the slope of the last two commands received (first-order hold,
  :class:`~tdtp.teleop.deadband.DeadbandReceiver`), timed by the samples' tick numbers and run
  forward from the moment the newest arrived, so jitter on the path does not bend the slope and the
  extrapolation never predicts across the network delay;
* **slave -> master, the contact force**: the deadband watches the force vector (``k`` times its
  magnitude, at least ``FORCE_FLOOR`` N, so that free space's zero force sends only heartbeats); the
  master holds the last force received (zero-order hold: a contact force steps, extrapolating it
  would push the hand into or out of the wall).

The payload a side reads from :meth:`DeadbandChannel.latest` is the newest received sample with the
reconstructed values in place; its ``sent_at`` is the newest received sample's, so the benchmark's
"age of the newest sample" says how long the receiver has been holding (up to ``max_hold`` plus the
path's delay), not how stale the value it uses is.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import tdtp
from tdtp.teleop.deadband import DeadbandConfig, DeadbandReceiver, DeadbandSender
from tdtp.teleop.haptic_sample import HapticSample

from teleop_loop.transports import FRAME, Channel
from teleop_loop.workspace import TICK

DEFAULT_K = 0.1
"""The Weber fraction the literature finds imperceptible for force (10 %)."""
COMMAND_FLOOR = 0.002
"""m/s: a velocity change below this never sends a command (a hand at rest jitters less)."""
FORCE_FLOOR = 0.1
"""N: a force change below this never sends (free space's zero force sends only heartbeats)."""
MAX_HOLD = 0.1
"""Seconds: a sample goes at least this often (the heartbeat keeps ACKs and RTT samples flowing)."""

Direction = Literal["command", "force"]


class DeadbandChannel:
    """A channel (tdtp's) behind a :class:`DeadbandSender` on the way out and a
    :class:`DeadbandReceiver` on the way in; ``sends`` and ``receives`` say which direction each
    carries (the master sends commands and receives forces, the slave the reverse)."""

    def __init__(self, inner: Channel, *, sends: Direction, k: float = DEFAULT_K) -> None:
        self.inner = inner
        self._sends = sends
        floor = COMMAND_FLOOR if sends == "command" else FORCE_FLOOR
        self.sender = DeadbandSender(
            [(0, 1, 2)], DeadbandConfig(k=k, min_threshold=floor, max_hold=MAX_HOLD)
        )
        self.receiver = DeadbandReceiver(extrapolate=sends == "force", max_hold=MAX_HOLD)
        """Extrapolates the commands the slave receives; holds the forces the master receives."""
        self._previous: HapticSample | None = None  # the last sample offered (command velocity)
        self._newest: HapticSample | None = None  # the newest sample received
        self._offset = 0.0  # arrival time - sent_at of the newest received sample

    def send(self, payload: bytes) -> None:
        sample = HapticSample.decode(payload)
        if sample is None:  # not a haptic sample: nothing to judge, it goes
            self.inner.send(payload)
            return
        if self._sends == "command":
            previous, self._previous = self._previous, sample
            dt = 0.0 if previous is None else _tick_time(sample) - _tick_time(previous)
            values: tuple[float, ...] = (
                (0.0, 0.0, 0.0)
                if previous is None or dt <= 0.0
                else tuple(
                    (a - b) / dt for a, b in zip(sample.position, previous.position, strict=True)
                )
            )
        else:
            values = sample.force
        if self.sender.offer(values, now=sample.sent_at):
            self.inner.send(payload)

    def latest(self) -> bytes | None:
        payload = self.inner.latest()
        if payload is None:
            return None
        sample = HapticSample.decode(payload)
        if sample is None:
            return payload
        newest = self._newest
        if newest is None or sample.index != newest.index:
            received = sample.force if self._sends == "command" else sample.position
            self.receiver.receive(received, now=_tick_time(sample))
            self._offset = tdtp.monotonic() - _tick_time(sample)
            self._newest = newest = sample
        held = self.receiver.value_at(tdtp.monotonic() - self._offset)
        if held is None or not all(math.isfinite(v) for v in held):
            return payload
        if self._sends == "command":  # the master: the force it holds
            out = HapticSample(newest.sent_at, newest.index, newest.position, tuple(held))
        else:  # the slave: the command it extrapolates
            out = HapticSample(newest.sent_at, newest.index, tuple(held), newest.force)
        return out.encode(FRAME)

    def packets_sent(self) -> int | None:
        return self.inner.packets_sent()

    def details(self) -> dict[str, Any]:
        stats = self.sender.stats
        return {
            **self.inner.details(),
            "deadband": {
                "offered": stats.offered,
                "sent": stats.sent,
                "heartbeats": stats.heartbeats,
                "saving": round(stats.saving, 4),
            },
        }

    async def close(self) -> None:
        await self.inner.close()


def _tick_time(sample: HapticSample) -> float:
    """When the sample was taken on its sender's tick clock (seconds from the run's start; warm-up
    samples, numbered below 0 modulo 2**32, before it). Their ``sent_at`` would do too, but it carries
    the sender's wake-up jitter (~0.1 ms of a 1 ms tick), which reads as 10 % velocity noise."""
    index = sample.index if sample.index < 1 << 31 else sample.index - (1 << 32)
    return index * TICK
