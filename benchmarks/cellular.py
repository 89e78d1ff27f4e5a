"""Every controller, raw UDP and Zenoh on recorded LTE traces: throughput against one-way delay, each way.

Usage: ``python benchmarks/cellular.py [--quick] [--trace NAME ...] [--controller NAME ...]
[--queue 150kB|15kB ...] [--duration S] [--offsets S,S,...] [--real ROW ...] [--json] [--out DIR]``

**Paths.** Mahimahi's recorded LTE traces (Verizon, T-Mobile, AT&T; GPL, read by path from
``--traces``, by default the first ``shared/traces`` folder above the checkout, never copied here),
one per direction: the ``.down`` trace carries master -> slave (the operator's commands reaching the
robot), the ``.up`` trace slave -> master (the robot's uplink). Each direction: 20 ms of propagation
after a DropTail queue of 150 kB or 15 kB (``limit-bytes``), served at the trace's 1500-byte delivery
opportunities with Mahimahi's semantics (docs/NETEM.md, "Recorded traces"). The traces start
``--offsets`` seconds in (several stretches of each trace: the spread of a figure is over them).

**Load.** Both ends offer one 100-byte sample per millisecond for ``--duration`` seconds (60; --quick 5).

**Rows.** ``ideal``: computed from the trace itself, the trace's own capacity with nothing queued (the
newest samples ride each opportunity; tdtp.sim.scenarios.cellular.ideal). ``oracle``: also from the
trace, the most samples a sender that knew the trace's future could deliver with every one within
60 ms (tdtp.sim.scenarios.cellular.deadline): where it meets issue 32's bars, they are reachable on
that trace, by a sender that could see the capacity coming. Every controller
registered in ``tdtp.control`` (the default marked) and ``udp`` (raw UDP: 1 kHz, no header, no
feedback) run in **virtual time** (tdtp.sim: the unchanged Connection, the same trace queue as the
emulator; deterministic, immune to the machine's load). ``--real`` rows run on **real sockets** in
wall-clock time, the others' load reported beside them: ``zenoh`` (eclipse-zenoh, best effort,
express, through ``tdtp netem-relay``), ``udp-real`` (two plain asyncio sockets through the relay),
and ``CONTROLLER-real`` (tdtp with its in-process netem, a cross-check of the virtual-time rows).
Real-socket links count 28 bytes of IPv4 + UDP headers per datagram (``overhead 28``), as the
simulator's packets do.

**Figures**, each way, over the samples generated in the window (tdtp.sim.scenarios.cellular):
samples/s delivered and their share of what the trace allowed (min(offered, capacity) per 100 ms,
counted in 128-byte samples); one-way delay p50/p95/p99 from generation to delivery; dropouts (100 ms
windows of the receiver's timeline with no sample); age p99 of the newest sample. Medians over the
offsets, min-max spreads. A throughput-vs-p95-delay plot per trace (Pantheon's way), the JSON and a
Markdown table in ``--out``: by default benchmarks/results/cellular for the full run only (a --quick
or filtered run writes no file unless --out is given, so it never replaces the results of record).

Issue 32's targets (default controller, 150 kB, each direction): p95 <= 60 ms, p99 <= 150 ms,
>= 90 % of what the trace allowed.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import multiprocessing
import struct
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
import paths
from _common import Json, Row, Stat
from paths import Meter

import tdtp
import tdtp.control
from tdtp.sim.scenarios import cellular as scenario

TRACES: dict[str, str] = {
    "verizon": "Verizon-LTE-short",
    "tmobile": "TMobile-LTE-short",
    "att": "ATT-LTE-driving-2016",
}
QUEUES: dict[str, int] = {"150kB": 150_000, "15kB": 15_000}
COMPUTED = ("ideal", "oracle")
"""Rows computed from the trace alone, not run."""
DELAY = "20ms"
PROPAGATION = 0.020
RATE = 1000.0
SIZE = scenario.SAMPLE_SIZE
UDP_IP = 28
DURATION, QUICK_DURATION = 60.0, 5.0
OFFSETS, QUICK_OFFSETS = (0.0, 20.0, 40.0, 60.0, 80.0), (0.0,)
REAL_DEFAULT, REAL_QUICK = ("udp-real", "zenoh", "teleop-real"), ("udp-real", "zenoh")
REAL_OFFSETS = (0.0,)
STAMP = struct.Struct("<dI")
PROBE = 0xFFFFFFFF
TARGET_P95, TARGET_P99, TARGET_SHARE = 60.0, 150.0, 0.90
WAYS = {"ms": "M->S (.down)", "sm": "S->M (.up)"}


def find_traces() -> Path | None:
    root = Path(__file__).resolve().parent.parent
    for folder in (root, *root.parents):
        candidate = folder / "shared" / "traces"
        if candidate.is_dir():
            return candidate
    return None


def spec(traces: Path, trace: str, way: str, queue: int, offset: float, overhead: int) -> str:
    """One direction's netem spec: the trace's .down for M->S, .up for S->M."""
    suffix = "down" if way == "ms" else "up"
    text = f"delay {DELAY} trace {traces / TRACES[trace]}.{suffix}"
    if offset:
        text += f" offset {offset:g}s"
    if overhead:
        text += f" overhead {overhead}"
    return f"{text} limit-bytes {queue}"


def with_allowed(figures: Json, allowed: float, duration: float) -> Json:
    """The direction's figures with what the trace allowed beside them."""
    return {**figures, "allowed": allowed, "allowed_per_s": allowed / duration}


# ---------------------------------------------------------------------------- virtual time


def sim_job(job: Json) -> Json:
    """One virtual-time run (in a pool worker): the figures each way and what the trace allowed."""
    t0 = time.process_time()
    ms, sm = job["ms"], job["sm"]
    if job["row"] == "udp":
        run = scenario.run_udp(ms, sm, duration=job["duration"], seed=job["seed"])
    else:
        run = scenario.run_tdtp(ms, sm, job["row"], duration=job["duration"], seed=job["seed"])
    out: Json = {**job, "time": "virtual", "links": run.links, "senders": run.senders}
    for way, arrivals, text in (("ms", run.ms, ms), ("sm", run.sm, sm)):
        allowed = scenario.allowed(text, start=arrivals.start, duration=job["duration"])
        out[way] = with_allowed(run.figures[way], allowed, job["duration"])
    out["cpu_seconds"] = round(time.process_time() - t0, 2)
    return out


ORACLE_BOUND = 0.060
"""The deadline oracle's bound: issue 32's p95 target, met by every sample."""


def ideal_job(job: Json) -> Json:
    """A row computed from the trace alone: ``ideal`` or ``oracle``."""
    out: Json = {**job, "time": "computed"}
    for way in ("ms", "sm"):
        if job["row"] == "oracle":
            arrivals = scenario.deadline(
                job[way], start=0.0, duration=job["duration"], bound=ORACLE_BOUND
            )
        else:
            arrivals = scenario.ideal(job[way], start=0.0, duration=job["duration"])
        figures = scenario.direction_figures(arrivals, propagation=PROPAGATION)
        allowed = scenario.allowed(job[way], start=0.0, duration=job["duration"])
        out[way] = with_allowed(figures, allowed, job["duration"])
    return out


# ---------------------------------------------------------------------------- real sockets


async def window(
    logs: tuple[Meter, Meter], senders: tuple[Callable[[bytes], None], ...], duration: float
) -> list[int]:
    """Both ends send a stamped sample every millisecond for ``duration``; then wait for the
    queues to drain (nothing arriving for 0.3 s, at most 8 s)."""
    start = tdtp.monotonic() + 0.01
    for log in logs:
        log.start, log.until = start, start + duration

    async def send(emit: Callable[[bytes], None]) -> int:
        await asyncio.sleep(max(0.0, start - tdtp.monotonic()))
        count = 0
        async for _ in tdtp.Ticker(RATE):
            now = tdtp.monotonic()
            if now >= start + duration:
                return count
            emit(STAMP.pack(now, count).ljust(SIZE, b"\0"))
            count += 1
        return count

    offered = await asyncio.gather(*(send(s) for s in senders))
    stop = tdtp.monotonic() + 8.0
    while tdtp.monotonic() < stop:
        if tdtp.monotonic() - max(log.last_arrival for log in logs) > 0.3:
            break
        await asyncio.sleep(0.02)
    return [int(n) for n in offered]


async def tdtp_real(controller: str, ms: str, sm: str, duration: float, seed: int) -> Json:
    logs = (Meter(), Meter())
    async with contextlib.AsyncExitStack() as stack:
        origin = tdtp.monotonic()  # the links' traces start with the first datagrams, just after
        master, slave = await paths.tdtp_pair(stack, controller, logs, ms=ms, sm=sm, seed=seed)
        offered = await window(logs, (master.send, slave.send), duration)
        closed = master.is_closed or slave.is_closed
    return {"logs": logs, "offered": offered, "origin": origin, "closed": closed}


async def relayed(row: str, ms: str, sm: str, duration: float, seed: int) -> Json:
    """``udp-real`` or ``zenoh`` through ``tdtp netem-relay`` (ms forward, sm back)."""
    at_slave, at_master = Meter(), Meter()
    logs = (at_slave, at_master)
    kind = "udp" if row == "udp-real" else row
    async with paths.baseline_pair(
        kind, ms, seed, at_slave.arrived, at_master.arrived, return_spec=sm
    ) as pair:
        await paths.wait_for_probes(logs, pair.senders, row)
        offered = await window(logs, pair.senders, duration)
    summary = pair.relay_summary
    return {
        "logs": logs,
        "offered": offered,
        "origin": pair.opened_at,
        "relay": {"forward": summary["forward"], "return": summary["return"]},
    }


def real_worker(conn: Any, *, job: Json) -> None:
    loop = "uvloop" if common.have_uvloop() else "asyncio"
    row, ms, sm, duration, seed = job["row"], job["ms"], job["sm"], job["duration"], job["seed"]

    async def run() -> Json:
        if row.endswith("-real") and row != "udp-real":
            return await tdtp_real(row.removesuffix("-real"), ms, sm, duration, seed)
        return await relayed(row, ms, sm, duration, seed)

    result = common.run_in_loop(loop, run)
    at_slave, at_master = result.pop("logs")
    out: Json = {"loop": loop, **{k: v for k, v in result.items() if k != "offered"}}
    for way, log, text, offered in (
        ("ms", at_slave, ms, result["offered"][0]),
        ("sm", at_master, sm, result["offered"][1]),
    ):
        arrivals = scenario.Arrivals(log.start, log.start + duration, offered)
        arrivals.generated, arrivals.arrived = log.sent_times, log.arrival_times
        figures = scenario.direction_figures(arrivals, propagation=PROPAGATION)
        allowed = scenario.allowed(
            text, start=log.start, duration=duration, origin=result["origin"]
        )
        out[way] = with_allowed(figures, allowed, duration)
    conn.send(out)


def run_real(job: Json) -> Json:
    others = common.OthersMeter()
    handle = common.start_worker(f"cellular-{job['row']}", real_worker, job=job)
    try:
        result = handle.recv(timeout=job["duration"] + 60.0)
    finally:
        handle.finish()
    return {**job, **result, "time": "real", "others_percent": others.percent()}


# ---------------------------------------------------------------------------- summaries


FIGURES: dict[str, Callable[[Json], float]] = {
    "samples_per_s": lambda w: w["samples_per_s"],
    "share": lambda w: w["delivered"] / w["allowed"] if w["allowed"] else math.nan,
    "p50_ms": lambda w: w["delay_ms"]["p50"],
    "p95_ms": lambda w: w["delay_ms"]["p95"],
    "p99_ms": lambda w: w["delay_ms"]["p99"],
    "dropouts": lambda w: w["dropouts"],
    "age_p99_ms": lambda w: w["age_ms"]["p99"],
    "allowed_per_s": lambda w: w["allowed_per_s"],
}
"""What is summarised per cell and direction (median and min-max over the offsets)."""


def summarise(runs: Sequence[Json]) -> Json:
    out: Json = {"runs": len(runs), "time": runs[0]["time"]}
    for way in ("ms", "sm"):
        out[way] = {}
        for name, get in FIGURES.items():
            values = [get(r[way]) for r in runs]
            stat = Stat.of(values)
            out[way][name] = {"median": stat.median, "min": stat.min, "max": stat.max}
    others = [r["others_percent"] for r in runs if "others_percent" in r]
    if others:
        out["others_percent"] = max(others)
    return out


def fmt(value: float, digits: int = 0) -> str:
    return "-" if value is None or math.isnan(value) else f"{value:,.{digits}f}"


def cell_text(stat: Json, key: str, digits: int = 0, scale: float = 1.0) -> str:
    s = stat[key]
    median = fmt(s["median"] * scale, digits)
    if s["min"] == s["max"] or math.isnan(s["min"]):
        return median
    return f"{median} ({fmt(s['min'] * scale, digits)}-{fmt(s['max'] * scale, digits)})"


def row_label(row: str, default: str) -> str:
    labels = {
        "ideal": "ideal (trace, nothing queued)",
        "oracle": f"oracle (knows the trace, all within {ORACLE_BOUND * 1e3:.0f} ms)",
        "udp": "raw UDP, fixed 1 kHz",
        "udp-real": "raw UDP, fixed 1 kHz",
        "zenoh": "Zenoh (best effort)",
    }
    if row in labels:
        return labels[row]
    name = row.removesuffix("-real")
    return f"tdtp {name}" + (" (default)" if name == default else "")


def markdown(summary: Json, default: str) -> str:
    lines = [
        "Each direction: delivered samples/s (% of what the trace allowed, min(offered, capacity) "
        "per 100 ms); one-way delay p50 / p95 / p99 in ms from generation to delivery; dropouts "
        "(100 ms windows without a sample); age p99 of the newest sample (ms). Medians over the "
        "trace offsets, min-max in brackets. *time*: computed from the trace, virtual (the "
        "simulator: deterministic), or real sockets (wall clock; the other tenants' CPU beside it).",
        "",
        "| trace | queue | row | time | way | samples/s | % allowed | p50 | p95 | p99 "
        "| dropouts | age p99 |",
        "| --- | --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for trace, queues in summary.items():
        for queue, rows in queues.items():
            for row, s in rows.items():
                when = s["time"]
                if when == "real":
                    when = f"real ({fmt(s.get('others_percent', math.nan))} % others)"
                for way, label in WAYS.items():
                    w = s[way]
                    lines.append(
                        f"| {trace} | {queue} | {row_label(row, default)} | {when} | {label} "
                        f"| {cell_text(w, 'samples_per_s')} | {cell_text(w, 'share', 0, 100)} "
                        f"| {cell_text(w, 'p50_ms')} | {cell_text(w, 'p95_ms')} "
                        f"| {cell_text(w, 'p99_ms')} | {cell_text(w, 'dropouts')} "
                        f"| {cell_text(w, 'age_p99_ms')} |"
                    )
    return "\n".join(lines)


def suite_rows(summary: Json, default: str) -> list[Row]:
    """For the suite's table: the default controller's worse direction per trace and queue, p95
    and p99 against the ideal's, and its share of what the trace allowed, with issue 32's targets."""
    rows: list[Row] = []
    for trace, queues in summary.items():
        for queue, cells in queues.items():
            if default not in cells:
                continue
            ours, ideal = cells[default], cells.get("ideal")
            for figure, target in (("p95_ms", TARGET_P95), ("p99_ms", TARGET_P99)):
                way = max(("ms", "sm"), key=lambda w, f=figure: ours[w][f]["median"])
                value = ours[way][figure]
                rows.append(
                    Row(
                        "cellular",
                        f"{trace} {queue}, {default} ({WAYS[way]}, virtual time): one-way delay "
                        f"{figure[:3]}",
                        "ms",
                        Stat(
                            value["median"],
                            value["min"],
                            value["max"],
                            math.nan,
                            math.nan,
                            ours["runs"],
                        ),
                        baseline="ideal (the trace, nothing queued)" if ideal else "",
                        baseline_value=_stat(ideal[way][figure], ideal["runs"]) if ideal else None,
                        ratio=_stat(
                            {k: value[k] / ideal[way][figure]["median"] for k in value},
                            ours["runs"],
                        )
                        if ideal
                        else None,
                        ratio_label="x ideal",
                        target=f"<= {target:.0f} ms each way (issue 32, 150 kB)"
                        if queue == "150kB"
                        else "",
                        meets=value["median"] <= target if queue == "150kB" else None,
                        digits=0,
                    )
                )
            way = min(("ms", "sm"), key=lambda w: ours[w]["share"]["median"])
            share = ours[way]["share"]
            rows.append(
                Row(
                    "cellular",
                    f"{trace} {queue}, {default} ({WAYS[way]}): share of what the trace allowed",
                    "%",
                    _stat({k: 100 * v for k, v in share.items()}, ours["runs"]),
                    target=f">= {100 * TARGET_SHARE:.0f} % each way (issue 32, 150 kB)"
                    if queue == "150kB"
                    else "",
                    meets=share["median"] >= TARGET_SHARE if queue == "150kB" else None,
                    digits=0,
                )
            )
    return rows


def _stat(s: Json, n: int) -> Stat:
    return Stat(s["median"], s["min"], s["max"], math.nan, math.nan, n)


# ---------------------------------------------------------------------------- the plot

MARKERS = {"ideal": "*", "oracle": "P", "udp": "x", "udp-real": "X", "zenoh": "s"}
CONTROLLER_MARKERS = "o^Dv<>ph"


def plot(summary: Json, default: str, out: Path) -> list[Path]:
    """Per trace: delivered share of what the trace allowed against p95 one-way delay (log, better
    to the left), each direction in its own panel; 150 kB filled, 15 kB hollow; bars are the
    min-max over the offsets."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib import ticker  # noqa: PLC0415

    written = []
    controllers = list(tdtp.control.available_controllers())
    for trace, queues in summary.items():
        fig, axes = plt.subplots(1, 2, figsize=(12, 5.5), sharey=True)
        names = list(dict.fromkeys(row for rows in queues.values() for row in rows))
        for ax, (way, label) in zip(axes, WAYS.items(), strict=True):
            for queue, rows in queues.items():
                for row, s in rows.items():
                    if row in COMPUTED and queue != next(iter(queues)):
                        continue  # the ideal does not depend on the queue: once is enough
                    w = s[way]
                    base = row.removesuffix("-real")
                    marker = (
                        MARKERS.get(row)
                        or CONTROLLER_MARKERS[
                            controllers.index(base) % len(CONTROLLER_MARKERS)
                            if base in controllers
                            else 0
                        ]
                    )
                    x, y = w["p95_ms"], w["share"]
                    real = " (real sockets)" if s["time"] == "real" else ""
                    ax.errorbar(
                        [x["median"]],
                        [100 * y["median"]],
                        xerr=[[x["median"] - x["min"]], [x["max"] - x["median"]]],
                        yerr=[[100 * (y["median"] - y["min"])], [100 * (y["max"] - y["median"])]],
                        fmt=marker,
                        markersize=12 if row in COMPUTED else 8,
                        mfc=None if queue == "150kB" else "none",
                        color=f"C{names.index(row) % 10}",
                        capsize=2,
                        label=f"{row_label(row, default)}{real}"
                        + ("" if row in COMPUTED else f", {queue}"),
                    )
            ax.set_xscale("log")
            ax.xaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
            ax.xaxis.set_minor_formatter(
                ticker.FuncFormatter(lambda v, _: f"{v:g}" if f"{v:g}"[0] in "235" else "")
            )
            ax.tick_params(axis="x", which="minor", labelsize=7)
            ax.set_xlabel("one-way delay p95 (ms, log)")
            ax.set_title(f"{trace}: {label}")
            ax.axvline(TARGET_P95, color="grey", lw=0.8, ls=":")
            ax.axhline(100 * TARGET_SHARE, color="grey", lw=0.8, ls=":")
            ax.grid(True, which="both", alpha=0.3)
        axes[0].set_ylabel("samples delivered, % of what the trace allowed")
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=7, frameon=False)
        fig.suptitle(
            f"{TRACES[trace]}: 1 kHz x 100 B each way, {DELAY} each way; filled 150 kB, hollow "
            "15 kB; better is up and left"
        )
        fig.tight_layout(rect=(0, 0.12, 1, 1))
        path = out / f"cellular_{trace}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


# ---------------------------------------------------------------------------- command line


def parse_args(argv: Sequence[str] | None) -> Any:
    doc = __doc__ or ""
    p = common.OneLineParser(prog="cellular.py", description=doc.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="5 s runs, one offset, for make bench")
    p.add_argument("--duration", type=float, help="seconds per run (60; --quick 5)")
    p.add_argument("--offsets", help="seconds into the traces, comma-separated (0,20,40,60,80)")
    p.add_argument("--trace", nargs="+", metavar="NAME", help=f"of: {', '.join(TRACES)}")
    p.add_argument("--queue", nargs="+", metavar="SIZE", help=f"of: {', '.join(QUEUES)}")
    p.add_argument(
        "--controller",
        nargs="+",
        metavar="NAME",
        help="virtual-time rows: registered controllers and/or udp (all of them)",
    )
    p.add_argument(
        "--real",
        nargs="*",
        metavar="ROW",
        help="real-socket rows: zenoh, udp-real, CONTROLLER-real (zenoh udp-real teleop-real; "
        "--quick: zenoh udp-real); --real with none: no real-socket row",
    )
    p.add_argument("--real-offsets", help="offsets of the real-socket rows (0)")
    p.add_argument("--traces", type=Path, help="folder of the trace files (shared/traces above)")
    p.add_argument("--jobs", type=int, default=2, help="virtual-time runs in parallel (2)")
    p.add_argument("--seed", type=int, default=1, help="seed of the runs (1; + the offset's index)")
    p.add_argument("--out", type=Path, help="table, JSON and PNGs (benchmarks/results/cellular)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNGs")
    p.add_argument("--json", action="store_true", help="one JSON report on stdout")
    args = p.parse_args(argv)
    # Only the full default run writes the results of record; a partial one writes where told.
    complete = not any(
        given is not None
        for given in (
            args.duration,
            args.offsets,
            args.trace,
            args.queue,
            args.controller,
            args.real,
            args.real_offsets,
        )
    )
    if args.duration is None:
        args.duration = QUICK_DURATION if args.quick else DURATION
    if not 1.0 <= args.duration <= 3600.0:
        p.error(f"--duration: give seconds between 1 and 3600, got {args.duration:g}")
    try:
        args.offsets = (
            tuple(float(x) for x in args.offsets.split(","))
            if args.offsets
            else (QUICK_OFFSETS if args.quick else OFFSETS)
        )
        args.real_offsets = (
            tuple(float(x) for x in args.real_offsets.split(","))
            if args.real_offsets
            else REAL_OFFSETS
        )
    except ValueError:
        p.error("--offsets/--real-offsets: give seconds separated by commas, e.g. 0,20,40")
    if any(not (0 <= o < 1e6) for o in (*args.offsets, *args.real_offsets)):
        p.error("--offsets: give non-negative seconds")
    if not 1 <= args.jobs <= 64:
        p.error(f"--jobs: give 1 to 64, got {args.jobs}")
    for name, given, known in (("--trace", args.trace, TRACES), ("--queue", args.queue, QUEUES)):
        unknown = [n for n in given or () if n not in known]
        if unknown:
            p.error(f"{name}: unknown {', '.join(unknown)}; known: {', '.join(known)}")
    controllers = tdtp.control.available_controllers()
    virtual = (*controllers, "udp")
    unknown = [n for n in args.controller or () if n not in virtual]
    if unknown:
        p.error(f"--controller: unknown {', '.join(unknown)}; known: {', '.join(virtual)}")
    real_known = ("zenoh", "udp-real", *(f"{c}-real" for c in controllers))
    if args.real is None:
        args.real = list(REAL_QUICK if args.quick else REAL_DEFAULT)
    unknown = [n for n in args.real if n not in real_known]
    if unknown:
        p.error(f"--real: unknown {', '.join(unknown)}; known: {', '.join(real_known)}")
    args.trace = list(args.trace or TRACES)
    args.queue = list(args.queue or QUEUES)
    args.controller = list(dict.fromkeys(args.controller or virtual))
    traces = args.traces or find_traces()
    if traces is None:  # not a misuse: this machine has no traces (the suite skips the benchmark)
        args.seconds, args.repeat = args.duration, len(args.offsets)
        return args
    missing = [
        f"{TRACES[t]}.{d}"
        for t in args.trace
        for d in ("up", "down")
        if not (traces / f"{TRACES[t]}.{d}").is_file()
    ]
    if missing:
        p.error(f"--traces: {traces} lacks {', '.join(missing)}")
    args.traces = traces.resolve()
    if args.out is None and complete and not args.quick:
        args.out = common.RESULTS / "cellular"
    args.seconds, args.repeat = args.duration, len(args.offsets)  # what common.emit reports
    return args


def progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def brief(result: Json) -> str:
    ms, sm = result["ms"], result["sm"]
    return (
        f"{ms['samples_per_s']:.0f} / {sm['samples_per_s']:.0f} samples/s "
        f"({100 * ms['delivered'] / ms['allowed']:.0f} / {100 * sm['delivered'] / sm['allowed']:.0f} % "
        f"allowed), p95 {ms['delay_ms']['p95']:.0f} / {sm['delay_ms']['p95']:.0f} ms, p99 "
        f"{ms['delay_ms']['p99']:.0f} / {sm['delay_ms']['p99']:.0f} ms"
    )


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    default = tdtp.control.DEFAULT_CONTROLLER
    if args.traces is None:
        why = "no shared/traces folder above the checkout (give --traces): nothing measured"
        progress(f"cellular.py: {why}")
        return common.emit("cellular", args, [], details={"skipped": {"all": why}}, text=why)
    skipped: Json = {}
    if "zenoh" in args.real and (why := paths.zenoh_missing()):
        progress(why)
        skipped["zenoh"] = why
        args.real.remove("zenoh")
    started = time.monotonic()
    results: list[Json] = []

    def job(trace: str, queue: str, row: str, offset: float, index: int, overhead: int) -> Json:
        return {
            "trace": trace,
            "queue": queue,
            "row": row,
            "offset": offset,
            "seed": args.seed + index,
            "duration": args.duration,
            "ms": spec(args.traces, trace, "ms", QUEUES[queue], offset, overhead),
            "sm": spec(args.traces, trace, "sm", QUEUES[queue], offset, overhead),
        }

    # The ideal and the oracle: from the trace alone (the same for both queues).
    for trace in args.trace:
        for i, offset in enumerate(args.offsets):
            for row in COMPUTED:
                result = ideal_job(job(trace, args.queue[0], row, offset, i, 0))
                for queue in args.queue:
                    results.append({**result, "queue": queue})
    # Virtual time: every controller and raw UDP, in a pool.
    sim_jobs = [
        job(trace, queue, row, offset, i, 0)
        for trace in args.trace
        for queue in args.queue
        for row in args.controller
        for i, offset in enumerate(args.offsets)
    ]
    if sim_jobs:
        progress(f"{len(sim_jobs)} virtual-time runs of {args.duration:g} s, {args.jobs} at a time")
        context = multiprocessing.get_context("spawn")
        with context.Pool(min(args.jobs, len(sim_jobs))) as pool:
            for n, result in enumerate(pool.imap(sim_job, sim_jobs), 1):
                results.append(result)
                progress(
                    f"[{n}/{len(sim_jobs)}] {result['trace']} {result['queue']} {result['row']} "
                    f"offset {result['offset']:g}s (virtual, {result['cpu_seconds']:.1f} s CPU): "
                    f"{brief(result)}"
                )
    # Real sockets, one at a time, after the pool has gone (so that it does not load them).
    real_jobs = [
        job(trace, queue, row, offset, i, UDP_IP)
        for trace in args.trace
        for queue in args.queue
        for row in args.real
        for i, offset in enumerate(args.real_offsets)
    ]
    if real_jobs:
        common.warn_if_loaded()
    for n, real in enumerate(real_jobs, 1):
        label = f"[{n}/{len(real_jobs)}] {real['trace']} {real['queue']} {real['row']}"
        progress(f"{label} offset {real['offset']:g}s (real sockets, {args.duration:g} s) ...")
        try:
            result = run_real(real)
        except RuntimeError as exc:
            progress(f"{label}: failed: {exc}")
            skipped[f"{real['trace']} {real['queue']} {real['row']}"] = str(exc)[-300:]
            continue
        results.append(result)
        progress(
            f"{label}: {brief(result)}; other tenants {result['others_percent']:.0f} % of a core"
        )
    summary: Json = {}
    for trace in args.trace:
        summary[trace] = {}
        for queue in args.queue:
            cells: Json = {}
            for row in (*COMPUTED, *args.controller, *args.real):
                runs = [
                    r
                    for r in results
                    if r["trace"] == trace and r["queue"] == queue and r["row"] == row
                ]
                if runs:
                    cells[row] = summarise(runs)
            summary[trace][queue] = cells
    wall = time.monotonic() - started
    table = markdown(summary, default)
    text = (
        f"{len(args.trace)} traces x {len(args.queue)} queues, {args.duration:g} s per run, "
        f"offsets {', '.join(f'{o:g}' for o in args.offsets)} s (virtual time; real sockets: "
        f"{', '.join(f'{o:g}' for o in args.real_offsets)} s), 100-byte samples at 1 kHz each "
        f"way, {DELAY} each way; default controller: {default}; {wall:.0f} s.\n\n{table}"
    )
    details: Json = {
        "default_controller": default,
        "traces": {t: TRACES[t] for t in args.trace},
        "trace_folder": str(args.traces),
        "summary": summary,
        "runs": results,
        "skipped": skipped,
        "wall_seconds": round(wall, 1),
    }
    if args.out is not None:
        out: Path = args.out
        out.mkdir(parents=True, exist_ok=True)
        common.write_text(out / "cellular.md", text + "\n")
        common.write_text(
            out / "cellular.json",
            json.dumps({"command": " ".join(sys.argv), **details}, indent=1, default=str) + "\n",
        )
        if not args.no_plots:
            for path in plot(summary, default, out):
                progress(f"written: {path}")
    return common.emit("cellular", args, suite_rows(summary, default), details=details, text=text)


if __name__ == "__main__":
    sys.exit(main())
