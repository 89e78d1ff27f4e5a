"""The reliable control channel on real loopback sockets, through the in-process emulator.

These tests check what the run itself recorded (every message sent was delivered once, in order;
the counters agree at both ends after draining), never a count or a rate expected from the clock.
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys

import pytest

from tdtp import (
    ConnectionConfig,
    ControlExpired,
    ControlQueueFullError,
    ControlReceived,
    EndpointClosedError,
)
from tdtp.aio.api import connect, listen
from tdtp.aio.endpoint import Endpoint
from tdtp.aio.ticker import Ticker
from tdtp.cli.main import main

NETEM = "delay 20ms 5ms loss 5%"


async def _drain(*endpoints: Endpoint, patience: float = 10.0) -> None:
    """Until every control message sent has been acknowledged (so delivered), or the patience ends."""
    async with asyncio.timeout(patience):
        while any(ep.connection.control_unacked for ep in endpoints):
            await asyncio.sleep(0.01)


@pytest.mark.asyncio
async def test_messages_cross_an_impaired_path_once_and_in_order() -> None:
    async with (
        await listen("127.0.0.1", 0, netem=NETEM, netem_seed=11) as server,
        await connect("127.0.0.1", server.port, netem=NETEM, netem_seed=12) as master,
    ):
        slave = await server.accept()
        got_at_master: list[ControlReceived] = []
        master.set_control_callback(
            lambda event: (
                got_at_master.append(event) if isinstance(event, ControlReceived) else None
            )
        )
        at_slave: list[ControlReceived] = []

        async def read_at_slave() -> None:
            async for message in slave.control_messages():
                at_slave.append(message)

        reader = asyncio.create_task(read_at_slave())
        sent = 0
        samples = 0
        async for tick in Ticker(500):
            if tick >= 1000:  # 2 s of samples, a control message both ways every 10th tick
                break
            master.send(b"m" * 40)
            slave.send(b"s" * 40)
            samples += 1
            if tick % 10 == 0:
                message = sent.to_bytes(4, "big")
                master.send_control(message)
                slave.send_control(message)
                sent += 1
        await _drain(master, slave)
        async with asyncio.timeout(5.0):  # the reader takes the last messages
            while len(at_slave) < slave.stats.control_delivered:
                await asyncio.sleep(0.001)
        reader.cancel()
        # The slave read its messages as they came (control_messages), the master by callback.
        for received, sender, receiver in (
            (at_slave, master, slave),
            (got_at_master, slave, master),
        ):
            assert [int.from_bytes(m.payload, "big") for m in received] == list(range(sent))
            assert [m.index for m in received] == list(range(sent))
            assert sender.stats.control_sent == sender.stats.control_acked == sent
            assert receiver.stats.control_delivered == sent
            # Every datagram that carried a MESSAGE is accounted for: first copies and retransmissions.
            assert sender.stats.control_transmissions == sent + sender.stats.control_retransmits
        # Samples kept flowing meanwhile (what the run itself recorded: sent = received + lost).
        assert slave.stats.samples_delivered > 0 and master.stats.samples_delivered > 0


@pytest.mark.asyncio
async def test_control_messages_iterate_until_the_session_ends() -> None:
    async with await listen("127.0.0.1", 0) as server:
        master = await connect("127.0.0.1", server.port)
        slave = await server.accept()
        for k in range(5):
            master.send_control(bytes([k]))
        await _drain(master)
        await master.close()
        received = [message.payload async for message in slave.control_messages()]
        assert received == [bytes([k]) for k in range(5)]
        with pytest.raises(EndpointClosedError):
            master.send_control(b"late")


@pytest.mark.asyncio
async def test_a_full_window_raises_and_a_peer_that_never_acknowledges_is_given_up() -> None:
    """The slave's application never reads (the driver reports a full backlog), so the slave never
    acknowledges: the master's window fills, send_control raises, and after control_timeout the
    messages are given up with one event; samples flowed all along."""
    config = ConnectionConfig(control_window=4, control_timeout=0.5)
    async with (
        await listen("127.0.0.1", 0, config=config) as server,
        await connect("127.0.0.1", server.port, config=config) as master,
    ):
        slave = await server.accept()
        slave.connection.control_held(1000)
        events: list[ControlReceived | ControlExpired] = []
        master.set_control_callback(events.append)
        for k in range(4):
            master.send_control(bytes([k]))
        with pytest.raises(ControlQueueFullError):
            master.send_control(b"five")
        async with asyncio.timeout(10.0):
            while master.control_expired is None:
                master.send(b"sample")
                await asyncio.sleep(0.01)
        (expired,) = [event for event in events if isinstance(event, ControlExpired)]
        assert expired.payloads == tuple(bytes([k]) for k in range(4))
        assert master.stats.control_given_up == 4 and master.connection.control_unacked == 0
        assert slave.stats.control_delivered == 0
        assert slave.stats.control_dropped.get("control_backlog", 0) >= 4
        assert slave.stats.samples_delivered > 0


def test_the_demo_checks_its_control_counters() -> None:
    """`tdtp demo --control-rate` over the issue's path: every counter value arrives, in order,
    each way (what the run recorded, not a rate)."""
    result = subprocess.run(
        [sys.executable, "-m", "tdtp", "demo", "--duration", "2", "--rate", "200",
         "--netem", NETEM, "--netem-seed", "5", "--control-rate", "20", "--json"],
        check=False, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    for direction in ("master_to_slave", "slave_to_master"):
        control = summary[direction]["control_messages"]
        assert control["out_of_order"] == 0
        assert control["sent"] == control["delivered"] > 0
        assert control["given_up"] == 0


@pytest.mark.parametrize("command", ["demo", "slave", "master"])
@pytest.mark.parametrize("value", ["-5", "0", "5000", "nan", "inf", "fast"])
def test_a_bad_control_rate_is_one_line_and_status_2(
    command: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    extra = {"demo": [], "slave": ["--port", "0"], "master": ["127.0.0.1:9"]}[command]
    with pytest.raises(SystemExit) as exited:
        main([command, *extra, f"--control-rate={value}"])
    assert exited.value.code == 2
    err = capsys.readouterr().err
    assert "--control-rate" in err
    assert len(err.strip().splitlines()) == 1
