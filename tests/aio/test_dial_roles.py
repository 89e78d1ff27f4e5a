"""Either side may dial (docs/PROTOCOL.md 5.1, issue 34): a slave (robot) dials its master (operator),
over real loopback sockets. Admission, keys, exclusive control and reconnection work as when the
master dials; a dialer of the listener's own role is refused (ROLE_CONFLICT); an ICMP refusal says
what it may mean behind a NAT."""

from __future__ import annotations

import asyncio
import socket

import pytest

from tdtp import (
    CloseCause,
    ConnectError,
    ConnectionConfig,
    PortUnreachableError,
    ReconnectPolicy,
    Role,
    Server,
    connect,
    listen,
)
from tdtp.errors import ArgumentTypeError
from tdtp.protection import PresharedKey

from eventually import eventually

KEY = PresharedKey(bytes(range(32)), name="robot-7")
OTHER = PresharedKey(bytes(range(1, 33)), name="robot-8")
FAST = ConnectionConfig(silence_timeout=0.05, open_timeout=2.0)


@pytest.mark.asyncio
async def test_a_slave_dials_its_master_and_samples_flow_both_ways() -> None:
    async with (
        listen(role=Role.MASTER, keys=[KEY]) as operator,
        connect("127.0.0.1", operator.port, role=Role.SLAVE, key=KEY) as robot,
    ):
        station = await operator.accept()
        assert robot.connection.role is Role.SLAVE and robot.connection.dials
        assert station.connection.role is Role.MASTER and not station.connection.dials
        assert station.connection.key is not None and station.connection.key.name == "robot-7"
        station.send(b"move to 0.1")  # the master commands
        command = await robot.recv()
        robot.send(b"force 2 N")  # the slave answers
        feedback = await station.recv()
        assert (command.payload, feedback.payload) == (b"move to 0.1", b"force 2 N")
        # The listening master validated the robot's address first, as a listening slave does.
        assert operator.stats.admission.cookies_sent >= 1
        assert operator.stats.admission.admitted == 1


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("listener", "dialer"), [(Role.SLAVE, Role.SLAVE), (Role.MASTER, Role.MASTER)]
)
async def test_a_dialer_of_the_listeners_own_role_is_refused(listener: Role, dialer: Role) -> None:
    async with listen(role=listener) as server:
        with pytest.raises(ConnectError, match="same role"):
            await connect("127.0.0.1", server.port, role=dialer)
        assert server.stats.admission.rejects_sent == 1
        assert server.endpoints == []


@pytest.mark.asyncio
async def test_a_listening_master_holds_keys_and_exclusive_control_as_a_slave_does() -> None:
    async with listen(role=Role.MASTER, keys=[KEY], exclusive=True) as operator:
        with pytest.raises(ConnectError, match="does not hold this key"):
            await connect("127.0.0.1", operator.port, role=Role.SLAVE, key=OTHER)
        async with connect("127.0.0.1", operator.port, role=Role.SLAVE, key=KEY):
            await operator.accept()
            with pytest.raises(ConnectError, match="exclusive"):
                await connect("127.0.0.1", operator.port, role=Role.SLAVE, key=KEY)
            assert operator.stats.peers_in_use == 1


@pytest.mark.asyncio
async def test_a_dialing_slave_reconnects_when_its_master_restarts() -> None:
    """The operator's station dies (no CLOSE) and comes back on its port: the robot's next datagram
    draws a RESET and it dials again, keeping its endpoint, as a reconnecting master does."""
    operator = await listen(role=Role.MASTER, config=FAST)
    port = operator.port
    robot = await connect(
        "127.0.0.1", port, role=Role.SLAVE, config=FAST, reconnect=ReconnectPolicy()
    )
    try:
        first = await operator.accept()
        first.send(b"a")
        await robot.recv()
        await _kill(operator)
        operator = await listen(port=port, role=Role.MASTER, config=FAST)
        accepting = asyncio.ensure_future(operator.accept())
        for _ in range(1000):  # patience for a loaded machine, not a timing goal
            if accepting.done():
                break
            robot.send(b"f" * 40)  # big enough to draw a RESET
            await asyncio.sleep(0.01)
        second = await asyncio.wait_for(accepting, 10.0)
        await eventually(lambda: robot.connection.state.value == "established")
        second.send(b"b")
        sample = await asyncio.wait_for(robot.recv(), 5.0)
        assert sample.payload == b"b"
        assert robot.reconnects.count == 1 and not robot.is_closed
        assert robot.reconnects.causes == {"peer_restarted": 1}
    finally:
        await robot.close()
        await operator.close()


async def _kill(server: Server) -> None:
    """The process dies: its sessions end without a CLOSE and the port is free."""
    for endpoint in server.endpoints:
        endpoint._release()
    await server.close()


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


@pytest.mark.asyncio
@pytest.mark.parametrize("role", [Role.MASTER, Role.SLAVE])
async def test_an_icmp_refusal_says_what_it_means_behind_a_nat(role: Role) -> None:
    peer = "slave" if role is Role.MASTER else "master"
    with pytest.raises(PortUnreachableError) as refused:
        await connect("127.0.0.1", _free_port(), role=role)
    text = str(refused.value)
    assert f"no {peer} runs there" in text
    assert "NAT" in text and "docs/NAT.md" in text


@pytest.mark.asyncio
async def test_a_role_that_is_not_a_role_is_refused_at_the_call() -> None:
    with pytest.raises(ArgumentTypeError, match=r"Role\.MASTER"):
        connect("127.0.0.1", 9, role="slave")  # type: ignore[arg-type]
    with pytest.raises(ArgumentTypeError, match=r"Role\.SLAVE"):
        listen(role="master")  # type: ignore[arg-type]


@pytest.mark.asyncio
async def test_the_listening_master_sees_the_slave_close() -> None:
    async with listen(role=Role.MASTER, config=FAST) as operator:
        robot = await connect("127.0.0.1", operator.port, role=Role.SLAVE, config=FAST)
        station = await operator.accept()
        await robot.close()
        closed = await station.wait_closed()
        assert closed.cause is CloseCause.PEER_CLOSE
        await eventually(lambda: operator.endpoints == [])
