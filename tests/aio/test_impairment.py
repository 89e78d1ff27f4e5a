"""Emulated impairment on real loopback sockets: endpoints, the relay, and the CLI's --netem."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from typing import cast

import pytest

from tdtp.aio.api import connect, listen
from tdtp.aio.relay import start_relay
from tdtp.aio.ticker import Ticker
from tdtp.aio.timer import monotonic
from tdtp.cli.options import build_parser


class _Echo(asyncio.DatagramProtocol):
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.DatagramTransport, transport)

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.transport.sendto(data, addr)


class _Client(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.replies: list[tuple[float, bytes]] = []

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.replies.append((monotonic(), data))


async def _relay_round_trips(spec: str, count: int) -> tuple[list[float], object]:
    loop = asyncio.get_running_loop()
    echo, _ = await loop.create_datagram_endpoint(_Echo, local_addr=("127.0.0.1", 0))
    target = echo.get_extra_info("sockname")
    relay = await start_relay(("127.0.0.1", 0), target, spec, seed=3)
    client, protocol = await loop.create_datagram_endpoint(
        _Client, remote_addr=(relay.address[0], relay.address[1])
    )
    sent: dict[bytes, float] = {}
    for i in range(count):
        payload = b"%04d" % i
        sent[payload] = monotonic()
        client.sendto(payload)
        await asyncio.sleep(0.001)
    await asyncio.sleep(0.3)
    rtts = [at - sent[data] for at, data in protocol.replies]
    stats = relay.forward.link.stats
    client.close()
    await relay.close()
    echo.close()
    return rtts, stats


@pytest.mark.asyncio
async def test_relay_delays_both_ways_and_never_early() -> None:
    rtts, _ = await _relay_round_trips("delay 10ms", 30)
    assert len(rtts) == 30
    assert min(rtts) >= 0.020  # 10 ms each way: an emulated delay is never shortened


@pytest.mark.asyncio
async def test_relay_loss_is_counted() -> None:
    rtts, stats = await _relay_round_trips("loss 100%", 20)
    assert rtts == []
    assert stats.lost == 20


@pytest.mark.asyncio
async def test_impaired_master_sees_the_emulated_rtt() -> None:
    async with (
        await listen("127.0.0.1", 0, netem="delay 5ms") as server,
        await connect("127.0.0.1", server.port, netem="delay 10ms") as master,
    ):
        slave = await server.accept()
        count = 0
        async for _ in Ticker(1000.0):
            master.send(b"m" * 50)
            slave.send(b"s" * 50)
            count += 1
            if count == 200:
                break
        await asyncio.sleep(0.1)
        assert master.stats.srtt >= 0.015  # 10 ms out, 5 ms back: never less
        assert slave.stats.srtt >= 0.015
        assert master.stats.packets_lost == 0


def test_cli_rejects_bad_netem_naming_the_token(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        build_parser().parse_args(["demo", "--netem", "delay 20xs"])
    assert "20xs" in capsys.readouterr().err


def test_demo_reports_the_emulated_loss_and_delay() -> None:
    """tdtp demo --netem "delay 20ms loss 5%": loss near 5 % each way, srtt near 40 ms."""
    done = subprocess.run(
        [
            sys.executable, "-m", "tdtp", "demo", "--duration", "3", "--json",
            "--controller", "fixed", "--netem", "delay 20ms loss 5%", "--netem-seed", "11",
        ],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    for key in ("master_to_slave", "slave_to_master"):
        direction = summary[key]
        sent = direction["packets_sent"]
        # How many samples a busy machine manages to send varies; the loss is judged against what
        # this run sent. Binomial: 5 % of n has a standard deviation of sqrt(0.05 * 0.95 / n).
        assert sent >= 100
        sigma = (0.05 * 0.95 / sent) ** 0.5
        assert abs(direction["loss_ratio"] - 0.05) <= 4 * sigma
        # The smallest RTT sample is the emulated 2 x 20 ms plus loopback: it is never shorter,
        # and on a busy machine at least one of thousands of samples sees an idle scheduler.
        assert 40.0 <= direction["min_rtt_ms"] <= 45.0
        assert direction["srtt_ms"] >= 40.0
        # A sample's age is half a round trip that crossed both emulated delays: never under
        # 20 ms (less the histogram's 1 %), whatever the machine's speed.
        age = direction["sample_age_ms"]
        assert 19.7 <= age["p50"] <= age["p99"]
        assert direction["samples_timed"] > 0
