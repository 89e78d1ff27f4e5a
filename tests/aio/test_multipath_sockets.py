"""Multipath sessions on real loopback sockets (PROTOCOL.md 5.11): a master with two local sockets,
the slave's server learning the second path, paths added and removed, keyed and not. The tests check
what the run recorded, never a wall-clock rate."""

from __future__ import annotations

import asyncio

import pytest

from tdtp import (
    ConnectionConfig,
    Endpoint,
    InvalidArgumentError,
    MultipathConfig,
    PathChanged,
    PortUnreachableError,
    Ticker,
    connect,
    listen,
)
from tdtp.protection import PresharedKey

from eventually import eventually

KEY = PresharedKey(bytes(range(32)), name="operator")
TWO = ["127.0.0.1", "127.0.0.1"]


async def _stream(ep: Endpoint, stop: asyncio.Event) -> None:
    async for _ in Ticker(1000.0):
        if stop.is_set() or ep.is_closed:
            return
        ep.send(b"sample" + bytes(94))


def _active(ep: Endpoint) -> set[int]:
    return {path.path_id for path in ep.paths if path.state == "active"}


@pytest.mark.asyncio
@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed"])
async def test_two_local_sockets_one_session_first_copy_wins(keyed: bool) -> None:
    async with (
        listen(keys=[KEY] if keyed else None) as server,
        connect(
            "127.0.0.1", server.port, local_addresses=TWO, key=KEY if keyed else None
        ) as master,
    ):
        slave = await server.accept()
        await eventually(lambda: _active(master) == {0, 1} and _active(slave) == {0, 1})
        assert server.stats.paths_learned == 1
        assert len(server.endpoints) == 1  # one session, two addresses
        stop = asyncio.Event()
        streams = [
            asyncio.create_task(_stream(master, stop)),
            asyncio.create_task(_stream(slave, stop)),
        ]
        await eventually(
            lambda: slave.stats.samples_delivered >= 300 and master.stats.samples_delivered >= 300
        )
        stop.set()
        await asyncio.gather(*streams)
        await asyncio.sleep(0.05)  # the last copies land
        for sender, receiver in ((master, slave), (slave, master)):
            paths = {path.path_id: path for path in sender.paths}
            received = {path.path_id: path for path in receiver.paths}
            drops = receiver.stats.drops
            # Every copy that arrived after its sample's first is a duplicate, none a replay.
            assert drops.get("duplicate", 0) > 0
            assert "replayed" not in drops and "unauthenticated" not in drops
            copies = sum(p.received for p in received.values())
            firsts = sum(p.first_received for p in received.values())
            assert copies == firsts + drops["duplicate"] + drops.get("stale", 0)
            # (a first copy may still come too late for in-order delivery: dropped as late)
            assert receiver.stats.received.data_packets + drops.get("late", 0) == firsts
            # Both paths carried copies (either may have held a few back: each has a controller
            # of its own, and a loaded machine's late turns read as queueing to it).
            assert paths[0].sent > 0 and paths[1].sent > 0
        for ep in (master, slave):
            stats = ep.stats
            assert stats.datagrams_in == stats.received.datagrams + stats.dropped
        # (No PeerSilent is fake time's to prove, tests/test_multipath.py: here a loaded machine's
        # event-loop stall of a silence_timeout would raise one, and that is not the protocol's.)


@pytest.mark.asyncio
async def test_a_path_added_and_removed_during_the_session() -> None:
    async with (
        listen() as server,
        connect("127.0.0.1", server.port, local_addresses=["127.0.0.1"]) as master,
    ):
        slave = await server.accept()
        events: list[PathChanged] = []
        slave.paths.set_callback(events.append)
        assert _active(master) == {0}
        socket_number = await master.paths.add("127.0.0.1")
        await eventually(lambda: _active(master) == {0, 1} and _active(slave) == {0, 1})
        stop = asyncio.Event()
        stream = asyncio.create_task(_stream(master, stop))
        await eventually(lambda: slave.paths[1].received >= 50)
        master.paths.remove(socket_number)
        await eventually(lambda: _active(slave) == {0})
        assert [(e.path_id, e.state) for e in events] == [(1, "active"), (1, "closed")]
        delivered = slave.stats.samples_delivered
        await eventually(lambda: slave.stats.samples_delivered >= delivered + 100)
        stop.set()
        await stream
        with pytest.raises(InvalidArgumentError, match="no path socket"):
            master.paths.remove(socket_number)


@pytest.mark.asyncio
async def test_a_dead_path_costs_the_session_nothing() -> None:
    """One path loses everything from the start: it is never validated, the session runs on the
    other, and the slave's server never learns its address."""
    async with (
        listen() as server,
        connect(
            "127.0.0.1", server.port, local_addresses=TWO, path_netem=[None, "loss 100%"]
        ) as master,
    ):
        slave = await server.accept()
        stop = asyncio.Event()
        stream = asyncio.create_task(_stream(master, stop))
        await eventually(lambda: slave.stats.samples_delivered >= 300)
        stop.set()
        await stream
        assert {p.path_id: p.state for p in master.paths} == {0: "active", 1: "probing"}
        assert server.stats.paths_learned == 0
        assert master.stats.packets_lost == 0


@pytest.mark.asyncio
async def test_multipath_misuse_is_refused_at_once() -> None:
    with pytest.raises(InvalidArgumentError, match="local_addresses must be a non-empty list"):
        connect("127.0.0.1", 9, local_addresses="127.0.0.1")
    with pytest.raises(InvalidArgumentError, match="netem"):
        connect("127.0.0.1", 9, local_addresses=TWO, netem="loss 1%")
    with pytest.raises(InvalidArgumentError, match="path_netem has 3 entries for 2 paths"):
        connect("127.0.0.1", 9, local_addresses=TWO, path_netem=[None, None, None])
    with pytest.raises(InvalidArgumentError, match="HOST or HOST:PORT"):
        connect("127.0.0.1", 9, local_addresses=["127.0.0.1:http"])
    async with listen() as server, connect("127.0.0.1", server.port) as master:  # one path
        await server.accept()
        assert len(master.paths) == 0
        with pytest.raises(InvalidArgumentError, match="multipath session"):
            await master.paths.add("127.0.0.1")


@pytest.mark.asyncio
async def test_a_slave_with_max_paths_one_refuses_the_second_path() -> None:
    config = ConnectionConfig(multipath=MultipathConfig(max_paths=1))
    async with (
        listen(config=config) as server,
        connect("127.0.0.1", server.port, local_addresses=TWO) as master,
    ):
        slave = await server.accept()
        await eventually(lambda: master.connection.multipath is not None and len(master.paths) == 1)
        assert [p.path_id for p in slave.paths] == [0]
        assert slave.stats.drops.get("path_limit", 0) >= 1
        assert [(e.path_id, e.state) for e in master.paths.events] == []


@pytest.mark.asyncio
async def test_nothing_listening_is_port_unreachable_at_once() -> None:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(PortUnreachableError, match="nothing listens"):
        await asyncio.wait_for(connect("127.0.0.1", port, local_addresses=TWO), 3.0)
