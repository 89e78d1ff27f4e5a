"""``tdtp demo`` shows what its emulated links hold: the live line and the ``--json`` report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tdtp.aio.timer import monotonic
from tdtp.cli.netem_view import netem_lines, netem_report
from tdtp.netem import NetemLink, parse_netem


class _Side:
    def __init__(self, link: NetemLink | None) -> None:
        self.netem_link = link


def test_the_line_says_what_each_queue_holds_and_drops(tmp_path: Path) -> None:
    trace = tmp_path / "slow.trace"
    trace.write_text("1000\n")  # one opportunity a second
    link = NetemLink(parse_netem(f"trace {trace} limit-bytes 250"), seed=1)
    now = monotonic()  # the demo's clock
    for _ in range(4):
        link.send(bytes(100), now)  # two wait (a second, for the opportunity), two are dropped
    plain = NetemLink(parse_netem("delay 20ms"), seed=1)
    plain.send(b"x", now)
    (line,) = netem_lines(_Side(link), _Side(plain))
    assert line.startswith("emulated  M->S queue 0.2 kB")
    assert "dropped 2" in line and "S->M in flight" in line
    report = netem_report(_Side(link))
    assert report is not None
    assert report["queue_dropped"] == 2 and report["trace_queue_at_end"]["bytes"] == 200
    assert netem_lines(_Side(None), _Side(None)) == []
    assert netem_report(_Side(None)) is None


def test_demo_reports_its_emulated_links(tmp_path: Path) -> None:
    trace = tmp_path / "fast.trace"
    trace.write_text("".join(f"{t}\n" for t in range(1, 101)))
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "tdtp",
            "demo",
            "--duration",
            "0.5",
            "--json",
            "--netem-sm",
            f"delay 5ms trace {trace} overhead 28 limit-bytes 15000",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    link = summary["slave_to_master"]["emulated_link"]
    # What the run recorded, whatever the machine's speed: every datagram accounted for.
    assert link["sent"] > 0
    assert link["sent"] + link["duplicated"] == (
        link["delivered"] + link["lost"] + link["queue_dropped"] + link["pending"]
    )
    assert 0 <= link["trace_queue_at_end"]["datagrams"] <= link["pending"]
    assert "emulated_link" not in summary["master_to_slave"]  # no netem that way
