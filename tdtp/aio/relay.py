"""An impairing UDP relay for any application: ``tdtp netem-relay --listen :9000 --forward HOST:9001``.

Clients send to the relay's listening port; the relay forwards each datagram to the target through an
emulated netem link and sends the target's answers back through another. Like a NAT, it gives every client
address its own upstream socket, so the target sees one peer per client and answers reach the right one.
The table of clients is bounded (``max_clients``) and idle clients are forgotten after ``idle_timeout``.
"""

from __future__ import annotations

import asyncio
import socket
from dataclasses import dataclass
from typing import cast

from tdtp.aio.api import address_error
from tdtp.aio.impairment import DelayLine, as_spec
from tdtp.aio.timer import monotonic
from tdtp.errors import InvalidArgumentError
from tdtp.netem import NetemLink, NetemSpec
from tdtp.session.events import Address

__all__ = [
    "BACKLOG_LIMIT",
    "NetemRelay",
    "RelayStats",
    "start_relay",
]

BACKLOG_LIMIT = 64
"""Datagrams held per client while its upstream socket opens (a few milliseconds at most)."""


@dataclass(slots=True)
class RelayStats:
    clients: int = 0
    """Clients known now."""
    clients_refused: int = 0
    """Datagrams from new clients dropped because the table was full."""
    forwarded: int = 0
    """Datagrams handed to the forward link (client -> target)."""
    returned: int = 0
    """Datagrams handed to the return link (target -> client)."""
    forward_errors: int = 0
    """Datagrams the relay could not send on to the target (its socket failed or refused them)."""


class _Upstream(asyncio.DatagramProtocol):
    """One client's socket towards the target."""

    def __init__(self, relay: NetemRelay, client: Address) -> None:
        self.relay = relay
        self.client = client
        self.transport: asyncio.DatagramTransport | None = None
        self.last_seen = monotonic()
        self.backlog: list[bytes] = []
        """Datagrams the forward link delivered before this socket was open (bounded)."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.DatagramTransport, transport)
        for data in self.backlog:
            self.transport.sendto(data)
        self.backlog.clear()

    def datagram_received(self, data: bytes, addr: Address) -> None:
        self.last_seen = monotonic()
        self.relay.stats.returned += 1
        self.relay.back.put(data, self.client)

    def error_received(self, exc: Exception) -> None:
        pass  # the target is not listening (yet): UDP says nothing more


class _Listener(asyncio.DatagramProtocol):
    def __init__(self, relay: NetemRelay) -> None:
        self.relay = relay

    def datagram_received(self, data: bytes, addr: Address) -> None:
        self.relay._from_client(data, addr)


class NetemRelay:
    """Create with :func:`start_relay`; stop with :meth:`close`."""

    def __init__(
        self,
        forward_to: Address,
        forward_spec: NetemSpec,
        return_spec: NetemSpec,
        *,
        seed: int | None,
        max_clients: int,
        idle_timeout: float,
    ) -> None:
        if isinstance(max_clients, bool) or not isinstance(max_clients, int) or max_clients < 1:
            raise InvalidArgumentError(f"max_clients must be an integer >= 1, got {max_clients!r}")
        self.forward_to = forward_to
        self.stats = RelayStats()
        self._max_clients = max_clients
        self._idle_timeout = idle_timeout
        self._clients: dict[Address, _Upstream] = {}
        self._listener: asyncio.DatagramTransport | None = None
        self.forward = DelayLine(NetemLink(forward_spec, seed=seed), self._to_target)
        self.back = DelayLine(
            NetemLink(return_spec, seed=None if seed is None else seed + 1), self._to_client
        )
        self._sweeper: asyncio.Task[None] | None = None

    @property
    def address(self) -> Address:
        """The address the relay listens on, where clients send."""
        assert self._listener is not None
        sockname: Address = self._listener.get_extra_info("sockname")
        return sockname

    def change(self, spec: NetemSpec | str, *, return_spec: NetemSpec | str | None = None) -> None:
        """Impair from now on with ``spec`` forward and ``return_spec`` back (default: ``spec``), as
        ``tc qdisc change`` would: ``relay.change("loss 100%")`` is an outage both ways, and
        changing back ends it. Datagrams already on a link keep their delivery times."""
        self.forward.change(spec)
        self.back.change(spec if return_spec is None else return_spec)

    async def rebind(self) -> None:
        """A NAT rebinding: from now on each client's datagrams reach the target from a new socket
        (a new source port), and the old sockets are closed, so what the target still sends to
        them is lost. Tests path migration (docs/PROTOCOL.md 5.8)."""
        for client, old in list(self._clients.items()):
            fresh = _Upstream(self, client)
            fresh.last_seen = old.last_seen
            self._clients[client] = fresh
            if old.transport is not None:
                old.transport.close()
            await self._open_upstream(fresh)

    def _from_client(self, data: bytes, client: Address) -> None:
        upstream = self._clients.get(client)
        if upstream is None:
            if len(self._clients) >= self._max_clients:
                self.stats.clients_refused += 1
                return
            upstream = _Upstream(self, client)
            self._clients[client] = upstream
            self.stats.clients = len(self._clients)
            asyncio.get_running_loop().create_task(self._open_upstream(upstream))
        upstream.last_seen = monotonic()
        self.stats.forwarded += 1
        self.forward.put(data, client)

    async def _open_upstream(self, upstream: _Upstream) -> None:
        loop = asyncio.get_running_loop()
        try:
            await loop.create_datagram_endpoint(
                lambda: upstream, remote_addr=(str(self.forward_to[0]), int(self.forward_to[1]))
            )
        except OSError:
            # No socket towards the target for this client: what it sent is not delivered.
            self.stats.forward_errors += len(upstream.backlog)
            upstream.backlog.clear()
            if self._clients.get(upstream.client) is upstream:
                del self._clients[upstream.client]
                self.stats.clients = len(self._clients)

    def _to_target(self, data: bytes, client: Address | None) -> None:
        upstream = self._clients.get(client) if client is not None else None
        if upstream is None:
            self.stats.forward_errors += 1
            return
        if upstream.transport is not None:
            try:
                upstream.transport.sendto(data)
            except OSError:
                self.stats.forward_errors += 1
        elif len(upstream.backlog) < BACKLOG_LIMIT:
            upstream.backlog.append(data)
        else:
            self.stats.forward_errors += 1

    def _to_client(self, data: bytes, client: Address | None) -> None:
        if self._listener is not None and client is not None:
            self._listener.sendto(data, client)

    async def _sweep(self) -> None:
        while True:
            await asyncio.sleep(min(self._idle_timeout, 1.0))
            cutoff = monotonic() - self._idle_timeout
            for client, upstream in list(self._clients.items()):
                if upstream.last_seen < cutoff:
                    if upstream.transport is not None:
                        upstream.transport.close()
                    del self._clients[client]
            self.stats.clients = len(self._clients)

    async def close(self) -> None:
        """Stop relaying: close the listening socket and every client's upstream one."""
        if self._sweeper is not None:
            self._sweeper.cancel()
        self.forward.close()
        self.back.close()
        for upstream in self._clients.values():
            if upstream.transport is not None:
                upstream.transport.close()
        self._clients.clear()
        if self._listener is not None:
            self._listener.close()


async def start_relay(
    listen: tuple[str, int],
    forward_to: tuple[str, int],
    spec: NetemSpec | str,
    *,
    return_spec: NetemSpec | str | None = None,
    seed: int | None = None,
    max_clients: int = 256,
    idle_timeout: float = 60.0,
) -> NetemRelay:
    """Listen on ``listen`` and relay to ``forward_to``, impairing the forward direction with ``spec``
    and the return direction with ``return_spec`` (default: the same as ``spec``).

    The target is resolved first: :class:`~tdtp.AddressError` if it cannot be, or if ``listen``
    cannot be bound.
    """
    forward_spec = as_spec(spec)
    loop = asyncio.get_running_loop()
    host, port = forward_to
    try:
        infos = await loop.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    except OSError as exc:
        raise address_error(exc, "relay to", host, port) from exc
    target = infos[0][4]
    relay = NetemRelay(
        (str(target[0]), int(target[1])),
        forward_spec,
        forward_spec if return_spec is None else as_spec(return_spec),
        seed=seed,
        max_clients=max_clients,
        idle_timeout=idle_timeout,
    )
    try:
        transport, _ = await loop.create_datagram_endpoint(
            lambda: _Listener(relay), local_addr=listen
        )
    except OSError as exc:
        relay.forward.close()
        relay.back.close()
        raise address_error(exc, "listen on", *listen) from exc
    relay._listener = transport
    relay._sweeper = loop.create_task(relay._sweep())
    return relay
