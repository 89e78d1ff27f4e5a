"""The examples run: each is started as a user would start it, on real loopback sockets, for a few
seconds, and judged by what the run itself recorded (its ``--json`` summary), never by rates expected
from the clock. Every wait has a bound."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

import tdtp

EXAMPLES = Path(__file__).resolve().parent.parent.parent / "examples"
ARM = EXAMPLES / "arm"
BOUND = 60.0
"""Seconds any one step may take before the test fails (a loaded machine is slow, not broken)."""


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _start(script: Path, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(script), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def _wait_for_line(process: subprocess.Popen[str], text: str) -> list[str]:
    """Read the process's output up to a line containing ``text`` (bounded): the lines read."""
    assert process.stdout is not None
    deadline = time.monotonic() + BOUND
    seen: list[str] = []
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if not line:
            break
        seen.append(line)
        if text in line:
            return seen
    process.kill()
    raise AssertionError(f"no line with {text!r} from {process.args}; it printed: {seen}")


@contextmanager
def _robot(keys: Path, port: int, summary: Path) -> Iterator[subprocess.Popen[str]]:
    robot = _start(
        ARM / "robot.py", "--key-file", str(keys), "--port", str(port), "--json", str(summary)
    )
    try:
        _wait_for_line(robot, "robot listening on")
        yield robot
    finally:
        _stop(robot)


def _stop(process: subprocess.Popen[str]) -> None:
    """Ctrl-C, and wait (bounded) for the summary to be written."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    try:
        process.communicate(timeout=BOUND)
    except subprocess.TimeoutExpired:
        process.kill()
        raise


def _operator(keys: Path, port: int, summary: Path, *args: str) -> subprocess.Popen[str]:
    return _start(
        ARM / "operator_station.py",
        f"127.0.0.1:{port}",
        "--key-file",
        str(keys),
        "--json",
        str(summary),
        *args,
    )


def _keys(tmp_path: Path) -> Path:
    path = tmp_path / "arm.keys"
    tdtp.write_key_file(path, [tdtp.PresharedKey.generate("operator-1")])
    return path


def test_the_arm_teleoperation_applies_mode_estop_and_resume_in_order(tmp_path: Path) -> None:
    keys, port = _keys(tmp_path), _free_port()
    robot_json, operator_json = tmp_path / "robot.json", tmp_path / "operator.json"
    with _robot(keys, port, robot_json):
        operator = _operator(
            keys,
            port,
            operator_json,
            "--seconds",
            "3",
            "--mode-at",
            "0.5=compliant",
            "--estop-at",
            "1.2",
            "--resume-at",
            "2",
        )
        output, _ = operator.communicate(timeout=BOUND)
        assert operator.returncode == 0, output
    assert "link ok" in output or "link ROBOT SILENT" in output  # the live status line ran
    ran, robot = json.loads(operator_json.read_text()), json.loads(robot_json.read_text())
    sent = ["MODE compliant", "ESTOP", "RESUME"]
    assert ran["control_sent"] == sent
    assert robot["control"] == sent  # exactly once each, in the order sent
    assert ran["control_done"] == [f"DONE {message}" for message in sent]
    # The deadband let through some of the commands, not all; the robot applied what came.
    assert 0 < ran["commands_sent"] < ran["commands_offered"]
    assert 0 < robot["commands_applied"] <= robot["commands_received"] <= ran["commands_sent"]
    (stop,) = robot["stops"]
    assert stop[0] == stop[1]  # not a joint moved during the emergency stop
    assert any(abs(q) > 0.0 for q in robot["q"]) and ran["states_received"] > 0


def test_the_arm_holds_on_silence_and_the_operator_reconnects_to_a_restarted_robot(
    tmp_path: Path,
) -> None:
    keys, port = _keys(tmp_path), _free_port()
    robot_json, operator_json = tmp_path / "robot.json", tmp_path / "operator.json"
    first = _start(ARM / "robot.py", "--key-file", str(keys), "--port", str(port))
    operator = None
    try:
        _wait_for_line(first, "robot listening on")
        operator = _operator(keys, port, operator_json, "--seconds", "120")
        _wait_for_line(first, "operator operator-1 connected")
        operator.send_signal(signal.SIGSTOP)  # the operator's station freezes for 0.5 s
        time.sleep(0.5)
        operator.send_signal(signal.SIGCONT)
        lines = _wait_for_line(first, "operator back: following")
        assert any("operator silent: holding" in line for line in lines)  # the watchdog held
        first.kill()  # the robot's computer crashes, and comes back on the same port
        first.communicate(timeout=BOUND)
        with _robot(keys, port, robot_json) as second:
            _wait_for_line(second, "operator operator-1 connected")
            time.sleep(0.3)
            _stop(operator)  # the operator stops first: the robot has not closed its session
    finally:
        first.kill()
        if operator is not None:
            _stop(operator)
    ran, restarted = json.loads(operator_json.read_text()), json.loads(robot_json.read_text())
    assert ran["reconnects"] >= 1 and ran["silences"] >= 1
    assert restarted["sessions"] == 1 and restarted["commands_received"] > 0


def test_the_minimal_haptic_loop_closes_the_loop() -> None:
    run = subprocess.run(
        [sys.executable, str(EXAMPLES / "haptic_loop.py"), "--seconds", "2"],
        capture_output=True,
        text=True,
        timeout=BOUND,
        check=True,
    )
    report = json.loads(run.stdout.strip().splitlines()[-1])
    assert report["positions_sent"] > 0 and report["forces_received"] > 0
    assert report["forces_received"] <= report["forces_sent"]
    assert report["strongest_push_n"] < 0.0  # the hand went into the wall and felt it


def test_the_two_process_master_and_slave_run() -> None:
    port = _free_port()
    slave = _start(EXAMPLES / "slave.py", "--port", str(port))
    try:
        _wait_for_line(slave, "slave listening on")
        master = subprocess.run(
            [sys.executable, str(EXAMPLES / "master.py"), f"127.0.0.1:{port}", "--seconds", "2"],
            capture_output=True,
            text=True,
            timeout=BOUND,
            check=True,
        )
        assert "connected to" in master.stdout
    finally:
        slave.send_signal(signal.SIGINT)
        try:
            slave.communicate(timeout=BOUND)
        except subprocess.TimeoutExpired:
            slave.kill()


pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals (SIGSTOP)")


def test_the_tutorials_robot_and_operator_run(tmp_path: Path) -> None:
    """docs/tutorial/: the keyed pair the tutorial builds, on one machine."""
    tutorial = EXAMPLES.parent / "docs" / "tutorial"
    keys, port = _keys(tmp_path), _free_port()
    robot = _start(tutorial / "robot.py", str(keys), "127.0.0.1", str(port))
    try:
        _wait_for_line(robot, "robot listening on")
        operator = subprocess.run(
            [
                sys.executable,
                str(tutorial / "operator_station.py"),
                f"127.0.0.1:{port}",
                str(keys),
                "2",
            ],
            capture_output=True,
            text=True,
            timeout=BOUND,
            check=True,
        )
        assert "keyed as operator-1" in operator.stdout
        assert "robot says ok" in operator.stdout  # the robot answered what it did
        _wait_for_line(robot, "operator operator-1 connected")
    finally:
        robot.kill()
        robot.communicate()
