"""Closed-loop teleoperation over every transport: a bilateral haptic loop through the same impairment.

A position-force loop at 1 kHz, each side in its own process (``teleop_loop/``): on the master an
operator's hand (an impedance following a seeded reach-press-slide motion) holds a haptic device and
sends its position; on the slave a MuJoCo arm follows it under a position controller, meets a stiff
wall, and sends back the contact force it measures, which the device renders. The transports (tdtp,
tdtp with perceptual deadband, raw UDP, TCP, Zenoh) each carry the loop through the same netem
profile: tdtp through its in-process netem, the others through the relay ``tdtp netem-relay`` runs
(UDP, Zenoh) or its per-segment counterpart for TCP (``teleop_loop/tcp_link.py``). Before the clock
starts, a warm-up waits (bounded) until a first sample has crossed each way.

Per profile and transport: fingertip tracking RMSE (mm), force RMSE (N), deepest wall penetration
(mm), packets/s each way, p99 age of the newest sample each way, and the energy the channel injected
(a passivity observer). A Markdown table (stderr, and ``--out``/closed_loop.md), the JSON (``--json`` on
stdout, and ``--out``/closed_loop.json), and a PNG per profile (position and force over time).

    python benchmarks/closed_loop.py                 # every profile and transport (~6 min)
    python benchmarks/closed_loop.py --repeat 3      # medians and min-max spreads (~20 min)
    python benchmarks/closed_loop.py --quick --json  # CI-sized
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from _common import (
    RESULTS,
    WorkerHandle,
    environment,
    have_uvloop,
    start_worker,
    warn_if_loaded,
)

from teleop_loop import metrics, relays, sides
from teleop_loop.transports import TRANSPORTS
from teleop_loop.workspace import CONTACT_X

PROFILES: dict[str, str] = {
    "clean": "delay 0ms",
    "wan": "delay 20ms 5ms loss 2%",
    "wifi": "delay 5ms 3ms loss gemodel 1% 20% 60% 0.1%",
    "lte": "delay 40ms 10ms loss 1% rate 2mbit limit 100",
    "congested": "delay 10ms rate 500kbit limit 50",
}
"""netem specs, the same each way. wifi: Gilbert-Elliott bursts (about 3 % loss in bursts of ~5
packets) with jitter; congested: a bottleneck below the stream's ~0.85 Mbit/s (1000 samples of 100 B)."""

QUICK_SECONDS = 2.0
SECONDS = 10.0
SETUP_TIMEOUT = 30.0
WARMUP_TIMEOUT = 20.0
"""Seconds the warm-up may take before a run is given up: long enough for a session set-up that
crosses a bursty link several times, short enough that a transport that never starts costs little."""


class UsageError(Exception):
    pass


class StartupError(Exception):
    """A transport did not carry a first sample both ways within the warm-up: the cell has no
    figures, the report says why, and the other cells still run."""


def _parse(argv: list[str]) -> argparse.Namespace:
    first = (__doc__ or "").strip().splitlines()[0]
    p = argparse.ArgumentParser(description=first)
    p.add_argument("--profiles", default=",".join(PROFILES), help="comma-separated (all)")
    p.add_argument("--transports", default=",".join(TRANSPORTS), help="comma-separated (all)")
    p.add_argument(
        "--seconds",
        type=float,
        default=None,
        help=f"per run ({SECONDS:g}; --quick {QUICK_SECONDS:g})",
    )
    p.add_argument("--repeat", type=int, default=1, help="runs per cell, netem seeds differ (1)")
    p.add_argument("--seed", type=int, default=1, help="operator motion and netem seeds (1)")
    p.add_argument("--quick", action="store_true", help=f"{QUICK_SECONDS:g} s runs, for CI")
    p.add_argument("--json", action="store_true", help="print the JSON report on stdout")
    p.add_argument(
        "--out",
        type=Path,
        default=RESULTS / "closed_loop",
        help="where the table, JSON and PNGs go",
    )
    p.add_argument(
        "--deadband-k",
        type=float,
        default=0.1,
        help="tdtp-deadband's Weber fraction: the relative change that sends a sample (0.1)",
    )
    p.add_argument(
        "--warmup-timeout",
        type=float,
        default=WARMUP_TIMEOUT,
        help=f"seconds a transport may take to carry its first sample each way ({WARMUP_TIMEOUT:g})",
    )
    p.add_argument("--no-plots", action="store_true", help="skip the PNGs")
    p.add_argument(
        "--loop", choices=("auto", "uvloop", "asyncio"), default="auto", help="event loop (auto)"
    )
    args = p.parse_args(argv)
    args.profiles = _names(args.profiles, PROFILES, "profile")
    args.transports = _names(args.transports, TRANSPORTS, "transport")
    if args.seconds is None:
        args.seconds = QUICK_SECONDS if args.quick else SECONDS
    if not 1.0 <= args.seconds <= 600:
        raise UsageError(f"--seconds must be between 1 and 600, got {args.seconds:g}")
    if not 1 <= args.repeat <= 20:
        raise UsageError(f"--repeat must be between 1 and 20, got {args.repeat}")
    if not 0.0 < args.deadband_k < 10.0:
        raise UsageError(f"--deadband-k must be a fraction in (0, 10), got {args.deadband_k:g}")
    if not 1.0 <= args.warmup_timeout <= 600:
        raise UsageError(
            f"--warmup-timeout must be between 1 and 600 seconds, got {args.warmup_timeout:g}"
        )
    if args.loop == "auto":
        args.loop = "uvloop" if have_uvloop() else "asyncio"
    elif args.loop == "uvloop" and not have_uvloop():
        raise UsageError("--loop uvloop: uvloop is not installed (the fast extra)")
    for name in args.transports:
        needs = TRANSPORTS[name].needs
        if needs and importlib.util.find_spec(needs) is None:
            raise UsageError(f"transport {name} needs the {needs} module: pip install -e '.[loop]'")
    if importlib.util.find_spec("mujoco") is None:
        raise UsageError(
            "the slave's arm needs MuJoCo: pip install -e '.[loop]' (or make closed-loop)"
        )
    return args


def _names(text: str, known: dict[str, Any], what: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in known]
    if unknown or not names:
        raise UsageError(
            f"unknown {what} {', '.join(unknown) or '(none given)'}; choose from {', '.join(known)}"
        )
    return names


def progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def run_once(
    profile: str,
    transport: str,
    seconds: float,
    netem_seed: int,
    motion_seed: int,
    loop: str,
    options: dict[str, Any] | None = None,
    warmup_timeout: float = WARMUP_TIMEOUT,
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """One run: the figures, the logs for the plots, and what each end's transport (and the relay)
    counted, with how long the warm-up took. :class:`StartupError` when the transport carried no
    sample one way or the other within ``warmup_timeout``."""
    options = options or {}
    spec = PROFILES[profile]
    kind = TRANSPORTS[transport].impairment
    handles: list[WorkerHandle] = []
    relay: WorkerHandle | None = None
    try:
        slave = start_worker(
            "slave",
            sides.slave,
            transport=transport,
            spec=spec,
            seed=netem_seed + 1,
            loop=loop,
            options=options,
        )
        handles.append(slave)
        port = slave.recv(SETUP_TIMEOUT)["port"]
        if kind != "in-process":
            relay = start_worker(
                "relay", relays.RELAYS[kind], forward_port=port, spec=spec, seed=netem_seed
            )
            port = relay.recv(SETUP_TIMEOUT)["port"]
        master = start_worker(
            "master",
            sides.master,
            transport=transport,
            port=port,
            spec=spec,
            seed=netem_seed,
            motion_seed=motion_seed,
            loop=loop,
            options=options,
        )
        handles.append(master)
        master.recv(SETUP_TIMEOUT)
        try:
            warm_up = _warm_up(profile, transport, slave, master, warmup_timeout)
        except StartupError:
            for handle in (slave, master):  # a run of no ticks: both sides close and exit
                with contextlib.suppress(OSError):
                    handle.send({"start_at": time.monotonic(), "duration": 0.0})
            raise
        start_at = time.monotonic() + 0.5
        for handle in (slave, master):
            handle.send({"start_at": start_at, "duration": seconds})
        before = after = None
        if relay is not None:
            time.sleep(max(0.0, start_at - time.monotonic()))
            relay.send("count")
            before = relay.recv(SETUP_TIMEOUT)
            time.sleep(max(0.0, start_at + seconds - time.monotonic()))
            relay.send("count")
            after = relay.recv(SETUP_TIMEOUT)
        m = master.recv(seconds + SETUP_TIMEOUT)
        s = slave.recv(seconds + SETUP_TIMEOUT)
        if relay is not None and before is not None and after is not None:
            packets = {
                "m2s": after["forward"]["sent"] - before["forward"]["sent"],
                "s2m": after["return"]["sent"] - before["return"]["sent"],
            }
        else:
            packets = {"m2s": m["packets_sent"], "s2m": s["packets_sent"]}
        figures = metrics.summarise(m["log"], s["log"], seconds, packets)
        details: dict[str, Any] = {
            "warm_up_s": warm_up,
            "master": m["details"],
            "slave": s["details"],
        }
        if after is not None:
            details["relay"] = after
        return figures, {"master": m["log"], "slave": s["log"]}, details
    finally:
        if relay is not None:
            with contextlib.suppress(Exception):
                relay.send("stop")
                relay.recv(5.0)
            relay.finish()
        for handle in handles:
            handle.finish()


def _warm_up(
    profile: str,
    transport: str,
    slave: WorkerHandle,
    master: WorkerHandle,
    timeout: float,
) -> dict[str, float]:
    """Wait until each side has received a first sample from the other (each says when), at most
    ``timeout`` seconds in all; the seconds each side waited."""
    deadline = time.monotonic() + timeout
    waited: dict[str, float] = {}
    for name, handle, way in (
        ("slave", slave, "master->slave"),
        ("master", master, "slave->master"),
    ):
        left = deadline - time.monotonic()
        if left <= 0.0 or not handle.conn.poll(left):
            raise StartupError(
                f"{transport} on {profile}: no sample crossed {way} within {timeout:g} s of "
                "warm-up (the transport's session never came up over this path)"
            )
        waited[name] = float(handle.recv(0.0)["warm"])
    return waited


def _median_cell(runs: list[dict[str, Any]], failures: list[str]) -> dict[str, Any]:
    """The median of every figure over the runs that started (nested dicts alike); with more than
    one, ``spread`` has the same shape with ``[min, max]`` in place of each figure. ``failed``
    lists why the others did not start; a cell where none started has only that."""

    def merge(values: list[Any], pick: Any) -> Any:
        first = values[0]
        if isinstance(first, dict):
            return {k: merge([v[k] for v in values], pick) for k in first}
        numbers = [v for v in values if v is not None]
        return pick(numbers) if numbers else None

    cell: dict[str, Any] = {}
    if runs:
        cell = merge(runs, lambda xs: round(statistics.median(xs), 4))
        if len(runs) > 1:
            cell["spread"] = merge(runs, lambda xs: [min(xs), max(xs)])
    cell["runs"] = len(runs)
    if failures:
        cell["failed"] = failures
    return cell


def markdown(report: dict[str, Any]) -> str:
    """The table: medians, with ``(min-max)`` after the RMSEs when a cell has several runs."""
    lines = [
        "| profile | transport | position RMSE (mm) | force RMSE (N) | penetration max (mm) "
        "| packets/s M->S / S->M | newest sample age p99 (ms) M->S / S->M "
        "| channel energy injected (J) | runs |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def pair(d: dict[str, Any], digits: int) -> str:
        return " / ".join("-" if d[k] is None else f"{d[k]:.{digits}f}" for k in ("m2s", "s2m"))

    def with_spread(c: dict[str, Any], key: str) -> str:
        text = f"{c[key]:.2f}"
        if "spread" in c:
            lo, hi = c["spread"][key]
            text += f" ({lo:.2f}-{hi:.2f})"
        return text

    for profile, cells in report["profiles"].items():
        for transport, c in cells.items():
            runs = f"{c['runs']}" + (
                f" ({len(c['failed'])} did not start)" if "failed" in c else ""
            )
            if not c["runs"]:
                lines.append(
                    f"| {profile} | {transport} | did not start: {c['failed'][0]} "
                    f"| - | - | - | - | - | {runs} |"
                )
                continue
            lines.append(
                f"| {profile} | {transport} | {with_spread(c, 'position_rmse_mm')} "
                f"| {with_spread(c, 'force_rmse_n')} "
                f"| {c['penetration_max_mm']:.2f} | {pair(c['packets_per_s'], 0)} "
                f"| {pair(c['age_p99_ms'], 1)} | {c['channel_energy_j']['injected']:.3f} | {runs} |"
            )
    return "\n".join(lines)


def plot(profile: str, logs: dict[str, dict[str, Any]], path: Path) -> None:
    import matplotlib  # noqa: PLC0415 - optional (the plot extra)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    mi = {c: i for i, c in enumerate(sides.MASTER_COLUMNS)}
    si = {c: i for i, c in enumerate(sides.SLAVE_COLUMNS)}
    fig, (ax_pos, ax_force) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    for i, (transport, log) in enumerate(logs.items()):
        master, slave = log["master"], log["slave"]
        t0 = master[0, mi["t"]]
        if i == 0:
            ax_pos.plot(
                master[:, mi["t"]] - t0,
                master[:, mi["x"]] * 1000,
                color="0.6",
                lw=2.5,
                label="operator's device (first transport)",
            )
        ax_pos.plot(
            slave[:, si["t"]] - t0, slave[:, si["x"]] * 1000, lw=1, label=f"{transport}: fingertip"
        )
        ax_force.plot(
            master[:, mi["t"]] - t0, -master[:, mi["fx"]], lw=1, label=f"{transport}: rendered"
        )
    ax_pos.axhline(CONTACT_X * 1000, color="k", ls=":", lw=1, label="wall")
    ax_pos.set_ylabel("x (mm)")
    ax_pos.legend(fontsize=7, loc="lower right")
    ax_force.set_ylabel("wall force felt, -Fx (N)")
    ax_force.set_xlabel("time (s)")
    ax_force.legend(fontsize=7, loc="upper right")
    fig.suptitle(f"closed loop, profile {profile}: {PROFILES[profile]}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    try:
        args = _parse(sys.argv[1:] if argv is None else argv)
    except UsageError as exc:
        print(f"closed_loop.py: {exc}", file=sys.stderr)
        return 2
    warn_if_loaded()
    report: dict[str, Any] = {
        "benchmark": "closed_loop",
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "seconds": args.seconds,
        "repeat": args.repeat,
        "seed": args.seed,
        "deadband_k": args.deadband_k,
        "loop": args.loop,
        "environment": environment(),
        "specs": {p: PROFILES[p] for p in args.profiles},
        "profiles": {},
        "details": {},
    }
    args.out.mkdir(parents=True, exist_ok=True)
    total = len(args.profiles) * len(args.transports) * args.repeat
    done = 0
    for profile in args.profiles:
        cells: dict[str, Any] = {}
        logs: dict[str, dict[str, Any]] = {}
        details: dict[str, list[dict[str, Any]]] = {}
        for transport in args.transports:
            runs = []
            failures: list[str] = []
            for rep in range(args.repeat):
                done += 1
                progress(
                    f"[{done}/{total}] {profile} ({PROFILES[profile]}) over {transport}, run {rep + 1}"
                )
                try:
                    figures, run_logs, run_details = run_once(
                        profile,
                        transport,
                        args.seconds,
                        args.seed * 1000 + rep * 10,
                        args.seed,
                        args.loop,
                        {"deadband_k": args.deadband_k},
                        args.warmup_timeout,
                    )
                except StartupError as exc:
                    progress(f"    did not start: {exc}")
                    failures.append(str(exc))
                    continue
                progress(
                    f"    position RMSE {figures['position_rmse_mm']:.2f} mm, force RMSE "
                    f"{figures['force_rmse_n']:.2f} N, packets/s {figures['packets_per_s']}"
                )
                runs.append(figures)
                details.setdefault(transport, []).append(run_details)
                if transport not in logs:
                    logs[transport] = run_logs
            cells[transport] = _median_cell(runs, failures)
        report["profiles"][profile] = cells
        report["details"][profile] = details
        if not args.no_plots and logs:
            path = args.out / f"closed_loop_{profile}.png"
            plot(profile, logs, path)
            progress(f"    wrote {path}")
    table = markdown(report)
    (args.out / "closed_loop.md").write_text(f"`{report['command']}`\n\n{table}\n")
    (args.out / "closed_loop.json").write_text(json.dumps(report, indent=1) + "\n")
    print(table, file=sys.stderr)
    if args.json:
        print(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
