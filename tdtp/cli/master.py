"""``tdtp master HOST:PORT``: one master streaming samples to a slave, with live statistics.

``tdtp master --listen PORT`` waits for a slave that dials it (``tdtp slave --connect``) instead, and
serves the next one when a session ends (a restarted robot dials again), until ``--duration``."""

from __future__ import annotations

import argparse
import asyncio
import math

from tdtp.aio.api import connect, listen
from tdtp.aio.endpoint import Endpoint, format_address
from tdtp.aio.reconnect import ReconnectPolicy
from tdtp.aio.timer import monotonic
from tdtp.capture.pcap import PcapWriter
from tdtp.cli.control_counter import ControlCounter, control_loop, control_report
from tdtp.cli.live_stats import (
    DirectionMeter,
    LiveDisplay,
    receive_line,
)
from tdtp.cli.options import (
    netem_directions,
    netem_seed,
    rendezvous_settings,
    session_config,
    side_deadband,
)
from tdtp.cli.outcome import (
    EXIT_FAILED,
    EXIT_OK,
    Outcome,
    Side,
    close_info,
    direction_summary,
    header_line,
    settings_report,
)
from tdtp.cli.session_tasks import (
    _with_display,
    every_second,
    open_capture,
    reconnect_note,
    reconnect_report,
    send_loop,
    silence_note,
    watchdog_logger,
)
from tdtp.config import Role
from tdtp.session.events import CloseCause


async def run_master(args: argparse.Namespace, outcome: Outcome) -> None:
    with open_capture(args, outcome) as capture:
        await _master(args, outcome, capture)


async def _master(args: argparse.Namespace, outcome: Outcome, capture: PcapWriter | None) -> None:
    if args.listen is not None:
        await _listening_master(args, outcome, capture)
        return
    meet = rendezvous_settings(args)
    host, port = args.address if meet is None else (None, None)
    side = _side(args)
    ms_spec, _ = netem_directions(args)
    async with connect(
        host,
        port,
        rendezvous=meet,
        config=session_config(args),
        timer=args.timer,
        on_data=side.on_data,
        netem=ms_spec,
        netem_seed=netem_seed(args, 0),
        key=args.session_keys.master,
        pcap=capture,
        reconnect=ReconnectPolicy(after_silence=args.reconnect_after) if args.reconnect else False,
        local_addresses=args.local_address,
    ) as ep:
        start = monotonic()
        until = start + (args.duration or math.inf)
        peer = format_address(ep.peer) if meet is not None else format_address((host, port))
        await _session(args, outcome, side, ep, start, until, peer)


def _side(args: argparse.Namespace) -> Side:
    side = Side("master", deadband=side_deadband(args, master=True))
    if args.control_rate is not None:
        side.control = ControlCounter()
    return side


async def _listening_master(
    args: argparse.Namespace, outcome: Outcome, capture: PcapWriter | None
) -> None:
    """``--listen``: the master waits for its slave to dial; one session at a time, the next one
    when it ends, until ``--duration`` (the summary is the last session's, with their count)."""
    host, port = args.listen
    ms_spec, _ = netem_directions(args)
    start = monotonic()
    until = start + (args.duration or math.inf)
    served = 0
    async with listen(
        host,
        port,
        role=Role.MASTER,
        config=session_config(args),
        max_peers=1,
        timer=args.timer,
        netem=ms_spec,
        netem_seed=netem_seed(args, 0),
        keys=args.session_keys.slave,
        pcap=capture,
    ) as server:
        if not args.json:
            print(f"tdtp master listening on {format_address(server.sockname)}", flush=True)
        while monotonic() < until:
            remaining = until - monotonic()
            try:
                async with asyncio.timeout(None if math.isinf(remaining) else remaining):
                    ep = await server.accept()
            except TimeoutError:
                break
            served += 1
            outcome.status, outcome.failure = EXIT_OK, None  # the last session's outcome counts
            side = _side(args)
            ep.set_data_callback(side.on_data)
            await _session(args, outcome, side, ep, monotonic(), until, format_address(ep.peer))
            await ep.close()
        if outcome.summary is None:
            outcome.status = EXIT_FAILED
            outcome.failure = (
                f"no slave dialed {format_address(server.sockname)} within the run "
                "(tdtp slave --connect HOST:PORT)"
            )
        else:
            outcome.summary["sessions"] = served


async def _session(
    args: argparse.Namespace,
    outcome: Outcome,
    side: Side,
    ep: Endpoint,
    start: float,
    until: float,
    peer: str,
) -> None:
    """One session of the master's: the send loop, the live display and the summary."""
    display = None if args.json else LiveDisplay()
    meter = DirectionMeter("M->S")
    reverse_meter = DirectionMeter("S->M")
    if display is not None:
        display.message(header_line(args, ep) + f", slave {peer}")
    ep.set_watchdog_callback(watchdog_logger(display, start, "master", "slave"))
    if side.control is not None:
        ep.set_control_callback(side.control.on_control)

    def show(interval: float) -> None:
        assert display is not None
        stats = ep.stats
        lines = [
            f"t={monotonic() - start:6.1f} s",
            meter.line(stats, stats.packets_acked, interval, None, session=session_state(ep)),
            receive_line("S->M", side.received, reverse_meter, interval, side.latency, stats),
        ]
        note = silence_note(ep, "master")
        if note is not None:
            lines.append(note)
        note = reconnect_note(ep, start)
        if note is not None:
            lines.append(note)
        counter = side.control
        if counter is not None:
            lines.append(
                f"control: sent {counter.sent}, received {counter.delivered} (out of order "
                f"{counter.out_of_order}), retransmits {ep.stats.control_retransmits}"
            )
        display.update(lines)

    try:
        sending = asyncio.gather(
            send_loop(ep, side, args.rate, args.size, until, master=True),
            *(
                [control_loop(ep, side.control, args.control_rate, until)]
                if side.control is not None
                else []
            ),
        )
        if display is None:
            await sending
        else:
            await _with_display(sending, every_second(until, show))
    finally:
        elapsed = monotonic() - start
        outcome.summary = {
            "command": "master",
            "duration_s": round(elapsed, 3),
            **settings_report(args, ep),
            "master_to_slave": direction_summary(
                sender=ep,
                receiver=None,
                receiving=None,
                observed_at=["master"],
                duration=elapsed,
                end=start + elapsed,
            ),
            "slave_to_master": direction_summary(
                sender=None,
                receiver=ep,
                receiving=side,
                observed_at=["master"],
                duration=elapsed,
                end=start + elapsed,
            ),
            "samples_received": side.received,
            "reconnects": reconnect_report(ep, start),
            "peer_silences": ep.stats.peer_silences,
            "longest_silence_s": round(ep.stats.longest_silence, 3),
            "close": close_info(ep),
        }
        if ep.rendezvous is not None:
            outcome.summary["rendezvous"] = ep.rendezvous.report(side.first_sample_at)
        if side.deadband is not None:
            outcome.summary["master_to_slave"]["deadband"] = side.deadband_report("m")
        if side.control is not None:
            summary = outcome.summary
            summary["master_to_slave"]["control_messages"] = control_report(side.control, None, ep)
            summary["slave_to_master"]["control_messages"] = control_report(
                None, side.control, None
            )
        failure = master_failure(ep)
        if failure is not None:
            outcome.status = EXIT_FAILED
            outcome.failure = failure


def session_state(ep: Endpoint) -> str | None:
    """``None`` while a session is up; else what the live line shows instead of its figures."""
    if ep.reconnects.reopening:
        lost = ep.reconnects.lost
        return f"no session: reconnecting ({lost[0]})" if lost is not None else "no session"
    event = ep.close_event
    if event is not None:
        return f"no session: closed ({event.cause.value})"
    return None


def master_failure(ep: Endpoint) -> str | None:
    """The one line ``tdtp master`` ends with when its run failed, ``None`` when it did not: the
    session was lost and not reopened (evicted, refused, the slave gone for good or for longer
    than reconnecting tried), or the run ended while reconnecting. A CLOSE ``NORMAL`` from the
    slave is not a failure: it ended the session on purpose."""
    record = ep.reconnects
    lost = f"session lost ({record.lost[0]}): {record.lost[1]}" if record.lost is not None else None
    event = ep.close_event
    if record.reopening:
        return f"the run ended while reconnecting: {lost}; no new session opened"
    if event is None or event.cause is CloseCause.PEER_CLOSE:
        return None
    ended = f"({event.cause.value}): {event.detail}"
    if record.lost is not None and event.cause in (CloseCause.REJECTED, CloseCause.OPEN_TIMEOUT):
        return f"{lost}; reconnecting gave up {ended}"
    return f"session lost {ended}"
