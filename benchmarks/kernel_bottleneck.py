"""TCP (cubic, bbr) beside one tdtp pair through a real kernel bottleneck: tbf at 1 Mbit/s in a router namespace.

Usage: ``python benchmarks/kernel_bottleneck.py [--duration 20] [--controllers NAME ...] [--tcp cubic bbr]
[--rate 1mbit] [--queue-ms 100] [--json]``  (``make kernel-check``; needs root, ``ip``, ``tc`` with tbf,
``iperf3``)

**Topology.** Three network namespaces made for the run (unique names, deleted at the end whatever
happens, with every process started in them): ``M`` (the tdtp master and the iperf3 client), ``R``
(a router, IPv4 forwarding on) and ``S`` (the tdtp slave and the iperf3 server), joined by two veth
pairs, ``M 10.201.1.1 - 10.201.1.2 R 10.201.2.1 - 10.201.2.2 S``. R's egress towards S is
``tc qdisc ... root tbf rate RATE burst 1600 latency QUEUE_MS``: a bottleneck with a drop-tail buffer
of QUEUE_MS at the rate. Nothing else is impaired; the way back (S -> M) is free. Only these
namespaces' addresses are used; no traffic leaves them.

**Runs**, each ``--duration`` seconds, one after the other, for each TCP congestion control of
``--tcp`` (cubic, and bbr: this kernel's default, when it has it):

1. ``TCP alone``: ``iperf3 -c S -C CC -t D`` from M (the baseline: what TCP takes of the link);
2. for each controller (default: every one registered in ``tdtp.control``): the same iperf3 and, started
   together with it, ``tdtp master S:PORT --controller NAME --duration D --json`` in M against
   ``tdtp slave`` in S (100-byte samples at 1 kHz each way, the CLI's defaults).

**Figures.** TCP: goodput (iperf3's receiver bytes over its seconds) and its share of the link rate,
over the whole run and over the second half (after TCP's start-up); the bytes the tbf sent during the
run and the part of them that was tdtp's (each tdtp datagram the slave received counted with its IPv4 +
UDP + Ethernet headers). tdtp: samples/s delivered each way and latency p99 (the CLI's own figures:
M->S measured by the slave, S->M by the master; one machine, one monotonic clock).

Recorded accounting (what the smoke test checks, never the rates): the slave received no more tdtp
datagrams than the master sent, iperf3's receiver no more bytes than its sender, and the tbf sent at
least the bytes of both.
"""

from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
# The namespaces are tests/netlab.py's (appended: nothing of tests/ shadows an installed module).
sys.path.append(str(Path(__file__).resolve().parents[1] / "tests"))
import _common as common
import netlab
from _common import Json, Row, Stat
from netlab import NetLab

import tdtp.control

M_ADDR, R_M_ADDR = "10.201.1.1", "10.201.1.2"
R_S_ADDR, S_ADDR = "10.201.2.1", "10.201.2.2"
TDTP_PORT = 9000
IPERF_PORT = 5201
WIRE_OVERHEAD = 20 + 8 + 14  # IPv4 + UDP + Ethernet, as tc counts a veth frame
TDTP_HEADER = 5
SIZE = 100
TARGET_SHARE = 0.40
"""Issues 19 and 32: TCP keeps at least this share of the bottleneck beside one tdtp pair."""
TDTP_TARGET_SHARE = 0.35
"""Issue 32: the default controller gets at least this share of the bottleneck beside one TCP flow
(cubic or bbr), by the tbf's bytes."""


def missing() -> str | None:
    """Why this machine cannot run the check, or None."""
    return netlab.missing("tc", "iperf3")


class Bottleneck(NetLab):
    """Three namespaces M, R, S and their links (tests/netlab.py: :meth:`close` removes them and
    their processes)."""

    def __init__(self, rate: str, queue_ms: float) -> None:
        super().__init__("tdtpk")
        self.rate, self.queue_ms = rate, queue_ms

    def setup(self) -> None:
        for role in ("m", "r", "s"):
            self.add(role)
        self.veth("m", "m0", "r", "r0", a_addr=f"{M_ADDR}/24", b_addr=f"{R_M_ADDR}/24")
        self.veth("r", "r1", "s", "s0", a_addr=f"{R_S_ADDR}/24", b_addr=f"{S_ADDR}/24")
        self.route("m", R_M_ADDR)
        self.route("s", R_S_ADDR)
        self.forward("r")
        # Offloads would hand tbf 64 KB super-packets; the bottleneck should see real ones.
        for role, dev in (("m", "m0"), ("r", "r0"), ("r", "r1"), ("s", "s0")):
            self.exec(role, "ethtool", "-K", dev, "tso", "off", "gso", "off", "gro", "off",
                      check=False)  # fmt: skip
        self.qdisc("r", "r1", "tbf", "rate", self.rate, "burst", "1600", "latency",
                   f"{self.queue_ms:g}ms")  # fmt: skip

    def counters(self) -> Json:
        """The tbf's counters: bytes and packets sent, drops, overlimits."""
        text = self.exec("r", "tc", "-s", "qdisc", "show", "dev", "r1")
        found = re.search(r"Sent (\d+) bytes (\d+) pkt \(dropped (\d+), overlimits (\d+)", text)
        if found is None:
            raise RuntimeError(f"no tbf statistics in: {text!r}")
        sent, packets, dropped, over = (int(x) for x in found.groups())
        return {"bytes": sent, "packets": packets, "dropped": dropped, "overlimits": over}


def finish(process: subprocess.Popen[str], timeout: float, what: str) -> str:
    try:
        out, err = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()
        raise RuntimeError(f"{what} did not finish within {timeout:.0f} s") from None
    if process.returncode != 0:
        raise RuntimeError(f"{what} exited with {process.returncode}: {err.strip()[-400:]}")
    return out


def stop(process: subprocess.Popen[str], what: str) -> str:
    """SIGINT (the tdtp CLI prints its summary and exits 130), then its output."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    try:
        out, err = process.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()
        raise RuntimeError(f"{what} did not stop") from None
    if process.returncode not in (0, 130, -signal.SIGINT):
        raise RuntimeError(f"{what} exited with {process.returncode}: {err.strip()[-400:]}")
    return out


def wait_for_packets(net: Bottleneck, packets: int, master: subprocess.Popen[str]) -> None:
    """Until the tbf has sent ``packets`` (tdtp's samples are crossing), at most 30 s."""
    stop_at = time.monotonic() + 30.0
    while net.counters()["packets"] < packets:
        if master.poll() is not None:
            raise RuntimeError(f"tdtp master exited with {master.returncode}: {master.stderr}")
        if time.monotonic() > stop_at:
            raise RuntimeError("tdtp's samples did not cross the router within 30 s")
        time.sleep(0.02)


def tcp_figures(report: Json, rate_bps: float) -> Json:
    end = report["end"]
    received = end["sum_received"]
    intervals = report.get("intervals", [])
    half = intervals[len(intervals) // 2 :]
    half_bits = sum(i["sum"]["bytes"] * 8 for i in half)
    half_seconds = sum(i["sum"]["seconds"] for i in half)
    goodput = received["bits_per_second"]
    second_half = half_bits / half_seconds if half_seconds else float("nan")
    return {
        "bytes_sent": end["sum_sent"]["bytes"],
        "bytes_received": received["bytes"],
        "seconds": received["seconds"],
        "retransmits": end["sum_sent"].get("retransmits"),
        "goodput_bps": goodput,
        "share": goodput / rate_bps,
        "second_half_bps": second_half,
        "second_half_share": second_half / rate_bps,
        "congestion": end.get("sender_tcp_congestion"),
    }


def one_run(
    net: Bottleneck, duration: float, controller: str | None, rate_bps: float, cc: str = "cubic"
) -> Json:
    """iperf3 (congestion control ``cc``) for ``duration`` s, with a tdtp pair beside it unless
    ``controller`` is None."""
    server = net.spawn("s", "iperf3", "-s", "-1", "-B", S_ADDR, "-p", str(IPERF_PORT), "--json")
    slave = None
    tdtp_cmd = [sys.executable, "-m", "tdtp"]
    if controller is not None:
        slave = net.spawn(
            "s", *tdtp_cmd, "slave", "--host", S_ADDR, "--port", str(TDTP_PORT),
            "--controller", controller, "--json",
        )  # fmt: skip
    time.sleep(1.0)  # the servers' interpreters starting
    before = net.counters()
    master = None
    if controller is not None:
        # The master runs until TCP's run is over (then SIGINT: it prints its summary), and TCP
        # starts once tdtp's packets cross the router: both compete for the whole of TCP's run.
        master = net.spawn(
            "m", *tdtp_cmd, "master", f"{S_ADDR}:{TDTP_PORT}", "--controller", controller, "--json",
        )  # fmt: skip
        wait_for_packets(net, before["packets"] + 50, master)
    client = net.spawn(
        "m", "iperf3", "-c", S_ADDR, "-p", str(IPERF_PORT), "-C", cc,
        "-t", f"{duration:g}", "--json",
    )  # fmt: skip
    tcp = tcp_figures(json.loads(finish(client, duration + 30.0, "iperf3 -c")), rate_bps)
    result: Json = {"controller": controller, "cc": cc, "tcp": tcp}
    if master is not None and slave is not None:
        master_report = json.loads(stop(master, "tdtp master"))
        time.sleep(0.5)
        slave_report = json.loads(stop(slave, "tdtp slave"))
        result["tdtp"] = tdtp_figures(master_report, slave_report)
    after = net.counters()
    finish(server, 10.0, "iperf3 -s")
    result["tbf"] = {k: after[k] - before[k] for k in after}
    tdtp_bytes = result.get("tdtp", {}).get("ms", {}).get("wire_bytes_at_tbf", 0)
    result["tbf"]["tdtp_bytes"] = tdtp_bytes
    result["tbf"]["tdtp_fraction"] = tdtp_bytes / result["tbf"]["bytes"] if after["bytes"] else 0
    return result


def tdtp_figures(master: Json, slave: Json) -> Json:
    (session,) = slave["sessions"]
    ms_sent, ms_recv = master["master_to_slave"], session["master_to_slave"]
    sm_sent, sm_recv = session["slave_to_master"], master["slave_to_master"]
    duration = float(master["duration_s"])

    def way(sent: Json, received: Json) -> Json:
        latency = received.get("latency_ms") or {}
        packets = int(received["packets_received"])
        return {
            "offered": sent["samples_offered"],
            "packets_sent": sent["packets_sent"],
            "bytes_sent": sent["bytes_sent"],
            "packets_received": packets,
            "samples_delivered": received["samples_delivered"],
            "samples_per_s": received["samples_delivered"] / duration,
            "latency_p50_ms": latency.get("p50"),
            "latency_p99_ms": latency.get("p99"),
            "srtt_ms": sent["srtt_ms"],
            "allowed_rate": sent["allowed_rate"],
            "rate_limit": sent.get("rate_limit"),
            "losses": sent["losses"],
            "superseded": sent["samples_superseded"],
            # Data packets only: ACKs ride in them, handshakes are a few bytes more.
            "wire_bytes_at_tbf": packets * (SIZE + TDTP_HEADER + WIRE_OVERHEAD),
        }

    return {
        "duration_s": duration,
        "ms": way(ms_sent, ms_recv),
        "sm": way(sm_sent, sm_recv),
        "core": master.get("core"),
    }


# ---------------------------------------------------------------------------- command line


def parse_rate(text: str) -> float:
    """tc's rate syntax (bits per second), through tdtp's netem parser, which reads it as tc does."""
    from tdtp.netem import parse_netem  # noqa: PLC0415

    rate = parse_netem(f"rate {text}").rate
    assert rate is not None
    return rate.rate_bps


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    doc = __doc__ or ""
    p = common.OneLineParser(prog="kernel_bottleneck.py", description=doc.splitlines()[0])
    p.add_argument("--duration", type=float, default=20.0, help="seconds per run (20)")
    p.add_argument("--controllers", nargs="+", metavar="NAME", help="tdtp controllers (all)")
    p.add_argument(
        "--tcp", nargs="+", metavar="CC", help="TCP congestion controls (cubic, and bbr if known)"
    )
    p.add_argument("--rate", default="1mbit", help="the bottleneck, tc syntax (1mbit)")
    p.add_argument("--queue-ms", type=float, default=100.0, help="tbf's buffer in ms (100)")
    p.add_argument("--json", action="store_true", help="one JSON report on stdout")
    args = p.parse_args(argv)
    if not (1.0 <= args.duration <= 600.0):
        p.error(f"--duration: give 1 to 600 seconds, got {args.duration:g}")
    if not (1.0 <= args.queue_ms <= 5000.0):
        p.error(f"--queue-ms: give 1 to 5000 ms, got {args.queue_ms:g}")
    try:
        args.rate_bps = parse_rate(args.rate)
    except ValueError as exc:
        p.error(f"--rate: {exc}")
    known = tdtp.control.available_controllers()
    unknown = [c for c in args.controllers or () if c not in known]
    if unknown:
        p.error(f"--controllers: unknown {', '.join(unknown)}; known: {', '.join(known)}")
    args.controllers = list(dict.fromkeys(args.controllers or known))
    available = kernel_congestion_controls()
    if args.tcp is None:
        args.tcp = [cc for cc in ("cubic", "bbr") if cc in available] or ["cubic"]
    unknown_cc = [cc for cc in args.tcp if available and cc not in available]
    if unknown_cc:
        p.error(f"--tcp: this kernel has no {', '.join(unknown_cc)}; it has {' '.join(available)}")
    args.seconds, args.repeat = args.duration, 1
    return args


def kernel_congestion_controls() -> list[str]:
    """The TCP congestion controls this kernel offers (empty when it does not say)."""
    path = Path("/proc/sys/net/ipv4/tcp_available_congestion_control")
    try:
        return path.read_text().split()
    except OSError:
        return []


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    why = missing()
    if why is not None:
        print(f"kernel_bottleneck.py: skipped: {why}", file=sys.stderr)
        return common.emit("kernel_bottleneck", args, [], details={"skipped": why})
    default = tdtp.control.DEFAULT_CONTROLLER
    others = common.OthersMeter()
    net = Bottleneck(args.rate, args.queue_ms)
    runs: list[Json] = []
    # SIGTERM (a timeout from make or CI) must still clean up.
    previous = signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        try:
            net.setup()
        except netlab.NetLabError as exc:
            print(
                f"kernel_bottleneck.py: cannot set up the namespaces and tbf: {exc}",
                file=sys.stderr,
            )
            return 1
        for cc, controller in [(cc, c) for cc in args.tcp for c in [None, *args.controllers]]:
            label = f"{cc} alone" if controller is None else f"{cc} + tdtp {controller}"
            print(f"== {label} ({args.duration:g} s) ...", file=sys.stderr, flush=True)
            try:
                result = one_run(net, args.duration, controller, args.rate_bps, cc)
            except (RuntimeError, json.JSONDecodeError, KeyError, ValueError) as exc:
                print(f"!! {label} failed: {exc}", file=sys.stderr, flush=True)
                runs.append({"controller": controller, "cc": cc, "error": str(exc)})
                continue
            tcp = result["tcp"]
            line = f"   TCP {tcp['goodput_bps'] / 1e3:.0f} kbit/s ({100 * tcp['share']:.0f} %)"
            if "tdtp" in result:
                t = result["tdtp"]
                line += (
                    f", tdtp {100 * result['tbf']['tdtp_fraction']:.0f} % of the tbf's bytes, "
                    f"{t['ms']['samples_per_s']:.0f} / {t['sm']['samples_per_s']:.0f} "
                    f"samples/s, latency p99 {ms_text(t['ms']['latency_p99_ms'])} / "
                    f"{ms_text(t['sm']['latency_p99_ms'])} ms"
                )
            print(line, file=sys.stderr, flush=True)
            runs.append(result)
    finally:
        net.close()
        signal.signal(signal.SIGTERM, previous)
    busy = others.percent()
    leftovers = net.left()
    rows = rows_of(runs, default)
    text = markdown(runs, args, default, busy)
    details: Json = {
        "default_controller": default,
        "rate": args.rate,
        "rate_bps": args.rate_bps,
        "queue_ms": args.queue_ms,
        "namespaces": net.tag,
        "namespaces_left": leftovers,
        "runs": runs,
        "others_percent": busy,
    }
    return common.emit("kernel_bottleneck", args, rows, details=details, text=text)


def label_of(controller: str | None, default: str, cc: str = "cubic") -> str:
    if controller is None:
        return f"{cc} alone"
    return f"{cc} + tdtp {controller}" + (" (default)" if controller == default else "")


def markdown(runs: list[Json], args: argparse.Namespace, default: str, busy: float) -> str:
    lines = [
        f"tbf {args.rate} with a {args.queue_ms:g} ms buffer, {args.duration:g} s per run, iperf3 "
        f"-C {' / '.join(args.tcp)}; tdtp 100-byte samples at 1 kHz each way; other tenants used "
        f"{busy:.0f} % of a core meanwhile.",
        "",
        "| run | TCP goodput kbit/s (share) | TCP 2nd half (share) | TCP retransmits "
        "| tdtp share of tbf bytes | tdtp samples/s M->S / S->M | tdtp latency p99 ms M->S / S->M "
        "| tbf drops |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in runs:
        label = label_of(r["controller"], default, r.get("cc", "cubic"))
        if "error" in r:
            lines.append(f"| {label} | failed: {r['error'][:100]} | | | | | | |")
            continue
        tcp, tbf = r["tcp"], r["tbf"]
        tdtp_cells = ["-", "-", "-"]
        if "tdtp" in r:
            t = r["tdtp"]
            tdtp_cells = [
                f"{100 * tbf['tdtp_fraction']:.0f} %",
                f"{t['ms']['samples_per_s']:.0f} / {t['sm']['samples_per_s']:.0f}",
                f"{ms_text(t['ms']['latency_p99_ms'])} / {ms_text(t['sm']['latency_p99_ms'])}",
            ]
        lines.append(
            f"| {label} | {tcp['goodput_bps'] / 1e3:.0f} ({100 * tcp['share']:.0f} %) "
            f"| {tcp['second_half_bps'] / 1e3:.0f} ({100 * tcp['second_half_share']:.0f} %) "
            f"| {tcp['retransmits']} | {' | '.join(tdtp_cells)} | {tbf['dropped']} |"
        )
    return "\n".join(lines)


def ms_text(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def rows_of(runs: list[Json], default: str) -> list[Row]:
    rows = []
    for r in runs:
        if "error" in r:
            continue
        tcp = r["tcp"]
        cc = r.get("cc", "cubic")
        label = label_of(r["controller"], default, cc)
        target, meets = "", None
        if r["controller"] is not None:
            target = f">= {TARGET_SHARE:.0%} (issues 19, 32)"
            meets = tcp["share"] >= TARGET_SHARE
        note = ""
        if "tdtp" in r:
            t = r["tdtp"]["ms"]
            note = (
                f"tdtp {t['samples_per_s']:.0f} samples/s M->S, latency p99 "
                f"{ms_text(t['latency_p99_ms'])} ms"
            )
        rows.append(
            Row(
                "kernel_bottleneck",
                f"{label}: TCP {cc}'s share of the tbf link",
                "",
                Stat.of([tcp["share"]]),
                target=target,
                meets=meets,
                note=note,
                digits=2,
            )
        )
        if r["controller"] == default and "tdtp" in r:
            share = r["tbf"]["tdtp_fraction"]
            rows.append(
                Row(
                    "kernel_bottleneck",
                    f"{label}: tdtp's share of the tbf's bytes",
                    "",
                    Stat.of([share]),
                    target=f">= {TDTP_TARGET_SHARE:.0%} (issue 32)",
                    meets=share >= TDTP_TARGET_SHARE,
                    digits=2,
                )
            )
    return rows


if __name__ == "__main__":
    sys.exit(main())
