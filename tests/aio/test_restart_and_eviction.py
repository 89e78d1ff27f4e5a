"""Over real loopback sockets: a slave that restarts on the same port is known to its master at once
(RESET, PROTOCOL.md 5.7), and a full server gives the slot of its longest-silent session to a new
master instead of refusing it (SECURITY.md)."""

from __future__ import annotations

import asyncio

import pytest

from tdtp import CloseCause, ConnectionConfig, PresharedKey
from tdtp.aio.api import ConnectError, connect, listen

KEY = PresharedKey(bytes(range(32)))


async def _until(check: object, patience: float = 10.0) -> None:
    """Poll ``check()`` until it is true: patience for a loaded machine, not a timing goal."""
    for _ in range(int(patience / 0.01)):
        if check():  # type: ignore[operator]
            return
        await asyncio.sleep(0.01)
    raise AssertionError("condition never became true")


@pytest.mark.asyncio
@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
async def test_a_slave_restarted_on_the_same_port_ends_the_masters_session(keyed: bool) -> None:
    key = KEY if keyed else None
    server = await listen("127.0.0.1", 0, key=key)
    port = server.port
    master = await connect("127.0.0.1", port, key=key)
    slave = await server.accept()
    master.send(b"x" * 40)
    await asyncio.wait_for(slave.recv(), 5.0)
    # The slave process dies (no CLOSE) and a new one binds the same port.
    for endpoint in server.endpoints:
        endpoint._release()
    server._closed = True
    assert server._transport is not None
    server._transport.close()
    await asyncio.sleep(0.05)
    restarted = await listen("127.0.0.1", port, key=key)
    try:
        for _ in range(50):
            if master.is_closed:
                break
            master.send(b"y" * 40)
            await asyncio.sleep(0.01)
        closed = await asyncio.wait_for(master.wait_closed(), 5.0)
        assert closed.cause is CloseCause.PEER_RESTARTED
        admission = restarted.stats.admission
        assert admission.resets_sent >= 1
        assert admission.reset_bytes_out <= admission.reset_bytes_in
        assert restarted.endpoints == []
    finally:
        await master.close()
        await restarted.close()


@pytest.mark.asyncio
async def test_a_full_server_evicts_its_longest_silent_session_for_a_new_master() -> None:
    config = ConnectionConfig(silence_timeout=0.05, idle_timeout=30.0)
    async with await listen("127.0.0.1", 0, config=config, max_peers=3) as server:
        masters = [await connect("127.0.0.1", server.port, config=config) for _ in range(3)]
        slaves = [await server.accept() for _ in range(3)]
        live = masters[2]
        for dead in masters[:2]:  # two masters go silent without a CLOSE
            dead._release()
            dead._transport.close()
        await _until(lambda: sum(s.connection.peer_silent for s in slaves) == 2)
        newcomer = await connect("127.0.0.1", server.port, config=config)
        await server.accept()
        evicted = [s for s in slaves if s.is_closed]
        assert len(evicted) == 1
        event = evicted[0].close_event
        assert event is not None and event.cause is CloseCause.EVICTED
        assert not slaves[2].is_closed  # the live one keeps its slot
        assert server.stats.peers_evicted == 1 and server.stats.peers_refused == 0
        # The other silent session goes for the next master; then only live ones are left: BUSY.
        second = await connect("127.0.0.1", server.port, config=config)
        await server.accept()
        assert server.stats.peers_evicted == 2
        with pytest.raises(ConnectError, match=r"busy|BUSY|serves as many"):
            await connect("127.0.0.1", server.port, config=config)
        assert server.stats.peers_refused == 1
        for master in (live, newcomer, second):
            await master.close()


async def _kill(server: object) -> None:
    """The slave process dies: no CLOSE to anyone, the port is freed."""
    for endpoint in server.endpoints:  # type: ignore[attr-defined]
        endpoint._release()
    server._closed = True  # type: ignore[attr-defined]
    server._transport.close()  # type: ignore[attr-defined]
    await asyncio.sleep(0.02)


@pytest.mark.asyncio
@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
async def test_a_reconnecting_master_keeps_its_endpoint_across_a_slave_restart(
    keyed: bool,
) -> None:
    """The application's loop, ep.send and ep.latest go on; ep.reconnects says what happened."""
    key = KEY if keyed else None
    server = await listen("127.0.0.1", 0, key=key)
    port = server.port
    master = await connect("127.0.0.1", port, key=key, reconnect=True)
    slave = await server.accept()
    slave.send(b"before")
    first = await asyncio.wait_for(master.recv(), 5.0)
    assert first.payload == b"before"
    await _kill(server)
    for _ in range(20):  # samples into the void: superseded or lost, never an exception
        master.send(b"x" * 40)
        await asyncio.sleep(0.005)
    restarted = await listen("127.0.0.1", port, key=key)
    try:
        accepting = asyncio.ensure_future(restarted.accept())
        for _ in range(1000):  # patience for a loaded machine, not a timing goal
            if accepting.done():
                break
            master.send(b"y" * 40)
            await asyncio.sleep(0.01)
        new_slave = await asyncio.wait_for(accepting, 10.0)
        await _until(lambda: master.connection.state.value == "established")
        new_slave.send(b"after")
        sample = await asyncio.wait_for(master.recv(), 5.0)
        assert sample.payload == b"after"
        assert master.latest() is not None and not master.is_closed
        record = master.reconnects
        assert record.count == 1 and not record.reopening
        assert record.causes == {"peer_restarted": 1}
        assert record.samples_received_before == 1
        assert restarted.stats.admission.resets_sent >= 1
    finally:
        await master.close()
        await restarted.close()
    closed = master.close_event
    assert closed is not None and closed.cause is CloseCause.LOCAL_CLOSE


@pytest.mark.asyncio
async def test_after_silence_reopens_when_no_reset_can_come_back() -> None:
    """A RESET no larger than a keyed KEEPALIVE (40 bytes since version 3) has room for one tag, and
    the restarted slave's ring puts another key first: the master cannot verify the RESETs it draws
    (PROTOCOL.md 5.7, "when no RESET can come back") and reopens after ``after_silence`` of silence
    instead, probing with OPENs until the slave is back."""
    from tdtp import ReconnectPolicy

    policy = ReconnectPolicy(after_silence=0.3)
    server = await listen("127.0.0.1", 0, key=KEY)
    port = server.port
    master = await connect("127.0.0.1", port, key=KEY, reconnect=policy)
    await server.accept()
    await _kill(server)
    await asyncio.sleep(0.2)  # keep-alives only
    other = PresharedKey(bytes(range(1, 33)), name="another-station")
    restarted = await listen("127.0.0.1", port, keys=[other, KEY])
    try:
        await asyncio.wait_for(restarted.accept(), 10.0)
        await _until(lambda: master.reconnects.count == 1)
        assert master.reconnects.causes == {"silence": 1}
    finally:
        await master.close()
        await restarted.close()


def test_reconnect_policies_are_checked() -> None:
    from tdtp import InvalidArgumentError, ReconnectPolicy
    from tdtp.errors import ArgumentTypeError

    with pytest.raises(InvalidArgumentError, match="attempts"):
        ReconnectPolicy(attempts=-1)
    with pytest.raises(InvalidArgumentError, match="after_silence"):
        ReconnectPolicy(after_silence=0)
    with pytest.raises(ArgumentTypeError, match="reconnect"):
        connect("127.0.0.1", 9, reconnect="yes")  # type: ignore[arg-type]
