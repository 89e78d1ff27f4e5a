"""What a run of ``tdtp demo``, ``master`` or ``slave`` records and reports: each side's counters, the
outcome with its exit status, the header line and the settings in the ``--json`` summary."""

from __future__ import annotations

import argparse
import asyncio
from dataclasses import dataclass, field
from typing import Any

from tdtp._build import build_info
from tdtp.aio.endpoint import Endpoint
from tdtp.cli.control_counter import ControlCounter
from tdtp.cli.live_stats import (
    LatencyRecorder,
)
from tdtp.cli.options import netem_directions
from tdtp.cli.paths_report import DropoutCounter, continuity
from tdtp.cli.summary import LatencyCounts, direction_report
from tdtp.session.events import DataReceived
from tdtp.teleop.deadband import DeadbandSender
from tdtp.teleop.haptic_sample import HapticSample

MAX_LATENCY = 10.0
"""Latencies above this are not recorded (the clocks of two hosts are not comparable)."""
EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 130, 143


@dataclass
class Side:
    """One end's application: what it sends, what it received, how late it arrived."""

    name: str
    latency: LatencyRecorder = field(default_factory=LatencyRecorder)
    received: int = 0
    last_position: tuple[float, ...] = (0.0, 0.0, 0.0)
    not_haptic: int = 0
    clock_mismatch: int = 0
    started: float = 0.0
    task_error: str | None = None
    """Why this side's task stopped early, if it failed (a bug; shown in ``--json``)."""
    deadband: DeadbandSender | None = None
    """``--deadband K``: which of this side's samples are worth sending (master: the position,
    slave: the force)."""
    control: ControlCounter | None = None
    """``--control-rate HZ``: this side's counter on the control channel."""
    first_sample_at: float | None = None
    """``monotonic()`` when the first sample arrived (``--rendezvous``: time to first sample)."""
    continuity: DropoutCounter = field(default_factory=DropoutCounter)
    """The 100 ms windows without a sample (``dropouts_100ms``)."""

    def deadband_report(self, unit: str) -> dict[str, Any] | None:
        """The ``deadband`` entry of the direction this side sends, ``None`` without a deadband."""
        band = self.deadband
        if band is None:
            return None
        stats = band.stats
        return {
            "k": band.config.k,
            "offered": stats.offered,
            "sent": stats.sent,
            "heartbeats": stats.heartbeats,
            "sent_fraction": round(stats.sent / stats.offered, 4) if stats.offered else None,
            "reconstruction_rmse": round(stats.reconstruction_rmse, 6),
            "unit": unit,
        }

    def on_data(self, event: DataReceived) -> None:
        if not self.received:
            self.first_sample_at = event.received_at
        self.received += 1
        self.continuity.arrived(event.received_at)
        sample = HapticSample.decode(event.payload)
        if sample is None:
            self.not_haptic += 1
            return
        self.last_position = sample.position
        latency = event.received_at - sample.sent_at
        if 0.0 <= latency < MAX_LATENCY:
            self.latency.add(latency)
        else:
            self.clock_mismatch += 1

    def latency_counts(self) -> LatencyCounts:
        return LatencyCounts(self.latency, self.not_haptic, self.clock_mismatch)


@dataclass
class Outcome:
    """What a run leaves behind, even when Ctrl-C cuts it short."""

    summary: dict[str, Any] | None = None
    status: int = EXIT_OK
    failure: str | None = None
    terminated: bool = False
    """SIGTERM stopped the run (exit status 143)."""


def direction_summary(
    *,
    sender: Endpoint | None,
    receiver: Endpoint | None,
    receiving: Side | None,
    observed_at: list[str],
    duration: float,
    end: float,
) -> dict[str, Any]:
    """One direction's entry in ``--json``: its sending and receiving ends' views (``None``: that end
    is not in this process; :func:`~tdtp.cli.summary.direction_report`), the latency and the dropouts
    up to ``end`` the receiving application (``receiving``) saw, and the sender's paths
    (:func:`~tdtp.cli.paths_report.continuity`)."""
    received = None if receiver is None else receiver.stats
    return direction_report(
        sender=None if sender is None else sender.stats,
        receiver=received,
        observed_at=observed_at,
        duration=duration,
        latency=None if receiving is None else receiving.latency_counts(),
    ) | continuity(
        sender=sender,
        receiver=received,
        counter=None if receiving is None else receiving.continuity,
        end=end,
    )


def header_line(args: argparse.Namespace, ep: Endpoint) -> str:
    mode = "separate ACKs" if args.separate_acks else "piggybacked ACKs"
    loop = type(asyncio.get_running_loop()).__module__.split(".")[0]
    conn = ep.connection
    security = "unkeyed"
    if conn.keyed:
        key = conn.key
        security = f"keyed ({key.label if key else '?'}, {conn.config.cipher_suite.name}, " + (
            "encrypted)" if conn.encrypted else "authenticated only)"
        )
    return (
        f"tdtp {args.command}: {args.rate:g} samples/s of {args.size} B each way, "
        f"{args.controller}, {mode}, {security}, loop {loop}, timer {ep.timer_kind}, "
        f"core {build_info().describe()}, sockets {ep.sockets}"
    )


def close_info(ep: Endpoint) -> dict[str, str] | None:
    event = ep.close_event
    return None if event is None else {"cause": event.cause.value, "detail": event.detail}


def settings_report(args: argparse.Namespace, ep: Endpoint) -> dict[str, Any]:
    ms, sm = netem_directions(args)
    return {
        "rate": args.rate,
        "size": args.size,
        "controller": args.controller,
        "ack_mode": "separate" if args.separate_acks else "bidirectional",
        "loop": type(asyncio.get_running_loop()).__module__.split(".")[0],
        "timer": ep.timer_kind,
        "core": build_info().as_dict(),
        "sockets": ep.sockets,
        "datagram_layer": ep.datagram_layer_stats,
        "keyed": ep.connection.keyed,
        "encrypted": ep.connection.encrypted,
        "netem_ms": None if ms is None else str(ms),
        "netem_sm": None if sm is None else str(sm),
        "multipath": (getattr(args, "multipath", None) or "redundant")
        if ep.connection.multipath is not None
        else None,
        "paths_netem": [str(spec) for spec in getattr(args, "path", None) or []] or None,
    }
