"""A robot behind NAT (issue 34): rendezvous, hole punching and the relay, measured on the kernel's NAT.

Usage: ``python benchmarks/nat.py [--tries 20] [--symmetric-tries 5] [--seconds 2] [--json]``
(root, ``ip``, ``nft``, ``conntrack``; the namespaces of tests/natlab.py, made and removed here).

Each *try* is a fresh ``tdtp slave --rendezvous`` in site A and ``tdtp master --rendezvous`` in site B,
started together, 1 kHz of 100-byte samples each way, against one ``tdtp relay`` (a fresh rendezvous
name per try). Pairs:

* ``eim-eim``: both behind endpoint-independent NATs (masquerade, stateful WAN firewall);
* ``symmetric-eim``: the slave behind a symmetric NAT (masquerade fully-random): no direct path.

Per pair: ``tries``, how many ended ``direct`` / ``relayed`` / ``failed``, and the time from the
later of the two rendezvous starts to the master's first sample (p50, spread).

``relay``: ``added_latency_p50_ms``: one-way latency p50 (the samples' own timestamps, one host,
one clock) of a relayed session minus a direct one's in the same run, both ways, median of
``--repeat`` pairs of runs; the relayed runs' samples/s each way. ``cpu_per_datagram_ratio_vs_raw_forwarder``:
the relay's CPU time per forwarded datagram over a bare uvloop forwarder's (30 lines: one dict look-up
and a ``sendto``), the same synthetic load through each (2,000 datagrams/s each way of 105 bytes,
from a public host), alternated, medians.

``upgrade_samples_lost``: a session opened with the direct path cut (so on the relay), healed after
1.5 s: the samples its senders counted lost (both ways), against the same run without a heal.
Then the direct path cut mid-session (time until the relay carries the samples, from the
Internet's packet counters, and samples lost), and the relay killed while the direct path is in use
(samples lost).

The machine's 2 cores are shared: wall-clock figures are noisy; the load average is reported.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, NoReturn

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT))

from natlab import RELAY_ADDR, NatLab, missing  # noqa: E402

Json = dict[str, Any]
TDTP = (sys.executable, "-m", "tdtp")
RELAY = f"{RELAY_ADDR}:7700"

RAW_FORWARDER = r"""
import asyncio, resource, sys, time, uvloop
class Forward(asyncio.DatagramProtocol):
    def __init__(self): self.peers = {}; self.order = []; self.count = 0
    def connection_made(self, t): self.t = t
    def datagram_received(self, data, addr):
        dest = self.peers.get(addr)
        if dest is not None:
            self.count += 1
            self.t.sendto(data, dest)
            return
        self.order.append(addr)
        if len(self.order) == 2:
            a, b = self.order
            self.peers = {a: b, b: a}
def cpu():
    u = resource.getrusage(resource.RUSAGE_SELF)
    return u.ru_utime + u.ru_stime
async def main():
    loop = asyncio.get_running_loop()
    t, p = await loop.create_datagram_endpoint(Forward, local_addr=("0.0.0.0", 7800))
    start = cpu()  # as tdtp relay counts: from when it is bound, not its imports
    print("ready", flush=True)
    await asyncio.sleep(float(sys.argv[1]))
    print(cpu() - start, p.count, flush=True)
uvloop.run(main())
"""

LOAD = r"""
import socket, sys, time
sys.path.insert(0, sys.argv[4])
from tdtp.wire.rendezvous import RegisterBody, RegisterFlags, decode_referral, encode_register
host, port, mode, _, rate, seconds = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4], float(sys.argv[5]), float(sys.argv[6])
x = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); y = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
x.bind(("0.0.0.0", 0)); y.bind(("0.0.0.0", 0)); y.settimeout(2); x.settimeout(2)
relay = (host, port)
if mode == "relay":
    rid = b"L" * 16
    for sock, flags in ((y, RegisterFlags.LISTENER), (x, RegisterFlags.NONE)):
        nonce = bytes(16)
        sock.sendto(encode_register(RegisterBody(int(flags), nonce, rid, bytes(16), ())), relay)
        cookie = decode_referral(sock.recv(200)).cookie
        sock.sendto(encode_register(RegisterBody(int(flags), nonce, rid, cookie, ())), relay)
        sock.recv(200)
else:
    x.sendto(b"hello", relay); time.sleep(0.05); y.sendto(b"hello", relay); time.sleep(0.05)
x.setblocking(False); y.setblocking(False)
payload = b"\x00" * 105
interval = 1.0 / rate; start = time.monotonic(); n = 0; got = 0
while time.monotonic() - start < seconds:
    due = start + n * interval
    while time.monotonic() < due:
        pass
    x.sendto(payload, relay); n += 1
    for sock, other in ((y, True), (x, False)):
        try:
            while True:
                sock.recv(2000); got += 1
                if other:
                    y.sendto(payload, relay)
        except BlockingIOError:
            pass
print(n, got)
"""


ON_STOP = ("--on-stop", "shutdown")
"""An interrupted slave says it is gone for good, so that its master ends the session (and reports
it) instead of reopening one before its own interrupt arrives."""


def _json(process: subprocess.Popen[str], what: str, timeout: float = 60.0) -> Json:
    out, err = process.communicate(timeout=timeout)
    if process.returncode not in (0, 130):
        raise RuntimeError(f"{what} exited {process.returncode}: {err[-800:]}")
    report: Json = json.loads(out)
    return report


def _stop(*processes: subprocess.Popen[str]) -> None:
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)


def _pair(lab: NatLab, name: str, seconds: float) -> tuple[Json, Json]:
    common = (
        "--rendezvous",
        RELAY,
        "--rendezvous-name",
        name,
        "--duration",
        str(seconds),
        "--json",
    )
    slave = lab.spawn("ha", *TDTP, "slave", *common, *ON_STOP)
    master = lab.spawn("hb", *TDTP, "master", *common)
    return _json(master, "master"), _json(slave, "slave")


def _first_sample(master: Json, slave: Json) -> float | None:
    ours, theirs = master["rendezvous"], slave["rendezvous"]
    first = ours.get("first_sample_s")
    if first is None:
        return None
    at = ours["started_at"] + first
    return float(at - max(ours["started_at"], theirs["started_at"]))


def _spread(values: list[float]) -> Json:
    if not values:
        return {"p50": None, "min": None, "max": None, "n": 0}
    return {
        "p50": round(statistics.median(values), 4),
        "min": round(min(values), 4),
        "max": round(max(values), 4),
        "n": len(values),
    }


def run_pair(kind_a: str, kind_b: str, tries: int, seconds: float) -> Json:
    with NatLab() as lab:
        lab.open()
        lab.add_site("a", kind_a)  # type: ignore[arg-type]
        lab.add_site("b", kind_b)  # type: ignore[arg-type]
        relay = lab.spawn("relay", *TDTP, "relay", "--port", "7700", "--json")
        time.sleep(1.0)
        outcome = {"tries": tries, "direct": 0, "relayed": 0, "failed": 0}
        firsts: list[float] = []
        opened_direct = 0
        for i in range(tries):
            try:
                master, slave = _pair(lab, f"try-{i}-{os.getpid()}", seconds)
            except RuntimeError:
                outcome["failed"] += 1
                continue
            path = master["rendezvous"]["path"]
            got = master["slave_to_master"]["packets_received"]
            if path is None or not got:
                outcome["failed"] += 1
                continue
            outcome[path] += 1
            direct_s = master["rendezvous"].get("direct_s")
            first = _first_sample(master, slave)
            if first is not None:
                firsts.append(first)
                if direct_s is not None and direct_s <= master["rendezvous"]["first_sample_s"]:
                    opened_direct += 1
        _stop(relay)
        _json(relay, "relay")
    spread = _spread(firsts)
    return {
        **outcome,
        "first_sample_s_p50": spread["p50"],
        "first_sample_s": spread,
        "opened_on_the_direct_path": opened_direct,
    }


def _latency(report: Json, key: str) -> float | None:
    latency = report.get(key, {}).get("latency_ms")
    return None if latency is None else float(latency["p50"])


def _streaming_rate(master: Json) -> float:
    """Samples/s the master received once samples flowed: its run counts from before the rendezvous
    (the slave's session from its acceptance), and the issue's target is the rate once relayed."""
    received = master["slave_to_master"]["packets_received"]
    streaming = master["duration_s"] - (master["rendezvous"].get("first_sample_s") or 0.0)
    return received / streaming if streaming > 0 else 0.0


def relay_latency(repeat: int, seconds: float) -> Json:
    """Relayed (symmetric NAT) against direct (two EIM NATs) in the same lab, alternated."""
    added: list[float] = []
    rates: dict[str, list[float]] = {"direct": [], "relayed": []}
    with NatLab() as lab:
        lab.open()
        lab.add_site("a", "eim")
        lab.add_site("b", "eim")
        relay = lab.spawn("relay", *TDTP, "relay", "--port", "7700", "--json")
        time.sleep(1.0)
        for i in range(repeat):
            figures = {}
            for mode in ("direct", "relayed"):
                if mode == "relayed":
                    lab.cut("a", "b")  # no direct path: the relay carries everything
                master, slave = _pair(lab, f"lat-{mode}-{i}-{os.getpid()}", seconds)
                lab.heal()
                if master["rendezvous"]["path"] != mode:
                    continue
                session = slave["sessions"][-1]
                ms = _latency(session, "master_to_slave")
                sm = _latency(master, "slave_to_master")
                if ms is None or sm is None:
                    continue
                figures[mode] = (ms + sm) / 2
                rate = min(session["master_to_slave"]["mean_rate"], _streaming_rate(master))
                rates[mode].append(rate)
            if len(figures) == 2:
                added.append(figures["relayed"] - figures["direct"])
        _stop(relay)
        _json(relay, "relay")
    return {
        "added_latency_ms": _spread(added),
        "samples_per_s_each_way": {mode: _spread(values) for mode, values in rates.items()},
    }


def relay_cpu(repeat: int, seconds: float, rate: float) -> Json:
    """CPU per forwarded datagram: tdtp relay against a bare uvloop forwarder, same load."""
    ratios: list[float] = []
    per: dict[str, list[float]] = {"relay": [], "raw": []}
    with NatLab() as lab:
        lab.open(public_host=True)
        for _ in range(repeat):
            for mode in ("relay", "raw"):
                if mode == "relay":
                    server = lab.spawn("relay", *TDTP, "relay", "--port", "7800", "--json")
                else:
                    server = lab.spawn(
                        "relay", sys.executable, "-c", RAW_FORWARDER, str(seconds + 3)
                    )
                time.sleep(1.5)
                load = lab.python(
                    "public", LOAD, RELAY_ADDR, "7800", mode, str(ROOT), str(rate), str(seconds),
                    timeout=seconds + 30,
                )  # fmt: skip
                if mode == "relay":
                    _stop(server)
                    report = _json(server, "relay")
                    cpu, forwarded = report["cpu_s"], report["stats"]["forwarded"]
                else:
                    out, _ = server.communicate(timeout=seconds + 30)
                    cpu_text, count = out.split()[-2:]
                    cpu, forwarded = float(cpu_text), int(count)
                if forwarded:
                    per[mode].append(cpu / forwarded * 1e6)
                del load
            if per["relay"] and per["raw"]:
                ratios.append(per["relay"][-1] / per["raw"][-1])
    return {
        "cpu_per_datagram_us": {mode: _spread(values) for mode, values in per.items()},
        "ratio": _spread(ratios),
    }


def upgrade_and_failover(seconds: float) -> Json:
    result: Json = {}
    with NatLab() as lab:
        lab.open()
        lab.add_site("a", "eim")
        lab.add_site("b", "eim")
        a, b = lab.sites["a"].wan_addr, lab.sites["b"].wan_addr
        for src, dst in ((a, b), (b, a)):
            lab.count("direct", src, dst)
        for wan in (a, b):
            lab.count("relayed", wan, RELAY_ADDR)
        relay = lab.spawn("relay", *TDTP, "relay", "--port", "7700", "--json")
        time.sleep(1.0)

        def lost(master: Json, slave: Json) -> int:
            session = slave["sessions"][-1]
            return int(master["master_to_slave"]["losses"]) + int(
                session["slave_to_master"]["losses"]
            )

        def start(name: str) -> tuple[subprocess.Popen[str], subprocess.Popen[str]]:
            common = ("--rendezvous", RELAY, "--rendezvous-name", name, "--json")
            return lab.spawn("ha", *TDTP, "slave", *common, *ON_STOP), lab.spawn(
                "hb", *TDTP, "master", *common
            )

        # Relay to direct: opened with the direct path cut, healed once samples flow.
        for healed in (False, True):
            lab.cut("a", "b")
            slave, master = start(f"up-{healed}-{os.getpid()}")
            lab.wait_for_traffic("relayed", 500)
            if healed:
                lab.heal()
                lab.wait_for_traffic("direct", 1000)
            else:
                time.sleep(seconds)
            _stop(master, slave)
            m, s = _json(master, "master"), _json(slave, "slave")
            lab.heal()
            key = "upgrade_samples_lost" if healed else "relayed_only_samples_lost"
            result[key] = lost(m, s)
            if healed:
                result["upgraded"] = m["rendezvous"]["path"] == "direct"
        # The direct path cut: how long until the relay carries the samples.
        slave, master = start(f"cut-{os.getpid()}")
        lab.wait_for_traffic("direct", 1000)
        cut_at = time.monotonic()
        lab.cut("a", "b")
        lab.wait_for_traffic("relayed", 50)
        result["direct_cut_to_relayed_s"] = round(time.monotonic() - cut_at, 3)
        lab.wait_for_traffic("relayed", 500)
        _stop(master, slave)
        m, s = _json(master, "master"), _json(slave, "slave")
        result["direct_cut_samples_lost"] = lost(m, s)
        lab.heal()
        # The relay killed while the direct path is in use.
        slave, master = start(f"kill-{os.getpid()}")
        lab.wait_for_traffic("direct", 1000)
        relay.kill()
        relay.communicate(timeout=10)
        lab.wait_for_traffic("direct", 1000)
        _stop(master, slave)
        m, s = _json(master, "master"), _json(slave, "slave")
        result["relay_killed_samples_lost"] = lost(m, s)
        result["relay_killed_path"] = m["rendezvous"]["path"]
    return result


class _OneLineParser(argparse.ArgumentParser):
    """Misuse is one line on stderr and exit status 2, as every benchmark's."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def main(argv: list[str] | None = None) -> int:
    parser = _OneLineParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--tries", type=int, default=20, help="pairs behind two EIM NATs")
    parser.add_argument("--symmetric-tries", type=int, default=5, help="pairs, one NAT symmetric")
    parser.add_argument(
        "--seconds", type=float, default=2.0, help="each try's run (the rate pairs: at least 6)"
    )
    parser.add_argument("--repeat", type=int, default=3, help="direct/relayed pairs for the rate")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    if args.tries < 1 or args.symmetric_tries < 1 or args.seconds <= 0 or args.repeat < 1:
        print(
            "nat.py: --tries, --symmetric-tries, --repeat >= 1 and --seconds > 0", file=sys.stderr
        )
        return 2
    why = missing()
    if why is not None:
        print(f"nat.py: cannot set up: {why}", file=sys.stderr)
        return 1
    load_before = os.getloadavg()
    began = time.monotonic()
    pairs = {
        "eim-eim": run_pair("eim", "eim", args.tries, args.seconds),
        "symmetric-eim": run_pair("symmetric", "eim", args.symmetric_tries, args.seconds),
    }
    # The rate pairs run longer than the tries: a 1 kHz stream's samples/s is judged over seconds
    # of streaming, not over the opening's first few hundred milliseconds.
    latency = relay_latency(args.repeat, max(6.0, args.seconds))
    cpu = relay_cpu(args.repeat, 4.0, 2000.0)
    moves = upgrade_and_failover(args.seconds)
    report = {
        "pairs": pairs,
        "relay": {
            "added_latency_p50_ms": latency["added_latency_ms"]["p50"],
            "cpu_per_datagram_ratio_vs_raw_forwarder": cpu["ratio"]["p50"],
            "latency": latency,
            "cpu": cpu,
        },
        "upgrade_samples_lost": moves.get("upgrade_samples_lost"),
        "moves": moves,
        "machine": {
            "load_before": [round(x, 2) for x in load_before],
            "load_after": [round(x, 2) for x in os.getloadavg()],
            "cpus": os.cpu_count(),
            "seconds": round(time.monotonic() - began, 1),
        },
    }
    print(json.dumps(report, indent=None if args.json else 2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
