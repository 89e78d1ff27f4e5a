"""``tdtp slave --port N``: a slave serving every master that connects, answering each with feedback.

``tdtp slave --connect HOST:PORT`` dials its master instead (``tdtp master --listen PORT``): a robot
behind a NAT or firewall that takes no incoming datagrams reaches its operator that way."""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
from collections import deque
from dataclasses import asdict
from typing import Any

from tdtp.aio.api import Server, connect, listen
from tdtp.aio.endpoint import Endpoint, format_address
from tdtp.aio.reconnect import ReconnectPolicy
from tdtp.aio.timer import monotonic
from tdtp.capture.pcap import PcapWriter
from tdtp.cli.control_counter import ControlCounter, control_loop, control_report
from tdtp.cli.keys import (
    SessionKeys,
    warn_if_exposed,
)
from tdtp.cli.live_stats import (
    LiveDisplay,
    age_text,
)
from tdtp.cli.options import (
    netem_directions,
    netem_seed,
    rendezvous_settings,
    session_config,
    side_deadband,
)
from tdtp.cli.outcome import EXIT_FAILED, Outcome, Side, close_info, direction_summary
from tdtp.cli.session_tasks import (
    _with_display,
    every_second,
    open_capture,
    reconnect_report,
    send_loop,
    silence_note,
    watchdog_logger,
)
from tdtp.config import Role
from tdtp.session.events import CloseCause

SESSIONS_KEPT = 256
"""Finished sessions a long-running slave remembers for its summary."""


async def run_slave(args: argparse.Namespace, outcome: Outcome) -> None:
    keys: SessionKeys = args.session_keys
    with open_capture(args, outcome) as capture:
        if args.connect is not None:
            await _dialing_slave(args, outcome, keys, capture)
        else:
            await _slave(args, outcome, keys, capture)


async def _dialing_slave(
    args: argparse.Namespace, outcome: Outcome, keys: SessionKeys, capture: PcapWriter | None
) -> None:
    """``--connect``: one session with the master listening there, reopened as a master's would be
    (``--reconnect``), answered with feedback until ``--duration``."""
    host, port = args.connect
    start = monotonic()
    until = math.inf if args.duration is None else start + args.duration
    _, sm_spec = netem_directions(args)
    side = Side(
        f"master {format_address((host, port))}",
        started=start,
        deadband=side_deadband(args, master=False),
    )
    if args.control_rate is not None:
        side.control = ControlCounter()
    async with connect(
        host,
        port,
        role=Role.SLAVE,
        config=session_config(args),
        timer=args.timer,
        on_data=side.on_data,
        netem=sm_spec,
        netem_seed=netem_seed(args, 1),
        key=keys.master,
        pcap=capture,
        reconnect=ReconnectPolicy(after_silence=args.reconnect_after) if args.reconnect else False,
    ) as ep:
        display = None if args.json else LiveDisplay()
        if display is not None:
            display.message(f"tdtp slave dialed the master at {format_address((host, port))}")
        if side.control is not None:
            ep.set_control_callback(side.control.on_control)
        ep.set_watchdog_callback(watchdog_logger(display, start, "slave", "master"))
        sides = {id(ep): (ep, side)}
        loops = [send_loop(ep, side, args.rate, args.size, until, master=False)]
        if side.control is not None:
            loops.append(control_loop(ep, side.control, args.control_rate, until))
        try:
            work = asyncio.gather(*loops)
            if display is None:
                await work
            else:
                await _with_display(
                    work, every_second(until, lambda _: _show_slave(display, [ep], sides))
                )
        except asyncio.CancelledError:
            # Ctrl-C or SIGTERM: the master hears whether this robot comes back (--on-stop), as
            # the masters of a listening slave do; the end of --duration closes it NORMAL.
            await ep.close(restarting=args.on_stop == "restart")
            raise
        finally:
            outcome.summary = {
                "command": "slave",
                "connected_to": format_address((host, port)),
                "masters_served": 1,
                "reconnects": reconnect_report(ep, start),
                "sessions": [_session(ep, side)],
            }
            event = ep.close_event
            if event is not None and event.cause is not CloseCause.PEER_CLOSE:
                outcome.status = EXIT_FAILED
                outcome.failure = f"session lost ({event.cause.value}): {event.detail}"


async def _slave(
    args: argparse.Namespace, outcome: Outcome, keys: SessionKeys, capture: PcapWriter | None
) -> None:
    until = math.inf if args.duration is None else monotonic() + args.duration
    sides: dict[int, tuple[Endpoint, Side]] = {}  # every session not yet in ``finished``
    finished: deque[dict[str, Any]] = deque(maxlen=SESSIONS_KEPT)
    _, sm_spec = netem_directions(args)
    async with listen(
        args.host,
        args.port or 0,
        rendezvous=rendezvous_settings(args),
        config=session_config(args),
        max_peers=args.max_peers,
        timer=args.timer,
        netem=sm_spec,
        netem_seed=netem_seed(args, 1),
        keys=keys.slave,
        pcap=capture,
        exclusive=args.exclusive,
        takeover_after=args.takeover_after,
    ) as server:
        warn_if_exposed(args.host, keys)  # once bound: a slave that failed to start exposes nothing
        display = None if args.json else LiveDisplay()
        if display is not None:
            keyed = f", keyed ({len(keys.slave)} key(s))" if keys.slave is not None else ", unkeyed"
            display.message(f"tdtp slave listening on {format_address(server.sockname)}{keyed}")
        tasks: set[asyncio.Task[None]] = set()
        acceptor = asyncio.create_task(
            _accept_loop(server, sides, args, until, tasks, finished, display)
        )
        try:
            await every_second(
                until, lambda interval: _show_slave(display, server.endpoints, sides)
            )
        except asyncio.CancelledError:
            # Ctrl-C or SIGTERM: the masters are told whether to come back (--on-stop), before
            # the summary is made; the end of --duration closes them NORMAL (listen's exit).
            await server.close(restarting=args.on_stop == "restart")
            raise
        finally:
            acceptor.cancel()
            for task in tasks:
                task.cancel()
            # Sessions still open, and those that closed just now (their task has not recorded
            # them yet): every master served is in the summary exactly once.
            sessions = list(finished) + [_session(ep, side) for ep, side in sides.values()]
            outcome.summary = {
                "command": "slave",
                "masters_served": server.stats.peers_accepted,
                "masters_refused": server.stats.peers_refused,
                "masters_evicted": server.stats.peers_evicted,
                "slots": asdict(server.stats.slots),
                "datagrams_unattached": server.stats.datagrams_unattached,
                "admission": asdict(server.stats.admission),
                "sessions": sessions,
            }
            if server.rendezvous is not None:
                firsts = [side.first_sample_at for _, side in sides.values()]
                first = min((at for at in firsts if at is not None), default=None)
                outcome.summary["rendezvous"] = server.rendezvous.report(first)


def _session(ep: Endpoint, side: Side | None) -> dict[str, Any]:
    """One master's session as the slave saw it: both directions from this end."""
    duration = monotonic() - side.started if side is not None else 0.0
    key = ep.connection.key
    session: dict[str, Any] = {
        "master": format_address(ep.peer),
        "key": None if key is None else key.label,
        "duration_s": round(duration, 3),
        "closed": ep.is_closed,
        "samples_received": side.received if side else ep.stats.samples_delivered,
        "samples_sent": ep.stats.sent.data_packets,
        "peer_silences": ep.stats.peer_silences,
        "longest_silence_s": round(ep.stats.longest_silence, 3),
        "close": close_info(ep),
        "task_error": side.task_error if side is not None else None,
        "master_to_slave": direction_summary(
            sender=None,
            receiver=ep,
            receiving=side,
            observed_at=["slave"],
            duration=duration,
            end=monotonic(),
        ),
        "slave_to_master": direction_summary(
            sender=ep,
            receiver=None,
            receiving=None,
            observed_at=["slave"],
            duration=duration,
            end=monotonic(),
        ),
    }
    if side is not None and side.deadband is not None:
        session["slave_to_master"]["deadband"] = side.deadband_report("N")
    if side is not None and side.control is not None:
        session["slave_to_master"]["control_messages"] = control_report(side.control, None, ep)
        session["master_to_slave"]["control_messages"] = control_report(None, side.control, None)
    return session


async def _accept_loop(
    server: Server,
    sides: dict[int, tuple[Endpoint, Side]],
    args: argparse.Namespace,
    until: float,
    tasks: set[asyncio.Task[None]],
    finished: deque[dict[str, Any]],
    display: LiveDisplay | None,
) -> None:
    start = monotonic()
    async for ep in server:
        side = Side(
            f"master {format_address(ep.peer)}",
            started=monotonic(),
            deadband=side_deadband(args, master=False),
        )
        sides[id(ep)] = (ep, side)
        if args.control_rate is not None:
            side.control = ControlCounter()
            ep.set_control_callback(side.control.on_control)
        ep.set_data_callback(side.on_data)
        ep.set_watchdog_callback(
            watchdog_logger(display, start, "slave", f"master {format_address(ep.peer)}")
        )
        task = asyncio.create_task(_serve_one(ep, side, args, until, sides, finished, display))
        tasks.add(task)
        task.add_done_callback(tasks.discard)


async def _serve_one(
    ep: Endpoint,
    side: Side,
    args: argparse.Namespace,
    until: float,
    sides: dict[int, tuple[Endpoint, Side]],
    finished: deque[dict[str, Any]],
    display: LiveDisplay | None,
) -> None:
    """Answer one master until the run ends or the session does. A failure of this task (a bug:
    payloads are opaque unless they are the demo's samples) is reported once, on the display or
    stderr and in ``--json``, and ends this session only: the slave goes on serving the others."""
    try:
        loops = [send_loop(ep, side, args.rate, args.size, until, master=False)]
        if side.control is not None:
            loops.append(control_loop(ep, side.control, args.control_rate, until))
        await asyncio.gather(*loops)
    except Exception as exc:
        side.task_error = f"{type(exc).__name__}: {exc}"
        message = f"session with {format_address(ep.peer)} failed: {side.task_error}"
        if display is not None:
            display.message(message)
        else:
            print(f"tdtp slave: {message}", file=sys.stderr)
        await ep.close()
    if ep.is_closed:
        finished.append(_session(ep, side))
        sides.pop(id(ep), None)


def _show_slave(
    display: LiveDisplay | None, endpoints: list[Endpoint], sides: dict[int, tuple[Endpoint, Side]]
) -> None:
    if display is None:
        return
    lines = [f"{len(endpoints)} master(s) connected"]
    for ep in endpoints:
        entry = sides.get(id(ep))
        side = entry[1] if entry is not None else None
        stats = ep.stats
        line = (
            f"  {format_address(ep.peer)}:  received {side.received if side else 0} samples"
            f"  sent {stats.sent.data_packets}  srtt {stats.srtt * 1e3:.3f} ms"
            f"  lost {stats.packets_lost}  allowed {stats.rate:.0f}/s"
        )
        age = age_text(stats)
        if age is not None:
            line += "  " + age
        counter = side.control if side is not None else None
        if counter is not None:
            line += (
                f"  control: received {counter.delivered} (out of order {counter.out_of_order}),"
                f" sent {counter.sent}"
            )
        note = silence_note(ep, "slave")
        if note is not None:
            line += "  " + note
        lines.append(line)
    display.update(lines)
