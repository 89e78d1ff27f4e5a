"""Every way to misuse the ``tdtp`` command gets one line on stderr and exit status 2, never a
traceback; interrupted and failed runs still say what happened."""

from __future__ import annotations

import asyncio
import io
import json
import os
import queue
import re
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator

import pytest

from tdtp import __version__, listen
from tdtp.aio.relay import start_relay
from tdtp.cli.live_stats import LiveDisplay
from tdtp.cli.main import main

from eventually import eventually

TDTP = [sys.executable, "-m", "tdtp"]


@pytest.fixture
def busy_port() -> Iterator[int]:
    """A UDP port on all interfaces that something else holds."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("0.0.0.0", 0))
        yield holder.getsockname()[1]


@pytest.fixture
def slave_port() -> Iterator[int]:
    """A library slave with the default configuration, in a thread of its own."""
    ports: queue.Queue[int] = queue.Queue()
    stop = threading.Event()

    async def serve() -> None:
        async with listen("127.0.0.1", 0) as server:
            ports.put(server.port)
            while not stop.is_set():
                await asyncio.sleep(0.01)

    thread = threading.Thread(target=asyncio.run, args=(serve(),), daemon=True)
    thread.start()
    yield ports.get(timeout=30)
    stop.set()
    thread.join(timeout=30)


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    try:
        status = main(argv)
    except SystemExit as exc:  # argparse's own errors
        status = int(exc.code or 0)
    return status, capsys.readouterr().err


MISUSES: list[tuple[list[str], str]] = [
    (["master", "nosuch.invalid:7000", "--duration", "1"], "host name not resolved"),
    (["slave", "--port", "-1"], "--port"),
    (["slave", "--port", "70000"], "--port: must be in 0..65535"),
    (["slave", "--port", "0", "--max-peers", "0"], "--max-peers"),
    (["slave", "--host", "nosuch.invalid", "--port", "0"], "host name not resolved"),
    (["slave", "--host", "192.0.2.1", "--port", "0"], "not an address of this host"),
    (["demo", "--rate", "inf"], "--rate"),
    (["demo", "--rate", "nan"], "--rate"),
    (["demo", "--rate", "0"], "--rate"),
    (["demo", "--rate", "1e9"], "at most 100000"),
    (["demo", "--rate", "fast"], "expected a number"),
    (["demo", "--size", "8"], "--size: must be in 36..65484"),
    (["demo", "--size", "70000"], "--size"),
    (["demo", "--ack-size", "3"], "--ack-size"),
    (["demo", "--ack-size", "5000"], "--ack-size: ack_size must be an integer in 5..1205"),
    (["demo", "--duration", "nan"], "--duration"),
    (["demo", "--duration", "-1"], "--duration"),
    (["demo", "--silence-timeout", "40"], "--silence-timeout: silence_timeout (40.0 s)"),
    (["demo", "--idle-timeout", "0.05"], "shorter than idle_timeout"),
    (["demo", "--netem", "delay 20xs"], "20xs"),
    (["demo", "--netem-seed", "-5", "--netem", "loss 1%"], "--netem-seed"),
    (["demo", "--controller", "nope"], "invalid choice: 'nope'"),
    (["master", "127.0.0.1:9", "--takeover"], "--takeover needs --key-file"),
    (["slave", "--port", "0", "--exclusive", "--takeover-after", "0"], "--takeover-after"),
    (["master", "127.0.0.1:0"], "expected HOST:PORT"),
    (["master", "no-port-here"], "expected HOST:PORT"),
    (["netem-relay", "delay 1ms", "--listen", ":0", "--forward", "nosuch.invalid:1"], "resolved"),
    (
        [
            "netem-relay",
            "delay 1ms",
            "--listen",
            ":0",
            "--forward",
            "127.0.0.1:1",
            "--max-clients",
            "0",
        ],
        "--max-clients",
    ),
    (["netem-relay", "delay 1ms", "--listen", ":99999", "--forward", "127.0.0.1:1"], "--listen"),
    (
        ["netem-relay", "delay 1ms", "--listen", ":0", "--forward", "127.0.0.1:1", "--seed", "-1"],
        "--seed",
    ),
    (["netem-relay", "loss 200%", "--listen", ":0", "--forward", "127.0.0.1:1"], "200%"),
    (["simulate", "paper", "--out", "/proc/no/such/dir"], "--out"),
    (["demo", "--multipath", "adaptive"], "--multipath in the demo needs its paths"),
    (["demo", "--path", "delay 1ms", "--netem", "loss 1%"], "--path gives each path"),
    (["demo", "--path", "delay 20xs"], "20xs"),
    (["demo", "--multipath", "sideways"], "invalid choice: 'sideways'"),
    (["master", "127.0.0.1:9", "--local-address", "10.0.0.1:99999"], "the local address"),
    (["master", "127.0.0.1:9", "--local-address", "192.0.2.1"], "not an address of this host"),
    (
        ["master", "127.0.0.1:9", "--local-address", "127.0.0.1", "--netem", "loss 1%"],
        "--local-address opens one socket per path",
    ),
    ([], "the following arguments are required"),
]


@pytest.mark.parametrize(("argv", "message"), MISUSES, ids=[" ".join(a) for a, _ in MISUSES])
def test_misuse_is_one_line_and_exit_status_2(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    status, err = _run(argv, capsys)
    assert status == 2, err
    assert message in err
    assert len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err


def test_a_port_in_use_is_a_usage_error(busy_port: int, capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (
        ["slave", "--port", str(busy_port), "--duration", "1"],
        ["netem-relay", "delay 1ms", "--listen", f":{busy_port}", "--forward", "127.0.0.1:1"],
    ):
        status, err = _run(argv, capsys)
        assert status == 2 and "in use" in err and len(err.strip().splitlines()) == 1, err


def test_a_sample_larger_than_the_slave_accepts_is_refused_at_the_open(
    slave_port: int, capsys: pytest.CaptureFixture[str]
) -> None:
    """The master's --size sets its min_peer_payload: a slave that accepts less is refused at the
    open, with both figures, instead of failing on the first send."""
    status, err = _run(["master", f"127.0.0.1:{slave_port}", "--size", "5000"], capsys)
    assert status == 1, err
    assert "the slave accepts payloads of at most 1200 bytes" in err and "(5000)" in err
    assert len(err.strip().splitlines()) == 1


def test_a_missing_uvloop_or_timerfd_is_a_usage_error(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "uvloop", None)  # import uvloop raises ImportError
    status, err = _run(["demo", "--loop", "uvloop"], capsys)
    assert status == 2 and "uvloop is not installed" in err
    import tdtp.aio.timer

    monkeypatch.setattr(tdtp.aio.timer, "timerfd_unavailable_reason", lambda: "not here")
    status, err = _run(["demo", "--timer", "timerfd", "--loop", "asyncio"], capsys)
    assert status == 2 and "timerfd is unavailable here (not here)" in err


def test_nothing_listening_fails_fast_with_exit_status_1(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    status, err = _run(["master", f"127.0.0.1:{port}"], capsys)
    assert status == 1
    assert f"nothing listens at 127.0.0.1:{port}" in err


def test_version_and_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["--version"])
    assert exited.value.code == 0
    assert capsys.readouterr().out.strip() == f"tdtp {__version__}"
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    help_text = capsys.readouterr().out
    assert "loss 2%" in help_text and "2%%" not in help_text


def test_a_very_low_rate_still_ends_at_the_duration() -> None:
    """One sample every 31 years: the demo used to wait for the second tick forever."""
    done = subprocess.run(
        [*TDTP, "demo", "--rate", "1e-9", "--duration", "1", "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["master_to_slave"]["samples_offered"] == 1


def test_ctrl_c_keeps_the_final_summary() -> None:
    with subprocess.Popen(
        [*TDTP, "demo", "--duration", "120"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as process:
        assert process.stdout is not None
        for line in process.stdout:  # wait until it runs: the first live display block
            if line.startswith("t="):
                break
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "M->S: offered" in out and "S->M: offered" in out
    assert "Traceback" not in err


def test_the_live_display_fits_an_80_column_terminal() -> None:
    """Lines the terminal wrapped itself took two rows each and the in-place redraw garbled."""

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    terminal = Terminal()
    display = LiveDisplay(terminal, width=80)
    line = (
        "M->S     1000 pkt/s  lost    0 ( 0.00%)  srtt   0.109 ms  p 0.0000  allowed     2037/s"
        "  superseded      0  latency p50  0.065 ms p99  0.172 ms  SILENT: slave hears nothing"
    )
    display.update(["t=   1.0 s", line, line])
    first = terminal.getvalue()
    display.update(["t=   2.0 s", line, line])
    second = terminal.getvalue()[len(first) :]
    # The redraw moves the cursor up exactly the rows drawn before, and no row is wider than 80.
    assert second.startswith(f"\x1b[{first.count(chr(10))}F")
    for row in (first + second).split("\n"):
        assert len(re.sub(r"\x1b\[\d*[FK]", "", row)) <= 80
    assert first.count("\n") > 3  # the long lines were broken between fields
    assert "SILENT: slave hears nothing" in first


@pytest.mark.asyncio
async def test_a_master_that_loses_its_slave_reports_the_true_cause() -> None:
    """The master's live display shows the silence, and when it outlasts --idle-timeout the run
    ends with exit status 1 and the cause (today: 'closed by the slave', exit 0)."""
    async with listen("127.0.0.1", 0) as server:
        relay = await start_relay(("127.0.0.1", 0), ("127.0.0.1", server.port), "delay 1ms")
        try:
            process = await asyncio.create_subprocess_exec(
                *TDTP,
                "master",
                f"127.0.0.1:{relay.address[1]}",
                "--idle-timeout",
                "3",
                "--no-reconnect",  # (reconnecting, it would open a new session instead)
                stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE,
                env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
            assert process.stdout is not None and process.stderr is not None
            async with asyncio.timeout(60):
                slave = await server.accept()
                await eventually(lambda: slave.stats.samples_delivered > 10)  # master is open
                relay.change("loss 100%")
                output: list[str] = []

                async def read_until(text: str) -> None:
                    while not any(text in line for line in output):
                        line = (await process.stdout.readline()).decode()  # type: ignore[union-attr]
                        assert line, f"the master ended before printing {text!r}"
                        output.append(line)

                await read_until("master hears nothing from the slave (watchdog)")
                await read_until("SILENT: master hears nothing")  # in the live block
                relay.change("delay 1ms")  # the slave is back for a while...
                await read_until("master hears the slave again after")
                relay.change("loss 100%")  # ...and gone for good
                rest, err = await process.communicate()
            assert process.returncode == 1, err
            assert b"session lost (idle_timeout)" in err
            # Without --json, the summary's last line says how the session ended.
            last = rest.decode().strip().splitlines()[-1]
            assert last.startswith("session closed (idle_timeout), slave silent 2 time(s)")
        finally:
            await relay.close()
