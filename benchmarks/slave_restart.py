"""Issues 20 and 31's restart target, measured with real processes: a master runs 10 s at 1 kHz, the
``tdtp slave`` is stopped 3 s into the run and started again on the same port 1 s later. Prints, for
N runs, the samples that reached the slaves (both processes' own counts), the master's samples
received, its reconnects, and how long after the slave was back the new session opened.

``--stop sigint`` (the default; issue 31): Ctrl-C. The slave closes its sessions with CLOSE
RESTARTING (``tdtp slave --on-stop restart``, the default), and the master reopens at its OPEN pacing
until the slave is back. ``--stop kill`` (issue 20): SIGKILL, no CLOSE; the master learns of the
restart from the new slave's RESET.

``--master cli`` (the default): ``tdtp master 127.0.0.1:PORT --duration 10 --json``. ``--master api``:
a Python master, ``tdtp.connect(..., reconnect=True)`` offering 100-byte samples from a 1 kHz
``Ticker`` (this script, role ``api-master``). ``--master both`` runs each in turn.

Every interpreter is started and has imported tdtp before the run (it waits for a line on stdin), so
"back 1 s later" means listening 1 s later, not 1 s plus a loaded machine's interpreter start-up.
Each restart run is paired with a run without the restart, interleaved, so both see the same load.

    nice -n 5 .venv/bin/python benchmarks/slave_restart.py [--runs 3] [--stop sigint|kill]
        [--master cli|api|both]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tdtp.wire import PROTOCOL_VERSION, OpenBody, encode_header, encode_open  # noqa: E402

RUN = 10.0
STOP_AT = 3.0
DOWN_FOR = 1.0


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


_ARMED = (
    "import sys; from tdtp.cli.main import main; sys.stdin.readline(); sys.exit(main(sys.argv[1:]))"
)


def _armed(*argv: str) -> subprocess.Popen[str]:
    """A tdtp process whose interpreter has started and imported tdtp, waiting for a line on stdin
    to run ``tdtp argv``: the run starts when the test says, not after a loaded machine's
    interpreter start-up (which is not what the issue's timeline measures)."""
    return subprocess.Popen(
        [sys.executable, "-c", _ARMED, *argv],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def _armed_api_master(port: int) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, __file__, "api-master", "--port", str(port)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def _go(process: subprocess.Popen[str]) -> None:
    assert process.stdin is not None
    process.stdin.write("go\n")
    process.stdin.flush()


def _wait_listening(port: int) -> None:
    """Until the slave answers an OPEN (with its COOKIE)."""
    probe_open = encode_header(2, 0, 0, 0, 255) + encode_open(
        OpenBody(PROTOCOL_VERSION, 0, 0, 1200, 0, bytes(16), bytes(8), bytes(16))
    )
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.settimeout(0.005)
        for _ in range(4000):
            probe.sendto(probe_open, ("127.0.0.1", port))
            try:
                probe.recv(100)
                return
            except OSError:
                time.sleep(0.002)
    raise SystemExit("the slave never listened")


async def api_master(port: int) -> dict[str, Any]:
    """The ``--master api`` role: ``tdtp.connect(..., reconnect=True)``, 1 kHz for RUN seconds."""
    import tdtp  # noqa: PLC0415 -- the role's own import, after the harness's argument parsing

    sys.stdin.readline()
    ep = await tdtp.connect("127.0.0.1", port, reconnect=True)
    start = tdtp.monotonic()
    offered = 0
    async for _ in tdtp.Ticker(1000):
        if tdtp.monotonic() - start >= RUN:
            break
        offered += 1
        ep.send(bytes(100))
    record = ep.reconnects
    report = {
        "samples_offered": offered,
        "samples_received": record.samples_received_before + ep.stats.samples_delivered,
        "reconnects": record.count,
        "causes": dict(record.causes),
        "start_monotonic": start,
        "last_at_monotonic": record.last_at,
    }
    await ep.close()
    return report


def _slave_received(out: str) -> int:
    summary = json.loads(out)
    return sum(int(session["samples_received"]) for session in summary["sessions"])


def one_run(master_kind: str, stop: str, restart: bool = True) -> dict[str, Any]:
    port = _free_port()
    slave_args = ("slave", "--host", "127.0.0.1", "--port", str(port), "--json")
    first, second = _armed(*slave_args), _armed(*slave_args)
    if master_kind == "cli":
        master = _armed("master", f"127.0.0.1:{port}", "--duration", str(RUN), "--json")
    else:
        master = _armed_api_master(port)
    time.sleep(3.0)  # every interpreter started and imported tdtp (even on a loaded machine)
    _go(first)
    _wait_listening(port)
    _go(master)
    started = time.monotonic()
    back_at = None
    first_received = 0
    if restart:
        time.sleep(max(0.0, started + STOP_AT - time.monotonic()))
        if stop == "kill":
            first.kill()  # SIGKILL: no CLOSE, the port is freed
            first.communicate()
        else:
            first.send_signal(signal.SIGINT)  # Ctrl-C: CLOSE RESTARTING to every master
            out, _ = first.communicate()
            first_received = _slave_received(out)
        time.sleep(max(0.0, started + STOP_AT + DOWN_FOR - time.monotonic()))
        _go(second)
        _wait_listening(port)
        back_at = time.monotonic()
    else:
        second.kill()
        second.communicate()
        second = first
    out, err = master.communicate(timeout=60)
    if master.returncode != 0 or not out:
        raise SystemExit(f"the master failed ({master.returncode}): {err.strip()}")
    second.send_signal(signal.SIGINT)
    slave_out, _ = second.communicate(timeout=60)
    # The CLI prints one indented JSON object; the api-master role one line.
    summary = json.loads(out if master_kind == "cli" else out.strip().splitlines()[-1])
    result: dict[str, Any] = {
        "reached_slaves": first_received + _slave_received(slave_out),
        "master_received": summary["samples_received"],
    }
    if master_kind == "cli":
        reconnects = summary["reconnects"]
        result["reconnects"] = reconnects["count"]
        result["causes"] = reconnects["causes"]
        if back_at is not None and reconnects["last_at_s"] is not None:
            # The master's clock starts when its first session opens (within a round trip of
            # `go`): the delay is good to a few milliseconds.
            result["reopened_after_s"] = round(reconnects["last_at_s"] - (back_at - started), 3)
    else:
        result["reconnects"] = summary["reconnects"]
        result["causes"] = summary["causes"]
        if back_at is not None and summary["last_at_monotonic"] is not None:
            result["reopened_after_s"] = round(summary["last_at_monotonic"] - back_at, 3)
    if stop == "kill" and restart:
        result["reached_slaves"] = None  # the killed slave printed nothing
    return result


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("role", nargs="?", choices=("api-master",))
    parser.add_argument("--port", type=int)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--stop", choices=("sigint", "kill"), default="sigint")
    parser.add_argument("--master", choices=("cli", "api", "both"), default="cli")
    args = parser.parse_args()
    if args.role == "api-master":
        print(json.dumps(asyncio.run(api_master(args.port))))
        return
    kinds = ["cli", "api"] if args.master == "both" else [args.master]
    for kind in kinds:
        runs, baselines = [], []
        for _ in range(args.runs):  # interleaved: both see the same machine load
            baselines.append(one_run(kind, args.stop, restart=False))
            runs.append(one_run(kind, args.stop))
        for run in baselines:
            print(f"{kind} baseline (no restart):", json.dumps(run))
        for run in runs:
            print(f"{kind} {args.stop} restart:", json.dumps(run))
        for key in ("reached_slaves", "master_received"):
            base = [int(run[key]) for run in baselines]
            values = [int(run[key]) for run in runs if run[key] is not None]
            text = (
                f"median {statistics.median(values)}, min {min(values)}, max {max(values)}"
                if values
                else "not counted (the killed slave printed nothing)"
            )
            print(
                f"{kind}, {key}: restart {text}; without it median {statistics.median(base)} "
                f"(of {RUN * 1000:.0f} offered; {(RUN - DOWN_FOR) * 1000:.0f} with the slave away "
                f"{DOWN_FOR:g} s)"
            )
        delays = [float(run["reopened_after_s"]) for run in runs if "reopened_after_s" in run]
        if delays:
            print(
                f"{kind}, new session after the slave was back: median {statistics.median(delays)}"
                f" s, max {max(delays)} s"
            )


if __name__ == "__main__":
    main()
