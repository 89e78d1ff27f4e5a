"""The command line's keys: tdtp keygen, --key-file, --keyed, and the unkeyed slave's warning."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tdtp import load_keys
from tdtp.cli.main import main


def _tdtp(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tdtp", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def test_keygen_writes_a_private_file_and_never_overwrites(tmp_path: Path) -> None:
    path = tmp_path / "pairing.keys"
    done = _tdtp("keygen", str(path), "--name", "station-1", "--name", "station-2")
    assert done.returncode == 0, done.stderr
    assert os.stat(path).st_mode & 0o777 == 0o600
    keys = load_keys(path)
    assert [key.name for key in keys] == ["station-1", "station-2"]
    assert keys[0].key_id.hex() in done.stdout and keys[0].secret.hex() not in done.stdout
    again = _tdtp("keygen", str(path))
    assert again.returncode == 2 and again.stderr.count("\n") == 1 and "exists" in again.stderr
    assert load_keys(path) == keys


def test_demo_runs_a_keyed_session(tmp_path: Path) -> None:
    path = tmp_path / "k"
    assert main(["keygen", str(path)]) == 0
    for extra in (("--keyed",), ("--key-file", str(path))):
        done = _tdtp("demo", "--duration", "0.5", "--json", *extra)
        assert done.returncode == 0, done.stderr
        summary = json.loads(done.stdout)
        assert summary["keyed"] is True and summary["encrypted"] is True
        direction = summary["master_to_slave"]
        assert direction["packets_received"] == direction["packets_sent"] > 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (("--key-file", "/nonexistent/keys"), "cannot read key file"),
        (("--key-name", "x"), "--key-name needs --key-file"),
        (("--keyed", "--key-file", "/tmp/x"), "--keyed or --key-file"),
    ],
)
def test_key_misuse_is_one_line_and_exit_2(
    extra: tuple[str, ...], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["demo", "--duration", "0.1", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_a_world_readable_key_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "k"
    assert main(["keygen", str(path)]) == 0
    path.chmod(0o644)
    done = _tdtp("demo", "--duration", "0.1", "--key-file", str(path))
    assert done.returncode == 2 and "chmod 600" in done.stderr


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
    return port


def test_an_unkeyed_slave_on_a_public_address_warns_once(tmp_path: Path) -> None:
    done = _tdtp("slave", "--host", "0.0.0.0", "--port", str(_free_port()), "--duration", "0.3")
    assert done.returncode == 0, done.stderr
    assert done.stderr.count("anyone who can reach the port can command it") == 1
    quiet = _tdtp("slave", "--host", "127.0.0.1", "--port", str(_free_port()), "--duration", "0.3")
    assert "anyone who can reach" not in quiet.stderr
    path = tmp_path / "k"
    assert main(["keygen", str(path)]) == 0
    keyed = _tdtp(
        "slave", "--host", "0.0.0.0", "--port", str(_free_port()), "--duration", "0.3",
        "--key-file", str(path),
    )  # fmt: skip
    assert "anyone who can reach" not in keyed.stderr
