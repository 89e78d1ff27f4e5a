"""Issue 31's eviction target, measured with real processes on loopback: a live operator freezes for
0.2 s while an attacker holds every other slot of a full slave and keeps sending it cookie-validated
OPENs. Does the operator keep its session, and its stream after the freeze?

Three processes (this script in three roles) and the harness:

* ``slave``: ``tdtp.listen(max_peers=4)``, unkeyed, or keyed with a ring of two keys (the operator's
  and the attacker's: "another key of the ring"); it answers every master with nothing but counts,
  per master, when each sample arrived (10 ms buckets), and reports them with the server's counters.
* ``operator``: ``tdtp.connect`` from a fixed local port, 1000 samples/s of 100 bytes for the whole
  run (``Ticker``), reconnecting as ``tdtp master`` does.
* ``attacker``: opens the slave's other three slots and keeps those sessions alive, then runs
  ``--flood`` concurrent loops of ``tdtp.connect`` (each a new socket and port: a full handshake, so
  every OPEN it ends with carries a valid cookie and, keyed, a valid tag), each retried at once when
  refused. This is the attack of the issue: before version 4 of the slot rule, any such OPEN took
  the slot of a session silent for 0.1 s.

At ``--freeze-at`` seconds the harness stops the operator's process (SIGSTOP: everything it sends and
reads stops, as in a GC pause or a Wi-Fi hiccup) for ``--freeze`` seconds (0.2), then lets it go on.
Reported per run: the operator's samples/s at the slave in the second before the freeze and in the
two seconds from 0.5 s after it (the target: >= 900 after), whether its session survived (its cause
if not), evictions, the validated OPENs the slave refused BUSY meanwhile, and the attacker's connect
attempts per second.

    nice -n 5 .venv/bin/python benchmarks/eviction_attack.py [--runs 3] [--keyed] [--flood 16]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import signal
import socket
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import tdtp  # noqa: E402
from tdtp import ConnectionConfig, PresharedKey, ReconnectPolicy  # noqa: E402

OPERATOR_KEY = PresharedKey(bytes(range(32)), name="operator")
ATTACKER_KEY = PresharedKey(bytes(range(100, 132)), name="attacker")
BUCKET = 0.01


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


# ---------------------------------------------------------------------------- the roles


async def slave(port: int, keyed: bool, seconds: float) -> dict[str, Any]:
    arrivals: dict[str, dict[int, int]] = defaultdict(lambda: defaultdict(int))
    ends: dict[str, str] = {}

    def counter(name: str) -> Callable[[tdtp.DataReceived], None]:
        buckets = arrivals[name]

        def on_data(_event: tdtp.DataReceived) -> None:
            buckets[int(time.monotonic() / BUCKET)] += 1

        return on_data

    keys = [OPERATOR_KEY, ATTACKER_KEY] if keyed else None
    async with tdtp.listen("127.0.0.1", port, max_peers=4, keys=keys) as server:
        print("ready", flush=True)

        async def serve() -> None:
            async for ep in server:
                peer = ep.peer
                name = f"{peer[0]}:{peer[1]}" if peer is not None else "?"
                ep.set_data_callback(counter(name))

                def closed(task: Any, ep: tdtp.Endpoint = ep, name: str = name) -> None:
                    event = ep.close_event
                    ends[name] = event.cause.value if event is not None else "open"

                asyncio.ensure_future(ep.wait_closed()).add_done_callback(closed)

        serving = asyncio.create_task(serve())
        await asyncio.sleep(seconds)
        serving.cancel()
        stats = server.stats
        report = {
            "arrivals": {name: dict(buckets) for name, buckets in arrivals.items()},
            "ends": ends,
            "peers_evicted": stats.peers_evicted,
            "peers_refused": stats.peers_refused,
            "refused_busy": stats.slots.refused_busy,
            "admitted": stats.admission.admitted,
        }
    return report


async def operator(port: int, local_port: int, keyed: bool, seconds: float) -> dict[str, Any]:
    key = OPERATOR_KEY if keyed else None
    ep = await tdtp.connect(
        "127.0.0.1",
        port,
        local_addr=("127.0.0.1", local_port),
        key=key,
        reconnect=ReconnectPolicy(after_silence=3.0),
    )
    print("ready", flush=True)
    offered = 0
    start = time.monotonic()
    async for _ in tdtp.Ticker(1000):
        if time.monotonic() - start >= seconds or ep.is_closed:
            break
        offered += 1
        with contextlib.suppress(tdtp.EndpointClosedError):
            ep.send(bytes(100))
    event = ep.close_event
    report = {
        "offered": offered,
        "sent": ep.stats.sent.data_packets + ep.reconnects.samples_sent_before,
        "reconnects": ep.reconnects.count,
        "causes": dict(ep.reconnects.causes),
        "closed": None if event is None else event.cause.value,
    }
    await ep.close()
    return report


async def attacker(port: int, keyed: bool, seconds: float, flood: int) -> dict[str, Any]:
    key = ATTACKER_KEY if keyed else None
    config = ConnectionConfig(open_timeout=1.0)
    held = []
    while len(held) < 3:
        try:
            held.append(await tdtp.connect("127.0.0.1", port, key=key, config=config))
        except tdtp.ConnectError:
            await asyncio.sleep(0.05)
    print("ready", flush=True)

    async def keep_alive(ep: tdtp.Endpoint) -> None:
        async for _ in tdtp.Ticker(100):
            if ep.is_closed:
                return
            ep.send(bytes(20))

    counts = {"attempts": 0, "opened": 0, "refused": 0}

    async def hammer() -> None:
        while True:
            counts["attempts"] += 1
            try:
                ep = await tdtp.connect("127.0.0.1", port, key=key, config=config)
            except tdtp.ConnectError:
                counts["refused"] += 1
                continue
            counts["opened"] += 1
            held.append(ep)
            keepers.append(asyncio.ensure_future(keep_alive(ep)))

    keepers = [asyncio.ensure_future(keep_alive(ep)) for ep in held]
    start = time.monotonic()
    loops = [asyncio.ensure_future(hammer()) for _ in range(flood)]
    await asyncio.sleep(seconds)
    for task in loops + keepers:
        task.cancel()
    elapsed = time.monotonic() - start
    return {**counts, "attempts_per_s": round(counts["attempts"] / elapsed, 1)}


# ---------------------------------------------------------------------------- the harness


def _spawn(*argv: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, __file__, *argv],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def _ready(process: subprocess.Popen[str]) -> None:
    assert process.stdout is not None
    line = process.stdout.readline()
    if line.strip() != "ready":
        _, err = process.communicate(timeout=30)
        raise SystemExit(f"a role failed to start: {line!r} {err.strip()}")


def _result(process: subprocess.Popen[str]) -> dict[str, Any]:
    out, err = process.communicate(timeout=120)
    if process.returncode != 0:
        raise SystemExit(f"a role failed ({process.returncode}): {err.strip()}")
    result: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    return result


def _rate(buckets: dict[str, int], start: float, end: float) -> float:
    first, last = int(start / BUCKET), int(end / BUCKET)
    count = sum(n for b, n in buckets.items() if first <= int(b) < last)
    return count / ((last - first) * BUCKET)


def one_run(keyed: bool, flood: int | None, freeze_at: float, freeze: float) -> dict[str, Any]:
    """One run; ``flood`` ``None``: the baseline, the same freeze with no attacker at all."""
    port, local = _free_port(), _free_port()
    total = freeze_at + freeze + 4.0
    mode = ["--keyed"] if keyed else []
    slave_process = _spawn("slave", "--port", str(port), "--seconds", str(total + 6.0), *mode)
    _ready(slave_process)
    op = _spawn(
        "operator", "--port", str(port), "--local-port", str(local), "--seconds",
        str(total), *mode,
    )  # fmt: skip
    _ready(op)
    started = time.monotonic()
    attack = None
    if flood is not None:
        attack = _spawn(
            "attacker", "--port", str(port), "--seconds", str(total), "--flood", str(flood), *mode
        )
        _ready(attack)
    time.sleep(max(0.0, started + freeze_at - time.monotonic()))
    op.send_signal(signal.SIGSTOP)
    frozen = time.monotonic()
    time.sleep(freeze)
    op.send_signal(signal.SIGCONT)
    thawed = time.monotonic()
    operator_report = _result(op)
    attacker_report = _result(attack) if attack is not None else None
    slave_report = _result(slave_process)
    name = f"127.0.0.1:{local}"
    buckets = slave_report["arrivals"].get(name, {})
    end = slave_report["ends"].get(name, "open")
    return {
        "attack": flood is not None,
        "kept": end in ("open", "peer_close") and not operator_report["reconnects"],
        "before": round(_rate(buckets, frozen - 1.0, frozen), 1),
        "after": round(_rate(buckets, thawed + 0.5, thawed + 2.5), 1),
        "frozen_for": round(thawed - frozen, 3),
        "operator_session": end,
        "operator": operator_report,
        "evicted": slave_report["peers_evicted"],
        "refused_busy": slave_report["refused_busy"],
        "admitted": slave_report["admitted"],
        "attacker": attacker_report,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("role", nargs="?", choices=("slave", "operator", "attacker"))
    parser.add_argument("--port", type=int)
    parser.add_argument("--local-port", type=int)
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--keyed", action="store_true", help="keyed (a ring of two keys)")
    parser.add_argument("--flood", type=int, default=16, help="concurrent connect loops (16)")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--freeze-at", type=float, default=3.0)
    parser.add_argument("--freeze", type=float, default=0.2)
    args = parser.parse_args()
    if args.role == "slave":
        print(json.dumps(asyncio.run(slave(args.port, args.keyed, args.seconds))))
        return
    if args.role == "operator":
        report = asyncio.run(operator(args.port, args.local_port, args.keyed, args.seconds))
        print(json.dumps(report))
        return
    if args.role == "attacker":
        print(json.dumps(asyncio.run(attacker(args.port, args.keyed, args.seconds, args.flood))))
        return
    runs, baselines = [], []
    for _ in range(args.runs):  # interleaved: both see the same machine load
        baselines.append(one_run(args.keyed, None, args.freeze_at, args.freeze))
        runs.append(one_run(args.keyed, args.flood, args.freeze_at, args.freeze))
    for run in baselines + runs:
        print(json.dumps(run))
    mode = "keyed (the attacker holds another key of the ring)" if args.keyed else "unkeyed"
    for label, group in (("no attacker", baselines), ("attack", runs)):
        after = [float(run["after"]) for run in group]
        before = [float(run["before"]) for run in group]
        kept = sum(bool(run["kept"]) for run in group)
        refused = [int(run["refused_busy"]) for run in group]
        print(
            f"{mode}, {label}: operator samples/s at the slave in the second before the "
            f"{args.freeze:g} s freeze median {statistics.median(before):.0f}, from 0.5 to 2.5 s "
            f"after it median {statistics.median(after):.0f} (min {min(after):.0f}, max "
            f"{max(after):.0f}); session kept in {kept} of {len(group)} runs; evictions "
            f"{sum(int(run['evicted']) for run in group)}; validated OPENs refused BUSY per run "
            f"median {statistics.median(refused):.0f}"
        )
    ratios = [float(a["after"]) / float(b["after"]) for a, b in zip(runs, baselines, strict=True)]
    print(
        f"after the freeze, attack / no attacker (paired): median {statistics.median(ratios):.3f}"
    )


if __name__ == "__main__":
    main()
