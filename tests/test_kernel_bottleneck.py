"""The real-kernel bottleneck check (benchmarks/kernel_bottleneck.py) runs end to end: namespaces made and
removed, iperf3 and a tdtp master/slave pair through a tbf, and what they recorded adds up.

Never a rate: the machine is shared. Skips without root, ``ip``, ``tc`` with tbf, or iperf3.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import tdtp.control

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "kernel_bottleneck.py"


def _run(*argv: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def test_tcp_and_a_tdtp_pair_share_a_tbf_and_every_byte_is_accounted_for() -> None:
    controller = tdtp.control.DEFAULT_CONTROLLER
    done = _run("--duration", "2", "--controllers", controller, "--tcp", "cubic", "--json")
    if done.returncode == 1 and "cannot set up" in done.stderr:
        pytest.skip(done.stderr.strip().splitlines()[-1])  # e.g. a kernel without tbf or veth
    assert done.returncode == 0, done.stderr
    report: dict[str, Any] = json.loads(done.stdout)
    details = report["details"]
    if "skipped" in details:
        pytest.skip(details["skipped"])
    runs = details["runs"]
    assert [r["controller"] for r in runs] == [None, controller]
    assert all("error" not in r for r in runs), runs
    for r in runs:
        tcp, tbf = r["tcp"], r["tbf"]
        assert tcp["congestion"] == "cubic"
        assert 0 < tcp["bytes_received"] <= tcp["bytes_sent"]
        # Every TCP byte the receiver got and every tdtp datagram the slave got crossed the tbf.
        through = tcp["bytes_received"] + tbf["tdtp_bytes"]
        assert tbf["bytes"] >= through
    pair = runs[1]["tdtp"]
    for way in ("ms", "sm"):
        d = pair[way]
        assert 0 < d["packets_received"] <= d["packets_sent"]
        assert d["samples_delivered"] <= d["packets_received"]
        assert d["packets_sent"] + d["superseded"] <= d["offered"]
    assert runs[1]["tbf"]["tdtp_bytes"] == pair["ms"]["wire_bytes_at_tbf"] > 0
    # The namespaces are gone, and nobody else's were touched.
    assert details["namespaces_left"] == []
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=False)
    assert details["namespaces"] not in listed.stdout
    assert len(report["rows"]) == 3  # TCP alone; beside the pair: TCP's share and tdtp's


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["--duration", "0"], "--duration"),
        (["--controllers", "smoke-signals"], "--controllers"),
        (["--rate", "fast"], "--rate"),
        (["--queue-ms", "-1"], "--queue-ms"),
    ],
)
def test_misuse_is_one_line_and_status_2(argv: list[str], option: str) -> None:
    done = _run(*argv, timeout=60)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and option in lines[0], done.stderr
