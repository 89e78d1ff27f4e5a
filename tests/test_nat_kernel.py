"""A robot behind the kernel's NAT (issue 34), in network namespaces these tests make (tests/natlab.py):
today's failure and its answer (the robot dials out), a rendezvous through ``tdtp relay`` with
endpoint-independent and symmetric NATs, a conntrack flush mid-session, a direct path cut and
healed. Real processes (the ``tdtp`` command); each test checks what the run recorded, never a
rate. Skipped without root, ``ip``, ``nft`` (nftables) or ``conntrack``.
"""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from natlab import RELAY_ADDR, NatLab, missing

pytestmark = pytest.mark.skipif(missing() is not None, reason=str(missing()))

TDTP = (sys.executable, "-m", "tdtp")
RELAY = f"{RELAY_ADDR}:7700"
NAME = ("--rendezvous-name", "robot-7")


def _json(process: subprocess.Popen[str], what: str, timeout: float = 30.0) -> dict[str, Any]:
    out, err = process.communicate(timeout=timeout)
    assert process.returncode in (0, 130), f"{what} exited {process.returncode}: {err[-1500:]}"
    report: dict[str, Any] = json.loads(out)
    return report


def _relay(lab: NatLab, seconds: float) -> subprocess.Popen[str]:
    relay = lab.spawn(
        "relay", *TDTP, "relay", "--port", "7700", "--duration", str(seconds), "--json"
    )
    return relay


def _pair(
    lab: NatLab, seconds: float, *extra: str
) -> tuple[subprocess.Popen[str], subprocess.Popen[str]]:
    common = ("--rendezvous", RELAY, *NAME, "--duration", str(seconds), "--json", *extra)
    # Interrupted, the slave says it is gone for good: its master then ends the session instead of
    # reopening one (and reporting the empty new session) before its own interrupt arrives.
    slave = lab.spawn("ha", *TDTP, "slave", *common, "--on-stop", "shutdown")
    master = lab.spawn("hb", *TDTP, "master", *common)
    return slave, master


@contextlib.contextmanager
def _lab(a: str | None, b: str | None, *, firewall: bool = True) -> Iterator[NatLab]:
    with NatLab() as lab:
        lab.open(public_host=True)
        lab.add_site("a", a, firewall=firewall)  # type: ignore[arg-type]
        lab.add_site("b", b)  # type: ignore[arg-type]
        yield lab


def _flowed(master: dict[str, Any], slave: dict[str, Any]) -> None:
    """What the two ends recorded adds up: samples went both ways, nothing arrived unsent."""
    session = slave["sessions"][-1]
    sent_ms = master["master_to_slave"]["packets_sent"]
    got_ms = session["master_to_slave"]["packets_received"]
    sent_sm = session["slave_to_master"]["packets_sent"]
    got_sm = master["slave_to_master"]["packets_received"]
    assert 0 < got_ms <= sent_ms and 0 < got_sm <= sent_sm, (master, slave)


def test_the_namespaces_nat_as_claimed() -> None:
    """Endpoint-independent: one port for every destination; symmetric: a port per destination."""
    with _lab("eim", "symmetric") as lab:
        relay_port, public_port = lab.mappings("a")
        assert relay_port == public_port
        relay_port, public_port = lab.mappings("b")
        assert relay_port != public_port


def test_a_master_cannot_dial_a_robot_behind_nat_but_the_robot_can_dial_out() -> None:
    """Today's failure, reproduced: the NAT answers the OPEN with ICMP port unreachable. The error
    now says so; the robot dialing its operator works through the same NAT."""
    with _lab("eim", None, firewall=False) as lab:
        robot = lab.spawn("ha", *TDTP, "slave", "--port", "7000", "--duration", "6", "--json")
        time.sleep(1.0)  # the slave is up (it runs; the NAT is what answers)
        began = time.monotonic()
        master = lab.spawn("hb", *TDTP, "master", f"{lab.sites['a'].wan_addr}:7000", "--json")
        _, err = master.communicate(timeout=30)
        assert master.returncode == 1
        assert "nothing listens" in err and "NAT" in err and "docs/NAT.md" in err, err
        assert time.monotonic() - began < 20
        robot.kill()
        operator = lab.spawn("hb", *TDTP, "master", "--listen", "7000", "--duration", "4", "--json")
        time.sleep(1.0)
        dialer = lab.spawn(
            "ha", *TDTP, "slave", "--connect", f"{lab.sites['b'].wan_addr}:7000",
            "--duration", "2", "--json",
        )  # fmt: skip
        slave, master_report = _json(dialer, "slave"), _json(operator, "master")
        assert master_report["sessions"] == 1
        _flowed(master_report, slave)


def test_both_behind_endpoint_independent_nats_meet_on_a_direct_path() -> None:
    with _lab("eim", "eim") as lab:
        relay = _relay(lab, 60)
        slave_run, master_run = _pair(lab, 1.5)
        slave, master = _json(slave_run, "slave"), _json(master_run, "master")
        relay_report = _json_after(relay, signal.SIGINT)
        assert master["rendezvous"]["path"] == "direct", master["rendezvous"]
        assert slave["rendezvous"]["path"] == "direct", slave["rendezvous"]
        assert master["rendezvous"]["first_sample_s"] is not None
        # The direct path is the NATs' WAN addresses: a hole punched through both.
        assert master["rendezvous"]["peer"].startswith(lab.sites["a"].wan_addr)
        _flowed(master, slave)
        stats = relay_report["stats"]
        assert stats["rendezvous_paired"] == 1
        assert stats["unvalidated_bytes_out"] <= stats["unvalidated_bytes_in"]


def test_behind_a_symmetric_nat_the_session_runs_through_the_relay_even_when_it_restarts() -> None:
    """No direct path through a symmetric NAT: the relay carries the session. The relay is then
    killed and started again on its port: both sides register again at their next datagram
    through it and the session goes on, never ended."""
    with _lab("symmetric", "eim") as lab:
        for wan in (lab.sites["a"].wan_addr, lab.sites["b"].wan_addr):
            lab.count("relayed", RELAY_ADDR, wan)
        relay = _relay(lab, 120)
        slave_run, master_run = _pair(lab, 120)
        lab.wait_for_traffic("relayed", 300)
        first = _json_after(relay, signal.SIGINT)
        relay = _relay(lab, 120)  # the same port, no registrations
        lab.wait_for_traffic("relayed", 300)
        for process in (master_run, slave_run, relay):
            process.send_signal(signal.SIGINT)
        slave, master = _json(slave_run, "slave"), _json(master_run, "master")
        second = _json(relay, "relay")
        assert master["rendezvous"]["path"] == "relayed", master["rendezvous"]
        assert slave["rendezvous"]["path"] == "relayed", slave["rendezvous"]
        # The session rode the restart out (or, had the relay taken longer than --reconnect-after
        # to come back on a loaded machine, the master opened the next one through it).
        assert master["reconnects"]["count"] <= 1
        assert master["close"] is None or master["close"]["cause"] in ("local_close", "peer_close")
        _flowed(master, slave)
        for report in (first, second):
            stats = report["stats"]
            assert stats["rendezvous_paired"] == 1 and stats["forwarded"] > 0
            assert stats["unvalidated_bytes_out"] <= stats["unvalidated_bytes_in"]
        assert second["stats"]["unknown_sent"] >= 1  # how the two learnt of the restart


def _json_after(process: subprocess.Popen[str], sig: int) -> dict[str, Any]:
    process.send_signal(sig)
    return _json(process, "relay")


def test_a_cut_direct_path_falls_back_to_the_relay_and_comes_back() -> None:
    """Cut the direct path mid-session, heal it: the session goes to the relay, then back, and
    never ends; a conntrack flush at both NATs on the way changes nothing either. Each step waits
    for the packets the Internet's counters see, not for a time."""
    with _lab("eim", "eim") as lab:
        a, b = lab.sites["a"].wan_addr, lab.sites["b"].wan_addr
        for src, dst in ((a, b), (b, a)):
            lab.count("direct", src, dst)
        for wan in (a, b):
            lab.count("relayed", wan, RELAY_ADDR)
        relay = _relay(lab, 120)
        slave_run, master_run = _pair(lab, 120)
        lab.wait_for_traffic("direct", 300)
        lab.cut("a", "b")
        lab.wait_for_traffic("relayed", 300)  # back on the relay
        lab.heal()
        lab.flush_conntrack("a")
        lab.flush_conntrack("b")
        lab.wait_for_traffic("direct", 300)  # and direct again
        for process in (master_run, slave_run, relay):
            process.send_signal(signal.SIGINT)
        slave, master = _json(slave_run, "slave"), _json(master_run, "master")
        _json(relay, "relay")
        for report in (master, slave):
            rendezvous = report["rendezvous"]
            assert rendezvous["direct_paths_lost"] >= 1, rendezvous
            assert rendezvous["direct_paths_validated"] >= 1, rendezvous
            assert rendezvous["path"] == "direct", rendezvous
        # Ended by the interrupt (ours or the slave's CLOSE first), never by the cut.
        assert master["close"] is None or master["close"]["cause"] in ("local_close", "peer_close")
        assert master["reconnects"]["count"] == 0
        _flowed(master, slave)


@pytest.mark.parametrize("argv", [["--tries", "0"], ["--seconds", "-1"], ["--tries", "many"]])
def test_the_nat_benchmarks_misuse_is_one_line_and_status_2(argv: list[str]) -> None:
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "nat.py"
    done = subprocess.run(
        [sys.executable, str(script), *argv],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 2
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
