"""The asyncio API as a user meets it: arguments checked at once, errors that say why, ``async with``
without ``await``, ports released on close, logging, reprs."""

from __future__ import annotations

import asyncio
import logging
import socket

import pytest

import tdtp
from tdtp import (
    AddressError,
    CloseCause,
    ConnectError,
    ConnectionConfig,
    EndpointClosedError,
    InvalidArgumentError,
    PayloadTypeError,
    PortUnreachableError,
    ServerClosedError,
    TdtpError,
    connect,
    listen,
)

from eventually import eventually


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
    return port


def test_every_exception_is_a_tdtp_error_with_the_standard_base_that_fits() -> None:
    assert issubclass(tdtp.EndpointClosedError, TdtpError)
    assert issubclass(tdtp.EndpointClosedError, ConnectionError)
    assert issubclass(tdtp.EndpointClosedError, tdtp.ConnectionClosedError)
    assert issubclass(tdtp.ConnectError, TdtpError) and issubclass(ConnectError, ConnectionError)
    assert issubclass(PortUnreachableError, ConnectError)
    assert issubclass(ServerClosedError, ConnectionError)
    assert issubclass(InvalidArgumentError, ValueError)
    assert issubclass(PayloadTypeError, TypeError)
    assert issubclass(AddressError, OSError)
    assert issubclass(tdtp.PayloadTooLargeError, TdtpError)
    from tdtp.aio.timer import TimerUnavailableError
    from tdtp.netem import NetemSyntaxError

    assert issubclass(TimerUnavailableError, TdtpError)
    assert issubclass(NetemSyntaxError, TdtpError)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: listen("127.0.0.1", 70000), "port must be an integer in 0..65535"),
        (lambda: listen("127.0.0.1", -1), "port"),
        (lambda: listen("127.0.0.1", "7000"), "port"),  # type: ignore[arg-type]
        (lambda: connect("127.0.0.1", 70000), "port must be an integer in 1..65535"),
        (lambda: connect("127.0.0.1", 0), "port"),
        (lambda: connect("", 7000), "host"),
        (lambda: connect("127.0.0.1", 7000, local_addr=("127.0.0.1", 99999)), "port"),
        (lambda: connect("127.0.0.1", 7000, timer="timefd"), "timer must be one of"),  # type: ignore[arg-type]
        (lambda: listen(timer="timefd"), "timer must be one of"),  # type: ignore[arg-type]
        (lambda: listen(max_peers=0), "max_peers"),
        (lambda: listen(max_peers=True), "max_peers"),  # type: ignore[arg-type]
        (lambda: listen(config="fast"), "config must be"),  # type: ignore[arg-type]
        (lambda: listen(on_data=42), "on_data must be callable"),  # type: ignore[arg-type]
        (lambda: listen(netem="delay 20xs"), "20xs"),
        (lambda: ConnectionConfig(controller="nope"), "unknown controller 'nope'"),  # type: ignore[arg-type]
        (
            lambda: ConnectionConfig(controller="fixed", controller_config=object()),
            "configured by FixedConfig",
        ),
        (lambda: ConnectionConfig(ack_size=3), "ack_size"),
        (lambda: ConnectionConfig(max_payload=70000), "max_payload"),
    ],
)
def test_misuse_is_refused_at_once_without_binding_anything(call: object, match: str) -> None:
    """No event loop is needed: the call itself raises (uvloop used to bind 70000 as port 4464)."""
    with pytest.raises(TdtpError, match=match):
        call()  # type: ignore[operator]


@pytest.mark.asyncio
async def test_async_with_works_with_and_without_await() -> None:
    async with listen() as server, connect("127.0.0.1", server.port) as master:
        slave = await server.accept()
        assert isinstance(master, tdtp.Endpoint) and isinstance(slave, tdtp.Endpoint)
    assert master.is_closed
    async with await listen() as server, await connect("127.0.0.1", server.port) as master:
        assert not master.is_closed
    assert master.is_closed


@pytest.mark.asyncio
async def test_server_close_waits_until_the_port_is_free() -> None:
    for netem in (None, "delay 5ms"):
        server = await listen("127.0.0.1", 0, netem=netem)
        port = server.port
        master = await connect("127.0.0.1", port)
        await server.accept()
        await server.close()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as again:
            again.bind(("127.0.0.1", port))  # raises EADDRINUSE if the socket were still open
        await server.close()  # idempotent
        with pytest.raises(ServerClosedError):
            await server.accept()
        await master.close()


@pytest.mark.asyncio
async def test_address_errors_say_what_is_wrong() -> None:
    async with listen("127.0.0.1", 0) as server:
        with pytest.raises(AddressError, match="in use"):
            await listen("127.0.0.1", server.port)
    with pytest.raises(AddressError, match="not resolved"):
        await connect("nosuch.invalid", 7000)
    with pytest.raises(AddressError, match="not resolved"):
        await listen("nosuch.invalid", 0)


@pytest.mark.asyncio
async def test_connecting_where_nothing_listens_fails_fast_with_a_specific_error() -> None:
    """ECONNREFUSED arrives in milliseconds; the open timeout here is 60 s, the bound 10 s."""
    port = _free_port()
    config = ConnectionConfig(open_timeout=60.0)
    async with asyncio.timeout(10.0):
        with pytest.raises(
            PortUnreachableError, match=f"nothing listens at 127.0.0.1:{port}"
        ) as refused:
            await connect("127.0.0.1", port, config=config)
    # A robot whose slave bound 127.0.0.1 refuses masters on other machines the same way.
    assert "binds 127.0.0.1 unless given a host" in str(refused.value)


@pytest.mark.asyncio
async def test_send_takes_bytes_like_only_and_names_the_close_cause_after_close() -> None:
    async with listen() as server, connect("127.0.0.1", server.port) as master:
        slave = await server.accept()
        with pytest.raises(PayloadTypeError, match=r"got str; encode text first"):
            master.send("text")  # type: ignore[arg-type]
        with pytest.raises(PayloadTypeError, match="got list"):
            master.send([1, 2, 3])  # type: ignore[arg-type]
        with pytest.raises(PayloadTypeError, match="got int"):
            master.send(5)  # type: ignore[arg-type]
        master.send(bytearray(b"ba"))
        master.send(memoryview(b"xmv")[1:])
        await eventually(lambda: slave.stats.samples_delivered >= 1)
        newest = slave.latest()
        assert newest is not None and newest.payload in (b"ba", b"mv")
        await master.close()
        await asyncio.wait_for(slave.wait_closed(), 10.0)
        with pytest.raises(EndpointClosedError, match=r"local_close.*closed by the application"):
            master.send(b"x")
        with pytest.raises(EndpointClosedError, match="peer_close") as raised:
            slave.send(b"x")
        assert raised.value.event.cause is CloseCause.PEER_CLOSE
        with pytest.raises(tdtp.ConnectionClosedError):  # the old name still catches it
            slave.send(b"x")


@pytest.mark.asyncio
async def test_logging_goes_to_the_tdtp_logger(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="tdtp")
    async with listen() as server, connect("127.0.0.1", server.port) as master:
        slave = await server.accept()
        master._transport.sendto(b"\xff\xff\xff\xff\xff junk")  # dropped: DEBUG, not shown at INFO
        await eventually(lambda: slave.stats.drops.get("unknown_type") == 1)
    messages = [r.getMessage() for r in caplog.records if r.name == "tdtp"]
    assert any("listening on 127.0.0.1:" in m for m in messages)
    assert sum("connection established" in m for m in messages) == 2
    assert any("connection closed (local_close" in m for m in messages)
    assert not any("dropped" in m for m in messages)
    caplog.clear()
    caplog.set_level(logging.DEBUG, logger="tdtp")
    async with listen() as server, connect("127.0.0.1", server.port) as master:
        slave = await server.accept()
        master._transport.sendto(b"\xff\xff\xff\xff\xff junk")
        await eventually(lambda: slave.stats.drops.get("unknown_type") == 1)
    assert any("dropped a datagram: unknown_type" in r.getMessage() for r in caplog.records)


@pytest.mark.asyncio
async def test_reprs_say_what_and_where() -> None:
    async with listen() as server, connect("127.0.0.1", server.port) as master:
        slave = await server.accept()
        assert repr(server) == f"<Server 127.0.0.1:{server.port} listening masters=1/256>"
        assert repr(master).startswith(f"<Endpoint master peer=127.0.0.1:{server.port} established")
        assert repr(slave).startswith("<Endpoint slave peer=127.0.0.1:")
    assert "closed" in repr(master) and "closed" in repr(server)


@pytest.mark.asyncio
async def test_concurrent_accepts_each_get_a_master_and_waiters_see_the_close() -> None:
    server = await listen("127.0.0.1", 0)
    accepts = [asyncio.create_task(server.accept()) for _ in range(3)]
    await asyncio.sleep(0)  # all three are waiting
    masters = [await connect("127.0.0.1", server.port) for _ in range(2)]
    try:
        await eventually(lambda: sum(task.done() for task in accepts) == 2)
        accepted = {id(task.result()) for task in accepts if task.done()}
        assert len(accepted) == 2  # two different masters, one per accept
        (waiting,) = [task for task in accepts if not task.done()]
        await server.close()
        with pytest.raises(ServerClosedError):
            await asyncio.wait_for(waiting, 10.0)
    finally:
        for master in masters:
            await master.close()
        await server.close()
