"""Over real loopback sockets: a slave that restarts on the same port is known to its master at once
(RESET, PROTOCOL.md 5.7; or its CLOSE RESTARTING, 5.2), and a full server gives a slot only to replace
a master that is gone, telling it why (5.1, rule 2.7; SECURITY.md)."""

from __future__ import annotations

import asyncio

import pytest

from tdtp import (
    AdmissionConfig,
    CloseCause,
    ConnectionConfig,
    PeerResumed,
    PeerSilent,
    PresharedKey,
    ReconnectingError,
    ReconnectPolicy,
    monotonic,
)
from tdtp.aio.api import ConnectError, connect, listen
from tdtp.wire.control import CloseReason

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
async def test_a_full_server_gives_a_slot_only_to_replace_a_master_that_is_gone() -> None:
    """PROTOCOL.md 5.1, rule 2.7: a session whose master is silent past the watchdog but not for
    ``reclaim_after`` keeps its slot (BUSY for the newcomer); once its master is gone, the slot
    goes to the next validated master, the longest gone first."""
    config = ConnectionConfig(
        silence_timeout=0.05, idle_timeout=30.0, admission=AdmissionConfig(reclaim_after=0.5)
    )
    async with await listen("127.0.0.1", 0, config=config, max_peers=3) as server:
        masters = [await connect("127.0.0.1", server.port, config=config) for _ in range(3)]
        slaves = [await server.accept() for _ in range(3)]
        live = masters[2]
        for dead in masters[:2]:  # two masters go silent without a CLOSE
            dead._release()
            dead._transport.close()
        await _until(lambda: sum(s.connection.peer_silent for s in slaves) == 2)
        # Silent past the watchdog, not gone: a hiccup keeps its slot.
        with pytest.raises(ConnectError, match=r"busy|BUSY|serves as many"):
            await connect("127.0.0.1", server.port, config=config)
        assert server.stats.peers_evicted == 0 and server.stats.slots.refused_busy == 1
        await _until(lambda: all(s.connection.quiet_for(monotonic()) > 0.55 for s in slaves[:2]))
        newcomer = await connect("127.0.0.1", server.port, config=config)
        await server.accept()
        evicted = [s for s in slaves if s.is_closed]
        assert len(evicted) == 1
        event = evicted[0].close_event
        assert event is not None and event.cause is CloseCause.EVICTED
        assert event.reason == CloseReason.EVICTED and "reclaims a slot" in event.detail
        assert not slaves[2].is_closed  # the live one keeps its slot
        assert server.stats.peers_evicted == 1
        # The other gone session goes for the next master; then only live ones are left: BUSY.
        second = await connect("127.0.0.1", server.port, config=config)
        await server.accept()
        assert server.stats.peers_evicted == 2
        with pytest.raises(ConnectError, match=r"busy|BUSY|serves as many"):
            await connect("127.0.0.1", server.port, config=config)
        assert server.stats.peers_refused == 2
        for master in (live, newcomer, second):
            await master.close()


@pytest.mark.asyncio
async def test_an_evicted_master_hears_why_and_reconnects_with_back_off() -> None:
    """Keyed, max_peers 1: the master's datagrams stop reaching the slave (its link drops them,
    its socket still reads); the same master (same key) opens again from another port and takes
    the slot back. The first hears CLOSE EVICTED, reopens after busy_backoff, is refused BUSY
    (the slot is held by a live master) with a growing back-off, and gives up after `attempts`."""
    policy = ReconnectPolicy(busy_backoff=0.05, max_backoff=0.2, attempts=2, after_silence=None)
    async with await listen("127.0.0.1", 0, key=KEY, max_peers=1) as server:
        first = await connect(
            "127.0.0.1", server.port, key=KEY, netem="delay 0ms", reconnect=policy
        )
        await server.accept()
        first._transport.change("loss 100%")  # type: ignore[attr-defined]
        session = server.endpoints[0]
        await _until(lambda: session.connection.quiet_for(monotonic()) > 0.15)
        second = await connect("127.0.0.1", server.port, key=KEY)
        await server.accept()
        first._transport.change("delay 0ms")  # type: ignore[attr-defined]
        closed = await asyncio.wait_for(first.wait_closed(), 10.0)
        record = first.reconnects
        assert record.causes == {"evicted": 1} and record.lost is not None
        assert record.lost[0] == "evicted" and "reopen later" in record.lost[1]
        assert record.failed_attempts == 3 and record.count == 0
        assert closed.cause is CloseCause.REJECTED and closed.reason == CloseReason.BUSY
        assert server.stats.slots.reclaimed_same_master == 1
        from tdtp.cli.master import master_failure

        line = master_failure(first)
        assert line is not None and line.startswith("session lost (evicted)")
        assert "reconnecting gave up (rejected)" in line
        await second.close()
        await first.close()


@pytest.mark.asyncio
async def test_a_restarting_slave_brings_its_masters_back_and_the_gap_reads_as_silence() -> None:
    """server.close(restarting=True) (what `tdtp slave` does on Ctrl-C or SIGTERM): the master
    reopens as soon as the slave listens again; meanwhile it reads as silent, its watchdog hears
    PeerSilent then PeerResumed, and a control message is refused (ReconnectingError), not
    queued."""
    seen: list[object] = []
    server = await listen("127.0.0.1", 0)
    port = server.port
    master = await connect("127.0.0.1", port, reconnect=True, on_watchdog=seen.append)
    await server.accept()
    await server.close(restarting=True)
    await _until(lambda: master.reconnects.reopening)
    assert master.peer_silent and isinstance(seen[-1], PeerSilent)
    with pytest.raises(ReconnectingError, match="peer_restarting"):
        master.send_control(b"E-STOP")
    master.send(b"x" * 40)  # a sample is superseded, never an exception
    restarted = await listen("127.0.0.1", port)
    try:
        await asyncio.wait_for(restarted.accept(), 10.0)
        await _until(lambda: master.reconnects.count == 1)
        assert master.reconnects.causes == {"peer_restarting": 1}
        assert not master.peer_silent and isinstance(seen[-1], PeerResumed)
        master.send_control(b"E-STOP")  # a session again: taken
    finally:
        await master.close()
        await restarted.close()
    assert master.peer_silent and master.stats.closed  # closed reads as closed


@pytest.mark.asyncio
async def test_a_normal_close_ends_a_reconnecting_master_unless_its_policy_says_otherwise() -> None:
    for reopen_on, reopens in ((None, False), ({CloseCause.PEER_CLOSE}, True)):
        policy = ReconnectPolicy() if reopen_on is None else ReconnectPolicy(reopen_on=reopen_on)
        server = await listen("127.0.0.1", 0)
        master = await connect("127.0.0.1", server.port, reconnect=policy)
        await server.accept()
        await server.close()
        if reopens:
            await _until(lambda master=master: master.reconnects.reopening)
            assert master.close_event is None
        else:
            closed = await asyncio.wait_for(master.wait_closed(), 5.0)
            assert closed.cause is CloseCause.PEER_CLOSE and master.reconnects.count == 0
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
    from tdtp import ReconnectPolicy

    key = KEY if keyed else None
    server = await listen("127.0.0.1", 0, key=key)
    port = server.port
    # Only the restarted slave's RESET may reopen: a loaded machine can take longer than the
    # default after_silence (3 s) between the kill and the new slave's answer.
    policy = ReconnectPolicy(after_silence=None)
    master = await connect("127.0.0.1", port, key=key, reconnect=policy)
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
    from tdtp import InvalidArgumentError
    from tdtp.errors import ArgumentTypeError

    with pytest.raises(InvalidArgumentError, match="attempts"):
        ReconnectPolicy(attempts=-1)
    with pytest.raises(InvalidArgumentError, match="after_silence"):
        ReconnectPolicy(after_silence=0)
    with pytest.raises(InvalidArgumentError, match="busy_backoff"):
        ReconnectPolicy(busy_backoff=0)
    with pytest.raises(InvalidArgumentError, match="reopen_on cannot hold"):
        ReconnectPolicy(reopen_on={CloseCause.LOCAL_CLOSE})
    with pytest.raises(ArgumentTypeError, match="reopen_on"):
        ReconnectPolicy(reopen_on={"peer_restarting"})  # type: ignore[arg-type]
    with pytest.raises(ArgumentTypeError, match="reopen_on"):
        ReconnectPolicy(reopen_on="peer_close")  # type: ignore[arg-type]
    policy = ReconnectPolicy(reopen_on=[CloseCause.EVICTED])
    assert policy.reopen_on == frozenset({CloseCause.EVICTED})
    assert CloseCause.PEER_RESTARTING in ReconnectPolicy().reopen_on
    with pytest.raises(ArgumentTypeError, match="reconnect"):
        connect("127.0.0.1", 9, reconnect="yes")  # type: ignore[arg-type]
