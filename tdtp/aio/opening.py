"""What :func:`~tdtp.aio.api.connect` and :func:`~tdtp.aio.server.listen` share: the :class:`Opener`
they return, the checks of their arguments, the wording of address errors, and the socket set-up both
give their transport (a zero write-buffer mark, datagrams handed straight to the receiver, waiting until
the port is free)."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import socket
from collections.abc import Callable, Coroutine, Generator
from typing import Any, Generic, Protocol, TypeVar

from tdtp.aio.capture import CapturingTransport
from tdtp.aio.endpoint import Endpoint, format_address
from tdtp.aio.impairment import as_spec
from tdtp.aio.timer import check_timer_preference
from tdtp.config import ConnectionConfig, Role
from tdtp.errors import (
    AddressError,
    ArgumentTypeError,
    ConnectError,
    EndpointClosedError,
    InvalidArgumentError,
    PortUnreachableError,
)
from tdtp.netem import NetemSpec
from tdtp.session.events import Address, CloseCause

__all__ = ["SOCKET_CLOSE_PATIENCE", "Opener", "address_error"]

SOCKET_CLOSE_PATIENCE = 5.0
"""Longest :meth:`Server.close` waits for an emulated link to let its last datagrams out before it
drops them and releases the port."""


class _Closable(Protocol):
    async def close(self) -> None: ...


T = TypeVar("T", bound=_Closable)


class Opener(Generic[T]):
    """What :func:`connect` and :func:`listen` return: ``await`` it for the endpoint (or server), or
    use it as ``async with tdtp.connect(...) as ep:``, which closes it on the way out."""

    def __init__(self, open_: Callable[[], Coroutine[Any, Any, T]]) -> None:
        self._open = open_
        self._opened: T | None = None

    def __await__(self) -> Generator[Any, None, T]:
        return self._open().__await__()

    async def __aenter__(self) -> T:
        self._opened = await self._open()
        return self._opened

    async def __aexit__(self, *exc_info: object) -> None:
        opened, self._opened = self._opened, None
        if opened is not None:
            await opened.close()


def _peer_key(addr: Address) -> tuple[object, object]:
    return addr[0], addr[1]


def _check_port(port: object, *, allow_zero: bool) -> int:
    low = 0 if allow_zero else 1
    if isinstance(port, bool) or not isinstance(port, int) or not low <= port <= 65535:
        what = "0..65535 (0 picks a free port)" if allow_zero else "1..65535"
        raise InvalidArgumentError(f"port must be an integer in {what}, got {port!r}")
    return port


def _check_common(
    config: object, timer: object, on_data: object, on_watchdog: object, netem: object
) -> NetemSpec | None:
    if config is not None and not isinstance(config, ConnectionConfig):
        raise ArgumentTypeError(
            f"config must be a tdtp.ConnectionConfig or None, got {type(config).__name__}"
        )
    check_timer_preference(timer)
    for name, callback in (("on_data", on_data), ("on_watchdog", on_watchdog)):
        if callback is not None and not callable(callback):
            raise ArgumentTypeError(f"{name} must be callable or None, got {callback!r}")
    if netem is None:
        return None
    if not isinstance(netem, NetemSpec | str):
        raise ArgumentTypeError(f"netem must be a netem string or NetemSpec, got {netem!r}")
    return as_spec(netem)


def address_error(exc: OSError, action: str, host: object, port: int) -> AddressError:
    """The :class:`~tdtp.AddressError` for an ``OSError`` from resolving or binding ``host:port``:
    what to ``action`` (e.g. "listen on") and why, in words a user can act on."""
    where = format_address((host, port))
    if exc.errno is None and isinstance(exc.__cause__, OSError):
        exc = exc.__cause__  # uvloop wraps the bind error: the errno is on its cause
    if isinstance(exc, socket.gaierror):
        return AddressError(f"cannot {action} {where}: host name not resolved ({exc.strerror})")
    if exc.errno == errno.EADDRINUSE:
        return AddressError(
            f"cannot {action} {where}: the port is in use; choose another port or stop the "
            "program using it"
        )
    if exc.errno == errno.EADDRNOTAVAIL:
        return AddressError(f"cannot {action} {where}: not an address of this host")
    return AddressError(f"cannot {action} {where}: {exc.strerror or exc}")


def _limit_write_buffer(transport: asyncio.BaseTransport) -> None:
    """Ask for ``pause_writing`` as soon as the loop has to buffer one datagram: the endpoint then
    holds data (a newer sample supersedes it) instead of letting the loop queue it."""
    # A loop without flow control keeps what it cannot send to itself; nothing to do then.
    with contextlib.suppress(AttributeError, NotImplementedError):
        transport.set_write_buffer_limits(high=0)  # type: ignore[attr-defined]


def _deliver_to(
    protocol: asyncio.DatagramProtocol,
    receive: Callable[[bytes, Address], None],
    capture: CapturingTransport | None,
) -> None:
    """Hand the protocol's datagrams straight to ``receive`` (one Python call less per datagram),
    through the pcap capture first when there is one."""
    if capture is None:
        protocol.datagram_received = receive  # type: ignore[method-assign,assignment]
        return
    record = capture.received

    def recorded(data: bytes, addr: Address) -> None:
        record(data, addr)
        receive(data, addr)

    protocol.datagram_received = recorded  # type: ignore[method-assign]


async def _released(closed: asyncio.Future[None], transport: asyncio.DatagramTransport) -> None:
    """Wait until the socket is closed (the port is free), dropping what an emulated link still
    holds after :data:`SOCKET_CLOSE_PATIENCE`."""
    try:
        await asyncio.wait_for(asyncio.shield(closed), SOCKET_CLOSE_PATIENCE)
    except TimeoutError:
        transport.abort()
        await asyncio.shield(closed)


def refused_text(where: str, peer_role: Role) -> str:
    """What an ICMP port unreachable in answer to our OPEN means: nothing listens there, or a NAT
    or firewall in front of the peer answered for it (it has no mapping for an unsolicited
    datagram); what to do about either."""
    peer = peer_role.value
    return (
        f"nothing listens at {where}: the answer to our OPEN was ICMP port unreachable. Either no "
        f"{peer} runs there (start it, or check the host and port; a {peer} started with "
        "tdtp.listen() binds 127.0.0.1 unless given a host: to be reached from other machines it "
        f'listens on "0.0.0.0" or its own address), or the {peer} sits behind a NAT or firewall '
        "that answered for it: let it dial out to us instead, or meet through a relay "
        "(docs/NAT.md, 'The robot behind NAT')"
    )


def no_answer_hint(port: int, peer_role: Role) -> str:
    """What to check when the peer never answered: the likely causes, in the order to check them."""
    peer = peer_role.value
    us = "master" if peer_role is Role.SLAVE else "slave"
    return (
        f". Nothing came back: check that the {peer} runs and that this machine can reach it. "
        f"tdtp.listen() binds 127.0.0.1 unless given a host, so a {peer} meant for other machines "
        'listens on "0.0.0.0" or its own address (tdtp slave binds 0.0.0.0); a firewall on the '
        f"way must let UDP port {port} through; and a {peer} behind NAT needs UDP port {port} "
        f"forwarded to it, or dials out itself, or meets us through a relay (docs/NAT.md) (a {us} "
        "behind NAT needs nothing: its OPEN opens the way back)"
    )


async def established(
    endpoint: Endpoint, where: str, port: int, unreachable: Callable[[], None]
) -> Endpoint:
    """Wait until a dialing endpoint's session is established: :class:`~tdtp.ConnectError` if the
    peer refused or never answered (with :func:`no_answer_hint` then),
    :class:`~tdtp.PortUnreachableError` as soon as its host said nothing listens (``unreachable``
    releases the socket then: nobody to send a CLOSE to)."""
    try:
        await endpoint.wait_established()
    except EndpointClosedError as exc:
        await endpoint.close()
        peer = Role.SLAVE if endpoint.connection.role is Role.MASTER else Role.MASTER
        hint = no_answer_hint(port, peer) if exc.event.cause is CloseCause.OPEN_TIMEOUT else ""
        raise ConnectError(f"could not open a TDTP connection to {where}: {exc}{hint}") from exc
    except PortUnreachableError:
        # fail_open() released the endpoint already
        unreachable()
        raise
    except BaseException:
        await endpoint.close()
        raise
    return endpoint
