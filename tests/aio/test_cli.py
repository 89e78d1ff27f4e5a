"""The ``tdtp`` command: the demo's JSON contract, and the argument checks."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tdtp.cli.main import main
from tdtp.cli.options import build_parser, host_port


def _demo(*extra: str) -> dict[str, object]:
    done = subprocess.run(
        [sys.executable, "-m", "tdtp", "demo", "--duration", "1.5", "--json", *extra],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    summary: dict[str, object] = json.loads(done.stdout)  # exactly one JSON object
    return summary


@pytest.mark.parametrize("extra", [(), ("--separate-acks", "--loop", "asyncio")])
def test_demo_json_reports_both_directions(extra: tuple[str, ...]) -> None:
    summary = _demo(*extra)
    import tdtp

    # Which build of the core ran: the same as in this process (the same environment).
    assert summary["core"] == tdtp.build_info().as_dict()
    # What carried the datagrams, and the layer's own account of the master's socket.
    layer = summary["datagram_layer"]
    if summary["sockets"] == "loop's transport":
        assert layer is None
    else:
        assert str(summary["sockets"]).startswith("datagram layer (")
        assert isinstance(layer, dict)
        m2s = summary["master_to_slave"]
        assert isinstance(m2s, dict)
        assert layer["datagrams_sent"] >= m2s["packets_sent"]  # data, plus ACKs and CONTROL
        assert (
            layer["send_calls"] <= layer["datagrams_sent"] + layer["send_errors"] + layer["blocked"]
        )
    for key in ("master_to_slave", "slave_to_master"):
        direction = summary[key]
        assert isinstance(direction, dict)
        for field in (
            "samples_offered",
            "packets_sent",
            "packets_received",
            "losses",
            "mean_rate",
            "srtt_ms",
            "header_bytes",
        ):
            assert field in direction, field
        # What the run recorded must add up, however fast or busy the machine was: every offered
        # sample was sent or superseded by a newer one, and on loopback every sent one arrived.
        offered, sent = direction["samples_offered"], direction["packets_sent"]
        assert offered >= 1
        assert sent + direction["samples_superseded"] == offered
        assert direction["losses"] == 0
        assert direction["packets_received"] == sent
        # 5 header bytes on every datagram the sender sent: its data, plus a few control packets
        # (and, with separate ACKs, its ACKs for the other direction).
        assert direction["header_bytes"] % 5 == 0
        assert direction["header_bytes"] >= 5 * direction["packets_sent"]
        # The receiver's sample ages (PROTOCOL.md 3.6): there, ordered, and timed only when the
        # samples carry acknowledgements or their own send time.
        age = direction["sample_age_ms"]
        assert 0.0 < age["p50"] <= age["p99"]
        assert 0 <= direction["samples_timed"] <= direction["samples_delivered"]
        if "--separate-acks" in extra:
            # No acknowledgement in the data: only the samples with their own send time are timed
            # (TIMED_DATA, one every 4 ms or so: PROTOCOL.md 5.13).
            assert direction["samples_timed"] < direction["samples_delivered"] / 2
    separate = "--separate-acks" in extra
    acks_back = summary["master_to_slave"]["ack_packets_sent_back"]  # type: ignore[index]
    # Separate ACKs: one per data packet the slave received. Piggybacked: at most the one or two
    # stand-alone ACKs at the very end, when the reverse flow has stopped.
    received = summary["master_to_slave"]["packets_received"]  # type: ignore[index]
    assert (acks_back >= received) if separate else (acks_back <= 2)


def test_bad_arguments_are_refused_with_a_message(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["master", "no-port-here"])
    assert "expected HOST:PORT" in capsys.readouterr().err


def test_host_port_forms() -> None:
    assert host_port("127.0.0.1:7000") == ("127.0.0.1", 7000)
    assert host_port("[::1]:7000") == ("::1", 7000)
    assert host_port("fe80::1:7000") == ("fe80::1", 7000)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


def _wait_until_listening(port: int, patience: float = 20.0) -> None:
    """Until a slave answers on ``port`` (an OPEN gets its COOKIE): a master started earlier would
    fail at once, as it should, on the ICMP port unreachable."""
    import time

    from tdtp.wire import PROTOCOL_VERSION, OpenBody, encode_header, encode_open

    probe_open = encode_header(2, 0, 0, 0, 255) + encode_open(
        OpenBody(PROTOCOL_VERSION, 0, 0, 1200, 0, bytes(16), bytes(8), bytes(16))
    )
    deadline = time.monotonic() + patience
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.settimeout(0.1)
        while time.monotonic() < deadline:
            probe.sendto(probe_open, ("127.0.0.1", port))
            try:
                probe.recv(100)
                return
            except OSError:  # no answer yet, or ICMP refused
                time.sleep(0.05)
    raise AssertionError(f"no slave answered on port {port}")


def test_master_and_slave_json_tell_each_direction_from_their_end(tmp_path: Path) -> None:
    port = _free_udp_port()
    slave = subprocess.Popen(
        [sys.executable, "-m", "tdtp", "slave", "--host", "127.0.0.1", "--port", str(port),
         "--json", "--pcap", str(tmp_path / "slave.pcap")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        _wait_until_listening(port)
        master_run = subprocess.run(
            [sys.executable, "-m", "tdtp", "master", f"127.0.0.1:{port}", "--duration", "1",
             "--json"],
            capture_output=True, text=True, timeout=60, check=False,
        )  # fmt: skip
        # Stopped once the master is done (Ctrl-C: it prints its summary), not after a fixed
        # duration that a slow start of the master could outlast.
        slave.send_signal(signal.SIGINT)
        slave_out, slave_err = slave.communicate(timeout=60)
    finally:
        slave.kill()
    assert master_run.returncode == 0, master_run.stderr
    assert slave.returncode == 130, slave_err  # Ctrl-C's status, after its summary
    master, served = json.loads(master_run.stdout), json.loads(slave_out)
    out, back = master["master_to_slave"], master["slave_to_master"]
    assert out["observed_at"] == back["observed_at"] == ["master"]
    # The master's own direction: every packet it sent has exactly one fate so far.
    assert out["packets_sent"] > 0
    assert out["packets_sent"] == (
        out["packets_acked"] + out["losses"] + out["packets_unreported"] + out["packets_in_flight"]
    )
    assert out["packets_received"] is None  # the slave's count is in the slave's output
    assert back["packets_received"] > 0 and back["srtt_ms"] is None
    assert back["latency_ms"] is not None  # same host, haptic samples: measurable
    assert out["latency_ms"] is None and "another process" in out["latency_note"]
    (session,) = served["sessions"]
    assert session["closed"] and session["master"].startswith("127.0.0.1:")
    seen_in, seen_out = session["master_to_slave"], session["slave_to_master"]
    assert seen_in["observed_at"] == ["slave"]
    # Loopback: what the master sent, the slave received, and the other way round at most what
    # the slave sent (its last samples may arrive after the master closed).
    assert seen_in["packets_received"] == out["packets_sent"]
    assert back["packets_received"] <= seen_out["packets_sent"]
    assert seen_out["packets_acked"] <= back["packets_received"]
    assert seen_in["drops_at_receiver"] == {}
    # The slave's socket carried at least every DATA it received and sent (plus control and ACKs).
    carried = seen_in["packets_received"] + seen_out["packets_sent"]
    assert served["pcap"]["packets"] >= carried and served["pcap"]["error"] is None


def test_an_unwritable_capture_is_one_line_and_status_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--duration", "0.5", "--pcap", "/nonexistent/dir/x.pcap"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tdtp: cannot write the capture file") and err.count("\n") == 1


HOSTILE_PAYLOADS = [
    bytes(range(100)),  # random-looking bytes
    b"\xff" * 100,  # NaNs everywhere in the demo's layout
    __import__("struct").pack(">dI3f3f", 1.0, 1, 1e38, 0, 0, 0, 0, 0) + bytes(64),
    __import__("struct").pack(">dI3f3f", 1.0, 1, 7e35, 0, 0, 0, 0, 0) + bytes(64),
    b"x",  # one byte
    bytes(1200),  # the largest payload the slave takes
]


def test_the_cli_slave_keeps_serving_whatever_the_payload_bytes() -> None:
    """Issue 20, item 5: payloads the demo does not recognise are opaque; the session goes on."""
    import asyncio
    import signal

    import tdtp

    from eventually import eventually

    port = _free_udp_port()
    slave = subprocess.Popen(
        [sys.executable, "-m", "tdtp", "slave", "--host", "127.0.0.1", "--port", str(port),
         "--rate", "200", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip

    async def hostile_master() -> tuple[int, int]:
        async with tdtp.connect("127.0.0.1", port) as ep:
            for payload in HOSTILE_PAYLOADS * 20:
                ep.send(payload)
                await asyncio.sleep(0.002)
            offered = ep.stats.samples_offered
            sent = ep.stats.sent.data_packets
            # Every hostile sample that left has its fate (loopback: acknowledged)...
            await eventually(lambda: ep.stats.packets_acked >= sent, within=30)
            # ...and the slave still answers afterwards: its send task survived them.
            heard = ep.stats.samples_delivered
            await eventually(lambda: ep.stats.samples_delivered >= heard + 20, within=30)
            return offered, sent

    try:
        _wait_until_listening(port)
        offered, sent = asyncio.run(hostile_master())
        slave.send_signal(signal.SIGINT)
        out, err = slave.communicate(timeout=60)
    finally:
        slave.kill()
    assert slave.returncode == 130, err
    assert offered == len(HOSTILE_PAYLOADS) * 20 and sent > 0
    (session,) = json.loads(out)["sessions"]
    assert session["task_error"] is None and "Traceback" not in err
    assert session["samples_received"] == sent  # loopback: every one arrived, none fatal
    assert session["samples_sent"] > 0


def test_master_and_slave_print_text_unless_json_is_asked_for() -> None:
    """Issue 20, item 9: the 89-line JSON came after the live display even without --json."""
    done = subprocess.run(
        [sys.executable, "-m", "tdtp", "slave", "--host", "127.0.0.1", "--port", "0",
         "--duration", "0.3"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    last = done.stdout.strip().splitlines()[-1]
    assert last == "served 0 master(s), refused 0" and "{" not in done.stdout


def test_demo_deadband_reports_what_it_held_back() -> None:
    """Issue 21: --deadband K sends only the samples worth sending, and says so per direction."""
    summary = _demo("--deadband", "0.1")
    for key, unit in (("master_to_slave", "m"), ("slave_to_master", "N")):
        direction = summary[key]
        assert isinstance(direction, dict)
        band = direction["deadband"]
        assert band["k"] == 0.1 and band["unit"] == unit
        # What the deadband let through is exactly what the application handed to the transport.
        assert band["sent"] == direction["samples_offered"] > 0
        assert band["offered"] >= band["sent"] and band["reconstruction_rmse"] >= 0.0
        assert band["sent_fraction"] == round(band["sent"] / band["offered"], 4)


def test_demo_over_two_paths_reports_each_path_and_the_copies() -> None:
    """``tdtp demo --path NETEM --path NETEM``: a multipath session; per direction the dropouts,
    the copies dropped as duplicates, and the sender's paths."""
    summary = _demo("--path", "delay 5ms", "--path", "delay 10ms", "--multipath", "redundant")
    assert summary["multipath"] == "redundant"
    assert summary["paths_netem"] == ["delay 5ms", "delay 10ms"]
    for key in ("master_to_slave", "slave_to_master"):
        direction = summary[key]
        assert isinstance(direction, dict)
        assert isinstance(direction["dropouts_100ms"], int)
        paths = direction["paths"]
        assert [path["id"] for path in paths] == [0, 1]
        for path in paths:
            assert set(path) >= {"sent", "first_delivered", "srtt_ms", "state"}
            assert 0 <= path["first_delivered"] <= path["sent"]
        # Every sample went on both paths once the second was validated: the receiver dropped
        # the later copies, and each delivered sample came first on one path or the other.
        assert 0 < direction["duplicates"] <= paths[1]["sent"]
        assert sum(p["first_delivered"] for p in paths) <= direction["packets_sent"]


def test_a_single_path_demo_reports_dropouts_and_no_paths() -> None:
    summary = _demo()
    direction = summary["master_to_slave"]
    assert isinstance(direction, dict)
    assert isinstance(direction["dropouts_100ms"], int)
    assert direction["paths"] is None and direction["duplicates"] == 0
