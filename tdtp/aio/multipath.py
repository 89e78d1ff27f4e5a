"""Multipath on asyncio: a master's several local sockets, and ``ep.paths`` (docs/PROTOCOL.md 5.11).

``tdtp.connect(host, port, local_addresses=[...])`` opens one UDP socket per local address (an IP,
``IP:PORT``, an interface as ``%wwan0`` or ``IP%wwan0``, each optionally ``=HOST:PORT`` for a remote
end other than the slave's address), opens the session on the first and, once it is established,
a path from each of the others: the core challenges it, the slave answers on it, and from then on
the scheduler spreads the samples over every path that works (:mod:`tdtp.session.multipath`). The
slave needs nothing: its server learns each new path from its first challenge and validates it.

:class:`PathSet` is ``ep.paths``: the paths' figures (iterate it, or index it by path id), their
events (:class:`~tdtp.session.events.PathChanged`: a path came, went or degraded), and
:meth:`PathSet.add` / :meth:`PathSet.remove` for a modem that comes and goes. The sockets are the
loop's own datagram transports (a path carries at most the session's samples, so the batched layer's
savings do not matter here), each connected to its remote end, so that the kernel keeps strangers out.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from tdtp.aio.impairment import ImpairedTransport, impaired_receiver
from tdtp.aio.timer import monotonic
from tdtp.config import Role
from tdtp.errors import InvalidArgumentError
from tdtp.netem import NetemSpec, parse_netem
from tdtp.session.connection import Connection
from tdtp.session.events import Address, PathChanged
from tdtp.session.multipath.path import PathStats
from tdtp.session.state import State

if TYPE_CHECKING:
    from tdtp.aio.endpoint import Endpoint

__all__ = [
    "LocalAddress",
    "PathCallback",
    "PathProtocol",
    "PathSet",
    "check_path_netem",
    "open_socket",
    "parse_local_address",
]

logger = logging.getLogger("tdtp")

PATH_EVENTS_KEPT = 256
"""Path events ``ep.paths.events`` keeps (the oldest go first)."""

PathCallback = Callable[[PathChanged], None]


@dataclass(frozen=True, slots=True)
class LocalAddress:
    """One local end of a path: an address (``""``: any), a port (0: any), an interface to bind
    to (``SO_BINDTODEVICE``; ``""``: none), and the remote end (``None``: the slave's address)."""

    host: str = ""
    port: int = 0
    interface: str = ""
    remote: tuple[str, int] | None = None

    def __str__(self) -> str:
        text = self.host or "*"
        if self.port:
            text += f":{self.port}"
        if self.interface:
            text += f"%{self.interface}"
        if self.remote is not None:
            text += f"={self.remote[0]}:{self.remote[1]}"
        return text


def _host_port(text: str, what: str) -> tuple[str, int]:
    if text.startswith("["):
        host, sep, port = text[1:].partition("]:")
    elif text.count(":") == 1:
        host, sep, port = text.partition(":")
    else:
        return text, 0
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise InvalidArgumentError(f"{what} {text!r} must be HOST or HOST:PORT (port 0..65535)")
    return host, int(port)


def parse_local_address(entry: str | tuple[str, int] | LocalAddress) -> LocalAddress:
    """``"10.0.1.1"``, ``"10.0.1.1:7001"``, ``"%wwan0"``, ``"10.0.1.1%wwan0"``, each optionally
    followed by ``"=HOST:PORT"`` (the path's remote end), a ``(host, port)`` tuple, or a
    :class:`LocalAddress`."""
    if isinstance(entry, LocalAddress):
        return entry
    if isinstance(entry, tuple):
        if len(entry) != 2 or not isinstance(entry[0], str) or not isinstance(entry[1], int):
            raise InvalidArgumentError(f"a local address tuple is (host, port), got {entry!r}")
        return LocalAddress(entry[0], entry[1])
    if not isinstance(entry, str) or not entry:
        raise InvalidArgumentError(
            f"a local address is a string like '10.0.1.1', '10.0.1.1:7001', '%wwan0' or "
            f"'10.0.1.1=10.0.9.1:7000', got {entry!r}"
        )
    local, _, remote_text = entry.partition("=")
    remote: tuple[str, int] | None = None
    if remote_text:
        host, port = _host_port(remote_text, "the remote end")
        if not host or not port:
            raise InvalidArgumentError(
                f"the remote end after '=' must be HOST:PORT with a port, got {remote_text!r}"
            )
        remote = (host, port)
    address, _, interface = local.partition("%")
    host, port = _host_port(address, "the local address") if address else ("", 0)
    return LocalAddress(host, port, interface, remote)


class PathProtocol(asyncio.DatagramProtocol):
    def __init__(
        self,
        receive: Callable[[bytes, Address], None],
        on_error: Callable[[Exception], None] | None = None,
    ) -> None:
        self.receive = receive
        self.on_error = on_error
        self.errors = 0

    def datagram_received(self, data: bytes, addr: Address) -> None:
        self.receive(data, addr)

    def error_received(self, exc: Exception) -> None:
        self.errors += 1  # one path's ICMP error says nothing about the session
        if self.on_error is not None:
            self.on_error(exc)


@dataclass(slots=True)
class _Socket:
    local: int
    spec: LocalAddress
    remote: Address
    transport: asyncio.DatagramTransport
    sender: asyncio.DatagramTransport | ImpairedTransport
    protocol: PathProtocol
    path_id: int | None = None


async def open_socket(
    loop: asyncio.AbstractEventLoop,
    spec: LocalAddress,
    remote: Address,
    receive: Callable[[bytes, Address], None],
    on_error: Callable[[Exception], None] | None = None,
) -> tuple[asyncio.DatagramTransport, PathProtocol]:
    family = socket.AF_INET6 if ":" in str(remote[0]) else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.setblocking(False)
        if spec.interface:
            if not hasattr(socket, "SO_BINDTODEVICE"):
                raise InvalidArgumentError(
                    f"binding a path to an interface ({spec.interface}) needs SO_BINDTODEVICE "
                    "(Linux); give the interface's address instead"
                )
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_BINDTODEVICE, spec.interface.encode())
        sock.bind((spec.host or ("::" if family == socket.AF_INET6 else "0.0.0.0"), spec.port))
        sock.connect((remote[0], remote[1]))
        transport, protocol = await loop.create_datagram_endpoint(
            lambda: PathProtocol(receive, on_error), sock=sock
        )
    except BaseException:
        sock.close()
        raise
    return transport, protocol


class PathSet:
    """``ep.paths``: the session's paths, their events, and adding or removing one.

    Iterating it gives a :class:`~tdtp.session.multipath.path.PathStats` per path (a snapshot);
    ``ep.paths[path_id]`` one. A single-path session has none (``len(ep.paths) == 0``)."""

    def __init__(self, endpoint: Endpoint) -> None:
        self._endpoint = endpoint
        self._sockets: dict[int, _Socket] = {}
        self._opened_for: Connection | None = None
        self._netem_seed: int | None = None
        self._timer: str = "auto"
        self.events: deque[PathChanged] = deque(maxlen=PATH_EVENTS_KEPT)
        """The latest path events, oldest first (also delivered to :meth:`set_callback`'s)."""
        self._callback: PathCallback | None = None
        self.send_errors = 0
        """Datagrams a path's socket refused (its network down, no route): lost like any other."""

    # ------------------------------------------------------------------ what an application reads

    def stats(self) -> list[PathStats]:
        paths = self._endpoint.connection.multipath
        return [] if paths is None else paths.path_stats(monotonic())

    def __iter__(self) -> Iterator[PathStats]:
        return iter(self.stats())

    def __len__(self) -> int:
        paths = self._endpoint.connection.multipath
        return 0 if paths is None else len(paths.paths)

    def __getitem__(self, path_id: int) -> PathStats:
        for stats in self.stats():
            if stats.path_id == path_id:
                return stats
        raise KeyError(f"no path {path_id}; the session's paths are {[s.path_id for s in self]}")

    def set_callback(self, on_path: PathCallback | None) -> None:
        """Call ``on_path`` with every :class:`~tdtp.PathChanged` as it happens."""
        self._callback = on_path

    # ------------------------------------------------------------------ adding and removing

    async def add(
        self, local: str | tuple[str, int] | LocalAddress, *, netem: NetemSpec | str | None = None
    ) -> int:
        """Open a path from another local address (see :func:`parse_local_address`); returns the
        socket's number. The path carries traffic once the slave has answered on it (its
        ``PathChanged`` to ``"active"``). ``netem`` impairs it both ways, in-process."""
        endpoint = self._endpoint
        conn = endpoint.connection
        if conn.role is not Role.MASTER or conn.multipath is None:
            raise InvalidArgumentError(
                "paths are added by a master in a multipath session: connect with "
                "local_addresses=[...] (or config=ConnectionConfig(multipath=MultipathConfig()))"
            )
        spec = parse_local_address(local)
        peer = conn.peer
        assert peer is not None
        remote: Address = spec.remote if spec.remote is not None else (peer[0], peer[1])
        number = max(self._sockets, default=0) + 1
        await self.bind(number, spec, remote, netem)
        self._open(self._sockets[number], monotonic())
        endpoint.flush()
        return number

    def remove(self, local: int) -> None:
        """Stop using the path through local socket ``local`` (the slave is told) and close it."""
        entry = self._sockets.pop(local, None)
        if entry is None:
            raise InvalidArgumentError(
                f"no path socket {local}; the added ones are {sorted(self._sockets)} (the "
                "session's own socket, 0, goes with the session)"
            )
        paths = self._endpoint.connection.multipath
        if paths is not None and entry.path_id is not None and entry.path_id in paths.paths:
            paths.close_path(entry.path_id, monotonic())
            self._endpoint.flush()
            self.flush()
        entry.sender.close()

    async def bind(
        self,
        number: int,
        spec: LocalAddress,
        remote: Address,
        netem: NetemSpec | str | None = None,
    ) -> None:
        """Open local socket ``number`` towards ``remote`` (a path once the session opens it)."""
        loop = asyncio.get_running_loop()

        def receive(data: bytes, addr: Address) -> None:
            self._received(number, data, addr)

        deliver: Callable[[bytes, Address], None] = receive
        spec_netem = parse_netem(netem) if isinstance(netem, str) else netem
        if spec_netem is not None:
            seed = None if self._netem_seed is None else self._netem_seed + 2 * number + 1
            deliver, _line = impaired_receiver(receive, spec_netem, seed=seed, timer=self._timer)
        transport, protocol = await open_socket(loop, spec, remote, deliver)
        sender: asyncio.DatagramTransport | ImpairedTransport = transport
        if spec_netem is not None:
            seed = None if self._netem_seed is None else self._netem_seed + 2 * number
            sender = ImpairedTransport(transport, spec_netem, seed=seed, timer=self._timer)
        self._sockets[number] = _Socket(number, spec, remote, transport, sender, protocol)

    def _open(self, entry: _Socket, now: float) -> None:
        paths = self._endpoint.connection.multipath
        if paths is None or paths.has_path(entry.local, entry.remote):
            return
        try:
            entry.path_id = paths.open_path(entry.local, entry.remote, now)
        except InvalidArgumentError as exc:
            logger.warning("tdtp: cannot open a path from %s: %s", entry.spec, exc)

    # ------------------------------------------------------------------ driven by the endpoint

    def flush(self) -> None:
        """After the connection's datagrams left: a new session's paths are opened, and what the
        core routed to the other sockets leaves through them."""
        conn = self._endpoint.connection
        paths = conn.multipath
        if paths is None:
            return
        if self._opened_for is not conn and conn.state is State.ESTABLISHED:
            self._opened_for = conn  # (again after a reconnect: a new session, new paths)
            now = monotonic()
            for entry in self._sockets.values():
                if entry.local:
                    self._open(entry, now)
            self._endpoint.flush(now)
        routed = paths.routed
        if not routed:
            return
        paths.routed = []
        sockets = self._sockets
        for data, _remote, local in routed:
            target = sockets.get(local)
            if target is None:
                continue  # removed meanwhile
            try:
                target.sender.sendto(data)
            except OSError:
                self.send_errors += 1

    def on_event(self, event: PathChanged) -> None:
        self.events.append(event)
        level = logging.WARNING if event.state in ("failed", "closed") else logging.INFO
        logger.log(level, "tdtp: path %d %s (%s)", event.path_id, event.state, event.detail)
        callback = self._callback
        if callback is not None:
            try:
                callback(event)
            except Exception as exc:  # the application's error: reported as asyncio does, then on
                asyncio.get_running_loop().call_exception_handler(
                    {
                        "message": f"{self._endpoint!r}: the on_path callback raised",
                        "exception": exc,
                        "endpoint": self._endpoint,
                    }
                )

    def _received(self, local: int, data: bytes, addr: Address) -> None:
        endpoint = self._endpoint
        conn = endpoint.connection
        paths = conn.multipath
        now = monotonic()
        if paths is None:
            return  # no multipath session (yet, or any more): nothing to take it
        paths.rx_local = local
        try:
            conn.receive_datagram(data, addr, now=now)
        finally:
            paths.rx_local = 0
        endpoint.flush(now)

    def close(self) -> None:
        for entry in self._sockets.values():
            entry.sender.close()
        self._sockets.clear()


def check_path_netem(
    path_netem: Sequence[NetemSpec | str | None] | None, paths: int
) -> list[NetemSpec | None]:
    if path_netem is None:
        return []
    if len(path_netem) > paths:
        raise InvalidArgumentError(
            f"path_netem has {len(path_netem)} entries for {paths} paths (one per local address)"
        )
    specs: list[NetemSpec | None] = []
    for spec in path_netem:
        if spec is None or isinstance(spec, NetemSpec):
            specs.append(spec)
        elif isinstance(spec, str):
            try:
                specs.append(parse_netem(spec))
            except ValueError as exc:
                raise InvalidArgumentError(f"path_netem: {exc}") from None
        else:
            raise InvalidArgumentError(f"path_netem entries are netem strings, got {spec!r}")
    return specs
