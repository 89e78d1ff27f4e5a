"""``tdtp demo``: a master and a slave on localhost in one process, with live statistics and a summary."""

from __future__ import annotations

import argparse
import asyncio
import math
import secrets
from dataclasses import replace
from typing import Any

from tdtp.aio.api import connect, listen
from tdtp.aio.timer import monotonic
from tdtp.capture.pcap import PcapWriter
from tdtp.cli.control_counter import (
    ControlCounter,
    control_line,
    control_loop,
    control_report,
    settle_control,
)
from tdtp.cli.keys import (
    SessionKeys,
)
from tdtp.cli.live_stats import (
    DirectionMeter,
    LiveDisplay,
)
from tdtp.cli.netem_view import netem_lines, netem_report
from tdtp.cli.options import (
    netem_directions,
    netem_seed,
    rendezvous_settings,
    session_config,
    side_deadband,
)
from tdtp.cli.outcome import Outcome, Side, direction_summary, header_line, settings_report
from tdtp.cli.session_tasks import (
    _settle,
    _with_display,
    every_second,
    open_capture,
    send_loop,
    silence_note,
    watchdog_logger,
)
from tdtp.cli.summary import srtt_text
from tdtp.config import ConnectionConfig


async def run_demo(args: argparse.Namespace, outcome: Outcome) -> None:
    config = session_config(args)
    keys: SessionKeys = args.session_keys
    master_side = Side("master", deadband=side_deadband(args, master=True))
    slave_side = Side("slave", deadband=side_deadband(args, master=False))
    if args.control_rate is not None:
        master_side.control, slave_side.control = ControlCounter(), ControlCounter()
    with open_capture(args, outcome) as capture:
        await _demo(args, outcome, config, keys, master_side, slave_side, capture)


async def _demo(
    args: argparse.Namespace,
    outcome: Outcome,
    config: ConnectionConfig,
    keys: SessionKeys,
    master_side: Side,
    slave_side: Side,
    capture: PcapWriter | None,
) -> None:
    duration = args.duration if args.duration is not None else 5.0
    ms_spec, sm_spec = netem_directions(args)
    meet = rendezvous_settings(args)
    if meet is not None and meet.name is None and not keys.keyed:
        meet = replace(meet, name=secrets.token_hex(16))  # both ends are ours: any secret name
    paths = args.path or []
    async with (
        listen(
            "127.0.0.1" if meet is None else "0.0.0.0",
            0,
            rendezvous=meet,
            config=config,
            timer=args.timer,
            on_data=slave_side.on_data,
            netem=sm_spec,
            netem_seed=netem_seed(args, 1),
            keys=keys.slave,
        ) as server,
        connect(
            "127.0.0.1" if meet is None else None,
            server.port if meet is None else None,
            rendezvous=meet,
            config=config,
            timer=args.timer,
            on_data=master_side.on_data,
            netem=ms_spec,
            netem_seed=netem_seed(args, 0),
            key=keys.master,
            pcap=capture,
            # --path: one socket per path on the master's side, each impaired both ways there.
            local_addresses=["127.0.0.1"] * len(paths) if paths else None,
            path_netem=paths or None,
        ) as master,
    ):
        slave = await server.accept()
        if master_side.control is not None and slave_side.control is not None:
            master.set_control_callback(master_side.control.on_control)
            slave.set_control_callback(slave_side.control.on_control)
        start = monotonic()
        until = start + duration
        elapsed: float | None = None
        display = None if args.json else LiveDisplay()
        meters = (DirectionMeter("M->S"), DirectionMeter("S->M"))
        if display is not None:
            display.message(header_line(args, master))
        master.set_watchdog_callback(watchdog_logger(display, start, "master", "slave"))
        slave.set_watchdog_callback(watchdog_logger(display, start, "slave", "master"))

        def show(interval: float) -> None:
            assert display is not None
            lines = [f"t={monotonic() - start:6.1f} s"]
            for meter, sender, receiver, receiving in (
                (meters[0], master, slave, slave_side),
                (meters[1], slave, master, master_side),
            ):
                lines.append(
                    meter.line(
                        sender.stats,
                        receiver.stats.received.data_packets,
                        interval,
                        receiving.latency.take_window(),
                        silence_note(receiver, receiving.name),
                        receiver=receiver.stats,
                    )
                )
            bands = [
                (label, side.deadband)
                for label, side in (("M->S", master_side), ("S->M", slave_side))
                if side.deadband is not None
            ]
            if bands:
                lines.append(
                    "deadband  "
                    + "  ".join(
                        f"{label} sends {band.stats.sent / max(band.stats.offered, 1) * 100:5.1f} % "
                        f"of {band.stats.offered} offered"
                        for label, band in bands
                    )
                )
            mc, sc = master_side.control, slave_side.control
            if mc is not None and sc is not None:
                lines.append(control_line("M->S", mc, sc, master))
                lines.append(control_line("S->M", sc, mc, slave))
            lines += netem_lines(master, slave)
            display.update(lines)

        def summarize() -> None:
            spent = elapsed if elapsed is not None else monotonic() - start
            both = ["master", "slave"]
            outcome.summary = {
                "command": "demo",
                "duration_s": round(spent, 3),
                **settings_report(args, master),
                "master_to_slave": direction_summary(
                    sender=master,
                    receiver=slave,
                    receiving=slave_side,
                    observed_at=both,
                    duration=spent,
                    end=start + spent,
                ),
                "slave_to_master": direction_summary(
                    sender=slave,
                    receiver=master,
                    receiving=master_side,
                    observed_at=both,
                    duration=spent,
                    end=start + spent,
                ),
            }
            if master.rendezvous is not None and server.rendezvous is not None:
                outcome.summary["rendezvous"] = {
                    "master": master.rendezvous.report(master_side.first_sample_at),
                    "slave": server.rendezvous.report(slave_side.first_sample_at),
                }
            for key, ep in (("master_to_slave", master), ("slave_to_master", slave)):
                if (link := netem_report(ep)) is not None:
                    outcome.summary[key]["emulated_link"] = link
            if args.deadband is not None:
                outcome.summary["master_to_slave"]["deadband"] = master_side.deadband_report("m")
                outcome.summary["slave_to_master"]["deadband"] = slave_side.deadband_report("N")
            mc, sc = master_side.control, slave_side.control
            if mc is not None and sc is not None:
                outcome.summary["master_to_slave"]["control_messages"] = control_report(
                    mc, sc, master
                )
                outcome.summary["slave_to_master"]["control_messages"] = control_report(
                    sc, mc, slave
                )

        try:
            loops = [
                send_loop(master, master_side, args.rate, args.size, until, master=True),
                send_loop(slave, slave_side, args.rate, args.size, until, master=False),
            ]
            for ep, side in ((master, master_side), (slave, slave_side)):
                if side.control is not None:
                    loops.append(control_loop(ep, side.control, args.control_rate, until))
            sending = asyncio.gather(*loops)
            if display is None:
                await sending
            else:
                await _with_display(sending, every_second(until, show))
            elapsed = monotonic() - start  # the sending window: rates are per second of it
            await _settle(master, slave)  # let the last samples land before counting
            if args.control_rate is not None:
                await settle_control(master, slave)  # every control message acknowledged
        finally:
            summarize()


def demo_table(summary: dict[str, Any]) -> str:
    rows = []
    for key, label in (("master_to_slave", "M->S"), ("slave_to_master", "S->M")):
        d = summary[key]
        latency = d.get("latency_ms") or {}
        age = d.get("sample_age_ms") or {}
        rows.append(
            f"{label}: offered {d['samples_offered']}, sent {d['packets_sent']}, "
            f"received {d['packets_received']} ({d['delivery_ratio'] * 100:.2f} %), "
            f"lost {d['losses']}, {d['mean_rate']:.1f} pkt/s, {srtt_text(d['srtt_ms'])}, "
            f"latency p50 {latency.get('p50', math.nan):.3f} ms p99 "
            f"{latency.get('p99', math.nan):.3f} ms, age p50 {age.get('p50', math.nan):.3f} ms p99 "
            f"{age.get('p99', math.nan):.3f} ms, header bytes {d['header_bytes']}, "
            f"ACK packets {d['ack_packets_sent_back']}, dropouts {d.get('dropouts_100ms')}"
        )
        if d.get("paths"):
            rows.append(
                f"{label}: duplicates {d['duplicates']}, paths "
                + "; ".join(
                    f"{p['id']}: {p['state']}, sent {p['sent']}, first {p['first_delivered']}, "
                    f"srtt {p['srtt_ms']:.3f} ms"
                    for p in d["paths"]
                )
            )
    return "\n".join(rows)
