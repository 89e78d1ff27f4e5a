"""What a perceptual deadband costs TDTP's piggybacked ACKs: wire bytes, ACK coverage, RTT freshness.

Usage: ``python benchmarks/deadband_cost.py [--seconds 10] [--repeat 3] [--k 0.1]
[--netem 'delay 20ms 5ms loss 2%'] [--quick] [--json]``

Method. A master and a slave :class:`~tdtp.Connection` in virtual time, each direction through its
own in-process :class:`~tdtp.netem.NetemLink` (as ``tdtp demo --netem`` does on real sockets, and as
``virtual_paths.py`` runs them): time jumps from event to event, so no machine load changes a figure
and a run is a function of its seed. Two paths: ``loopback`` (``delay 50us``, about what a loopback
round trip costs) and ``--netem``. Both sides offer the demo's haptic signal at 1 kHz for
``--seconds`` after a one-second start-up that is not counted: the master an operator's hand
(:func:`tdtp.teleop.haptic_sample.operator_motion`: reach, press and slide along a wall, retreat,
with tremor), the slave the wall's force on the position it last received
(:func:`~tdtp.teleop.haptic_sample.slave_feedback`). Five modes:

- ``tdtp``: every sample a packet, ACKs piggybacked (the default);
- ``tdtp+deadband``: a :class:`~tdtp.teleop.deadband.DeadbandSender` with Weber fraction ``--k`` on
  each side (position and force, the demo's floors of 0.5 mm and 0.05 N, heartbeat 100 ms): ACKs
  ride on the reverse samples when there are any, and go stand-alone otherwise;
- ``tdtp+deadband, ack_delay 2 ms``: the same, both sides configured to send a stand-alone ACK
  after 2 ms instead of 20 ms (``ConnectionConfig.ack_delay``; how the stand-alone ACKs of a sparse
  stream trade packets for feedback delay);
- ``separate``: ``AckMode.SEPARATE``, Trinomial's one ACK per data packet (the paper's comparison);
- ``separate+deadband``: the same with the deadband.

Per direction (``M->S``: what the master sends, its data and the ACKs it returns for the slave's):
packets/s by kind (data, stand-alone ACKs, and control packets: in the window, KEEPALIVEs) and wire bytes/s with 28 bytes of IPv4 + UDP per datagram; the share of offered
samples sent; **ACK coverage**, the share of the data packets sent that the sender saw acknowledged;
the **feedback delay**, from sending a data packet to the first acknowledgement at or above it
(acknowledged or reported absent: when the sender learns its fate), p50/p99; **RTT freshness**, the
age of the sender's newest RTT sample, read every 10 ms, p50/p99; the receiver's **sample age**
(``stats.sample_age_p50``/``_p99``, docs/PROTOCOL.md 3.6) and the share of its samples their own
header timed; and the receiver's **reconstruction error**: every 1 ms tick, the distance between
what the sender offered and what the receiver holds (the last sample it got), RMS over the run, in
mm (position) or N (force). It includes the path's delay, so compare it across modes.

The rows (``--json``: ``rows``) give both directions' wire rate of each mode against plain TDTP in
the same run; the tables (``text``) give everything, medians over ``--repeat`` seeds with the range.
"""

from __future__ import annotations

import argparse
import math
import random
import statistics
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat

from tdtp import AckMode, Connection, ConnectionConfig, DataReceived, Role, State
from tdtp.cli.options import DEADBAND_FLOORS
from tdtp.netem import NetemLink, parse_netem
from tdtp.netem.parser import NetemSyntaxError
from tdtp.teleop.deadband import DeadbandConfig, DeadbandReceiver, DeadbandSender
from tdtp.teleop.haptic_sample import HapticSample, master_trajectory, slave_feedback

MASTER = ("192.0.2.1", 40001)
SLAVE = ("192.0.2.2", 40002)
IP_UDP = 28
RATE = 1000.0
SIZE = 36  # the haptic sample, unpadded
WARMUP = 1.0
DRAIN = 1.0  # after the last sample, until every packet of the window has its verdict
PROBE = 0.01  # RTT freshness is read every 10 ms
LOOPBACK = "delay 50us"
DEFAULT_NETEM = "delay 20ms 5ms loss 2%"
QUICK_SECONDS = 2.0
MODES = ("tdtp", "tdtp+deadband", "tdtp+deadband, ack_delay 2 ms", "separate", "separate+deadband")
FAST_ACK_DELAY = 0.002
WAYS = ("M->S", "S->M")


@dataclass
class Side:
    name: str
    conn: Connection
    addr: tuple[str, int]
    link: NetemLink
    band: DeadbandSender | None
    held: DeadbandReceiver = field(default_factory=DeadbandReceiver)
    """What this side holds of the peer's values (the last sample received)."""
    last_position: tuple[float, ...] = (0.0, 0.0, 0.0)
    offered: int = 0
    send_times: dict[int, float] = field(default_factory=dict)
    """Full sequence number -> send time of our data packets not yet covered by an ACK."""
    next_seq: int = 0
    largest_acked: int = -1
    feedback_delays: list[float] = field(default_factory=list)
    rtt_samples: int = 0
    last_rtt_at: float = math.nan
    freshness: list[float] = field(default_factory=list)
    squared_error: float = 0.0
    error_ticks: int = 0
    base: dict[str, int] = field(default_factory=dict)
    stop: dict[str, int] = field(default_factory=dict)


def _counters(conn: Connection) -> dict[str, int]:
    stats = conn.stats
    sent = stats.sent
    return {
        "datagrams": sent.datagrams,
        "bytes": sent.bytes,
        "data": sent.data_packets,
        "acks": sent.ack_packets,
        "control": sent.control_packets,
        "acked": stats.packets_acked,
        "unreported": stats.packets_unreported,
        # Every data packet that arrived, whether delivered or dropped as late (both acknowledged).
        "received": stats.received.data_packets + stats.drops.get("late", 0),
        "delivered": stats.samples_delivered,
        "timed": stats.samples_timed,
    }


def run(mode: str, profile: str, *, seed: int, seconds: float, k: float) -> dict[str, Json]:
    """One session in virtual time; per direction, the figures of the module docstring."""
    separate = mode.startswith("separate")
    config = ConnectionConfig(
        ack_mode=AckMode.SEPARATE if separate else AckMode.BIDIRECTIONAL,
        ack_delay=FAST_ACK_DELAY if mode.endswith("2 ms") else ConnectionConfig().ack_delay,
    )
    spec = parse_netem(profile)
    rng = random.Random(seed)

    def band(floor: float) -> DeadbandSender | None:
        if "deadband" not in mode:
            return None
        return DeadbandSender(groups=[(0, 1, 2)], config=DeadbandConfig(k=k, min_threshold=floor))

    master = Side(
        "master",
        Connection(config, role=Role.MASTER, rng=random.Random(rng.random())),
        MASTER,
        NetemLink(spec, seed=rng.getrandbits(32)),
        band(DEADBAND_FLOORS["position"]),
    )
    slave = Side(
        "slave",
        Connection(config, role=Role.SLAVE, rng=random.Random(rng.random())),
        SLAVE,
        NetemLink(spec, seed=rng.getrandbits(32)),
        band(DEADBAND_FLOORS["force"]),
    )
    peer = {"master": slave, "slave": master}
    now = 0.0
    master.conn.connect(SLAVE, now=now)
    started: float | None = None
    next_tick = next_probe = math.inf
    end = stop = math.inf

    def flush(side: Side, t: float) -> None:
        for datagram, _addr in side.conn.datagrams_to_send(now=t):
            side.link.send(datagram, t)
        log = side.conn._recovery.sent  # a benchmark's probe: the sequence numbers sent
        while side.next_seq < log.next_seq:
            side.send_times[side.next_seq] = t
            side.next_seq += 1

    def heard(side: Side, t: float) -> None:
        """After a datagram reached ``side``: feedback delays, RTT samples, samples delivered."""
        log = side.conn._recovery.sent
        if side.largest_acked < 0:
            side.largest_acked = log.first_seq - 1
        if log.largest_acked > side.largest_acked:
            for seq in range(side.largest_acked + 1, log.largest_acked + 1):
                sent_at = side.send_times.pop(seq, None)
                if sent_at is not None and WARMUP <= sent_at < stop:
                    side.feedback_delays.append(t - sent_at)
            side.largest_acked = log.largest_acked
        samples = side.conn.stats.rtt_samples
        if samples != side.rtt_samples:
            side.rtt_samples, side.last_rtt_at = samples, t
        while (event := side.conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                sample = HapticSample.decode(event.payload)
                if sample is not None:
                    values = sample.position if side is slave else sample.force
                    side.held.receive(values, now=t)
                    if side is slave:
                        side.last_position = sample.position

    def tick(t: float, index: int) -> None:
        elapsed = t - (started or 0.0)
        offers: dict[str, tuple[float, ...]] = {}
        for side in (master, slave):
            if side.conn.state is not State.ESTABLISHED:
                continue
            if side is master:
                sample = master_trajectory(elapsed, index, t)
                values = sample.position
            else:
                sample = slave_feedback(side.last_position, index, t)
                values = sample.force
            offers[side.name] = values
            if t >= WARMUP:
                side.offered += 1
            if side.band is None or side.band.offer(values, now=t):
                side.conn.send(sample.encode(SIZE), now=t)
        if t >= WARMUP:
            for name, values in offers.items():
                receiver = peer[name]
                held = receiver.held.value_at(t)
                if held is not None:
                    scale = 1e3 if name == "master" else 1.0  # mm, N
                    error = math.dist(values, held) * scale
                    receiver.squared_error += error * error
                    receiver.error_ticks += 1

    index = 0
    while now < end:
        candidates = [end, next_tick, next_probe]
        for side in (master, slave):
            timer = side.conn.get_timer()
            if timer is not None:
                candidates.append(timer)
            due = side.link.next_delivery()
            if due is not None:
                candidates.append(due)
        upcoming = min(candidates)
        if math.isinf(upcoming):
            break
        now = max(now, upcoming)
        for side in (master, slave):
            other = peer[side.name]
            for datagram, _tag in side.link.deliver(now):
                other.conn.receive_datagram(datagram, side.addr, now=now)
                heard(other, now)
        for side in (master, slave):
            side.conn.handle_timer(now=now)
            heard(side, now)
        if started is None and slave.conn.state is State.ESTABLISHED:
            started = now
            next_tick = now
            stop = WARMUP + seconds
            end = stop + DRAIN
            next_probe = WARMUP
        if now >= stop and not master.stop:
            next_tick = next_probe = math.inf  # the applications stop; the verdicts come in
            for side in (master, slave):
                side.stop = _counters(side.conn)
        if now >= next_tick:
            tick(now, index)
            index += 1
            next_tick += 1.0 / RATE
        if now >= next_probe:
            if not master.base:
                for side in (master, slave):
                    side.base = _counters(side.conn)
            for side in (master, slave):
                if not math.isnan(side.last_rtt_at):
                    side.freshness.append(now - side.last_rtt_at)
            next_probe += PROBE
        for side in (master, slave):
            flush(side, now)
    span = seconds
    out: dict[str, Json] = {}
    for way, side in (("M->S", master), ("S->M", slave)):
        receiver = peer[side.name]
        # Rates over the window; verdicts (acknowledged, unreported) once the drain settled them.
        d = {key: side.stop[key] - side.base[key] for key in side.base}
        final = _counters(side.conn)
        settled = {key: final[key] - side.base[key] for key in side.base}
        r_final = _counters(receiver.conn)
        r = {key: r_final[key] - receiver.base[key] for key in receiver.base}
        rstats = receiver.conn.stats
        out[way] = {
            "data_per_s": d["data"] / span,
            "ack_per_s": d["acks"] / span,
            "control_per_s": d["control"] / span,
            "packets_per_s": d["datagrams"] / span,
            "wire_kbit_s": (d["bytes"] + IP_UDP * d["datagrams"]) * 8 / span / 1e3,
            "sent_share": d["data"] / side.offered if side.offered else math.nan,
            "ack_coverage": settled["acked"] / r["received"] if r["received"] else math.nan,
            "unreported_share": settled["unreported"] / d["data"] if d["data"] else math.nan,
            "feedback_p50_ms": _percentile(side.feedback_delays, 0.5) * 1e3,
            "feedback_p99_ms": _percentile(side.feedback_delays, 0.99) * 1e3,
            "rtt_age_p50_ms": _percentile(side.freshness, 0.5) * 1e3,
            "rtt_age_p99_ms": _percentile(side.freshness, 0.99) * 1e3,
            "sample_age_p50_ms": rstats.sample_age_p50 * 1e3,
            "sample_age_p99_ms": rstats.sample_age_p99 * 1e3,
            "timed_share": r["timed"] / r["delivered"] if r["delivered"] else math.nan,
            "recon_rmse": math.sqrt(receiver.squared_error / receiver.error_ticks)
            if receiver.error_ticks
            else math.nan,
        }
    return out


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return math.nan
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))]


# ---------------------------------------------------------------------------- report

COLUMNS = (
    ("data_per_s", "data/s", 0),
    ("ack_per_s", "ACK/s", 0),
    ("control_per_s", "KEEPALIVE/s", 0),
    ("packets_per_s", "datagrams/s", 0),
    ("wire_kbit_s", "wire kbit/s", 1),
    ("sent_share", "sent/offered", 3),
    ("ack_coverage", "ACK coverage", 3),
    ("unreported_share", "unreported", 3),
    ("feedback_p50_ms", "feedback p50 ms", 2),
    ("feedback_p99_ms", "p99", 2),
    ("rtt_age_p50_ms", "RTT age p50 ms", 2),
    ("rtt_age_p99_ms", "p99", 2),
    ("sample_age_p50_ms", "sample age p50 ms", 2),
    ("sample_age_p99_ms", "p99", 2),
    ("timed_share", "timed", 3),
    ("recon_rmse", "recon. RMSE (mm / N)", 3),
)


def _median(values: Sequence[float], digits: int) -> str:
    clean = [v for v in values if not math.isnan(v)]
    if not clean:
        return "-"
    med = statistics.median(clean)
    text = f"{med:.{digits}f}"
    if len(clean) > 1 and max(clean) - min(clean) >= 10 ** (-digits):
        text += f" [{min(clean):.{digits}f}-{max(clean):.{digits}f}]"
    return text


def table(results: dict[str, list[dict[str, Json]]]) -> str:
    head = "| mode | way | " + " | ".join(label for _, label, _ in COLUMNS) + " |"
    rule = "| --- | --- | " + " | ".join("---:" for _ in COLUMNS) + " |"
    lines = [head, rule]
    for mode, runs in results.items():
        for way in WAYS:
            cells = [_median([run[way][key] for run in runs], digits) for key, _, digits in COLUMNS]
            lines.append(f"| {mode} | {way} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def rows_for(profile_label: str, results: dict[str, list[dict[str, Json]]]) -> list[Row]:
    """Both directions' wire rate of each mode, against plain TDTP run on the same seeds."""

    def wire(run: dict[str, Json]) -> float:
        return float(sum(run[way]["wire_kbit_s"] for way in WAYS))

    plain = [wire(run) for run in results["tdtp"]]
    rows = []
    for mode, runs in results.items():
        values = [wire(run) for run in runs]
        is_plain = mode == "tdtp"
        rows.append(
            Row(
                benchmark="deadband_cost",
                figure=f"wire rate both ways, {mode}, {profile_label}",
                unit="kbit/s",
                value=Stat.of(values),
                baseline="" if is_plain else "tdtp, every sample a packet",
                baseline_value=None if is_plain else Stat.of(plain),
                ratio=None if is_plain else Stat.of(common.paired_ratios(values, plain)),
                ratio_label="" if is_plain else "x tdtp",
                digits=1,
            )
        )
    return rows


# ---------------------------------------------------------------------------- command line


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    doc = __doc__ or ""
    p = common.OneLineParser(prog="deadband_cost.py", description=doc.splitlines()[0])
    p.add_argument("--seconds", type=float, default=None, help="virtual seconds measured (10)")
    p.add_argument("--repeat", type=int, default=None, help="seeds per mode and path (3)")
    p.add_argument("--k", type=float, default=0.1, help="the deadband's Weber fraction (0.1)")
    p.add_argument("--netem", default=DEFAULT_NETEM, help=f"the second path ({DEFAULT_NETEM!r})")
    p.add_argument(
        "--quick", action="store_true", help=f"{QUICK_SECONDS:g} s, one seed, unless given"
    )
    p.add_argument("--json", action="store_true", help="one JSON report on stdout")
    args = p.parse_args(argv)
    if args.seconds is None:
        args.seconds = QUICK_SECONDS if args.quick else 10.0
    if args.repeat is None:
        args.repeat = 1 if args.quick else 3
    if not 0.0 < args.seconds <= 3600.0:
        p.error(f"--seconds: give virtual seconds between 0 and 3600, got {args.seconds:g}")
    if not 1 <= args.repeat <= 100:
        p.error(f"--repeat: give 1 to 100 seeds, got {args.repeat}")
    if not 0.0 < args.k < 10.0:
        p.error(f"--k: give a Weber fraction above 0 and below 10, got {args.k:g}")
    try:
        parse_netem(args.netem)
    except NetemSyntaxError as exc:
        p.error(f"--netem: {exc}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    profiles = {"loopback": LOOPBACK, args.netem: args.netem}
    details: Json = {"k": args.k, "profiles": profiles, "results": {}}
    rows: list[Row] = []
    texts = []
    for label, profile in profiles.items():
        results: dict[str, list[dict[str, Json]]] = {}
        for mode in MODES:
            runs = []
            for seed in range(1, args.repeat + 1):
                print(f"deadband_cost: {label}, {mode}, seed {seed}", file=sys.stderr, flush=True)
                runs.append(run(mode, profile, seed=seed, seconds=args.seconds, k=args.k))
            results[mode] = runs
        details["results"][label] = results
        rows.extend(rows_for(label, results))
        texts.append(f"Path `{profile}` ({label}), k = {args.k:g}:\n\n{table(results)}")
    return common.emit("deadband_cost", args, rows, details=details, text="\n\n".join(texts))


if __name__ == "__main__":
    raise SystemExit(main())
