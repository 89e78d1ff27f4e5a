"""Issue 20's restart target, measured with real processes: ``tdtp master`` runs 10 s at 1 kHz, the
slave is killed (SIGKILL) 3 s into the run and started again on the same port 1 s later. Prints the
master's samples received, its reconnects, and when the new session started, for N runs.

    nice -n 5 .venv/bin/python benchmarks/slave_restart.py [--runs 3]
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import statistics
import subprocess
import sys
import time

from tdtp.wire import PROTOCOL_VERSION, OpenBody, encode_header, encode_open


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
        probe.settimeout(0.05)
        for _ in range(400):
            probe.sendto(probe_open, ("127.0.0.1", port))
            try:
                probe.recv(100)
                return
            except OSError:
                time.sleep(0.02)
    raise SystemExit("the slave never listened")


def one_run(restart: bool = True) -> dict[str, object]:
    port = _free_port()
    slave_args = ("slave", "--host", "127.0.0.1", "--port", str(port), "--json")
    first, second = _armed(*slave_args), _armed(*slave_args)
    master = _armed("master", f"127.0.0.1:{port}", "--duration", "10", "--json")
    time.sleep(3.0)  # every interpreter started and imported tdtp (even on a loaded machine)
    _go(first)
    _wait_listening(port)
    _go(master)
    started = time.monotonic()
    if restart:
        time.sleep(max(0.0, started + 3.0 - time.monotonic()))
        first.kill()  # SIGKILL: no CLOSE, the port is freed
        first.communicate()
        time.sleep(max(0.0, started + 4.0 - time.monotonic()))
        _go(second)
    else:
        second.kill()
        second.communicate()
        second = first
    out, err = master.communicate(timeout=60)
    if master.returncode != 0 or not out:
        raise SystemExit(f"the master failed ({master.returncode}): {err.strip()}")
    second.send_signal(signal.SIGINT)
    second.communicate(timeout=60)
    summary = json.loads(out)
    reconnects = summary["reconnects"]
    return {
        "samples_received": summary["samples_received"],
        "reconnects": reconnects["count"],
        "causes": reconnects["causes"],
        "new_session_at_s": reconnects["last_at_s"],
        "since_last": reconnects["samples_received_since_last"],
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=3)
    count = parser.parse_args().runs
    runs, baselines = [], []
    for _ in range(count):  # interleaved: both see the same machine load
        baselines.append(one_run(restart=False))
        runs.append(one_run())
    for run in baselines:
        print("baseline (no restart):", json.dumps(run))
    for run in runs:
        print("restart:", json.dumps(run))
    base = [int(run["samples_received"]) for run in baselines]  # type: ignore[call-overload]
    print(f"baseline samples received: median {statistics.median(base)}, min {min(base)}, "
          f"max {max(base)}")  # fmt: skip
    received = [int(run["samples_received"]) for run in runs]  # type: ignore[call-overload]
    print(f"samples received: median {statistics.median(received)}, min {min(received)}, "
          f"max {max(received)} of {len(received)} runs")  # fmt: skip


if __name__ == "__main__":
    main()
