"""The ``tdtp`` command: the demo's JSON contract, and the argument checks."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from tdtp.cli import _host_port, build_parser


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
    assert _host_port("127.0.0.1:7000") == ("127.0.0.1", 7000)
    assert _host_port("[::1]:7000") == ("::1", 7000)
    assert _host_port("fe80::1:7000") == ("fe80::1", 7000)
