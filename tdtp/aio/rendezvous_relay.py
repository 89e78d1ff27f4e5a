"""``tdtp.relay()``: a rendezvous-and-relay service on one UDP port, for any public host (``tdtp relay``).

Two endpoints behind NATs register with it under one rendezvous name; it tells each the other's
addresses so they can punch through to each other, and forwards their datagrams whole while they
cannot (docs/NAT.md, docs/PROTOCOL.md 5.12). The decisions are :class:`~tdtp.rendezvous.relay.RelayCore`'s
(sans-IO); this module is its socket and its once-a-second timer.

The forwarding path is the protocol's ``datagram_received``: one dictionary look-up by source
address, one check that the datagram is not a rendezvous message, one counter, one ``sendto``. It
costs about what a bare forwarder costs (``benchmarks/nat.py`` measures the ratio in the same run).
"""

from __future__ import annotations

import asyncio
import logging
import socket

from tdtp.aio.endpoint import format_address
from tdtp.aio.opening import Opener, _check_port, _released, address_error
from tdtp.aio.timer import monotonic
from tdtp.errors import ArgumentTypeError, ConnectionStateError, InvalidArgumentError
from tdtp.rendezvous.relay import RelayCore, RelayStats
from tdtp.rendezvous.settings import RelayConfig
from tdtp.session.events import Address

__all__ = ["Relay", "relay"]

logger = logging.getLogger("tdtp")

_CONTROL = 2
_FIRST_RENDEZVOUS_CODE = 21
_LAST_RENDEZVOUS_CODE = 24


class _RelayProtocol(asyncio.DatagramProtocol):
    def __init__(self, core: RelayCore) -> None:
        self.core = core
        self.routes = core.routes
        self.transport: asyncio.DatagramTransport | None = None
        self.closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: Address) -> None:
        route = self.routes.get(addr)
        if route is not None and (
            data[0] >> 6 != _CONTROL
            or len(data) < 6
            or not _FIRST_RENDEZVOUS_CODE <= data[5] <= _LAST_RENDEZVOUS_CODE
        ):
            if route.sent < self.core.forward_rate:
                route.sent += 1
                self.transport.sendto(data, route.dest)  # type: ignore[union-attr]
            else:
                route.dropped += 1
            return
        transport = self.transport
        assert transport is not None
        for datagram, to in self.core.receive(data, addr, monotonic()):
            transport.sendto(datagram, to)

    def error_received(self, exc: Exception) -> None:
        pass  # an ICMP error about one registrant says nothing about the others

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.closed.done():
            self.closed.set_result(None)


class Relay:
    """A running relay: :attr:`address`, :attr:`stats`, :meth:`close`."""

    def __init__(self, core: RelayCore) -> None:
        self._core = core
        self._protocol: _RelayProtocol | None = None
        self._transport: asyncio.DatagramTransport | None = None
        self._tick: asyncio.TimerHandle | None = None
        self._closed = False

    @property
    def address(self) -> Address:
        """The bound address (learn the port after ``relay(port=0)``)."""
        if self._transport is None:
            raise ConnectionStateError("the relay is not bound; start it with tdtp.relay()")
        sockname: Address = self._transport.get_extra_info("sockname")
        return sockname

    @property
    def port(self) -> int:
        """The bound UDP port (the one ``relay(port=0)`` picked)."""
        return int(self.address[1])

    @property
    def stats(self) -> RelayStats:
        """Registrations, pairings, forwarded and dropped datagrams, bytes to unvalidated sources."""
        return self._core.stats

    def _on_tick(self) -> None:
        self._core.handle_timer(monotonic())
        self._tick = asyncio.get_running_loop().call_later(1.0, self._on_tick)

    async def close(self) -> None:
        """Stop relaying and free the port. Idempotent."""
        if not self._closed:
            self._closed = True
            if self._tick is not None:
                self._tick.cancel()
            if self._transport is not None:
                self._transport.close()
        if self._protocol is not None and self._transport is not None:
            await _released(self._protocol.closed, self._transport)

    async def __aenter__(self) -> Relay:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    def __repr__(self) -> str:
        where = "(unbound)" if self._transport is None else format_address(self.address)
        return f"<Relay {where} registrations={self._core.stats.registrations}>"


def relay(
    host: str | None = "0.0.0.0", port: int = 0, *, config: RelayConfig | None = None
) -> Opener[Relay]:
    """Run a rendezvous relay on ``host``:``port`` (``async with tdtp.relay(port=7700) as r:``).

    Endpoints meet there with ``tdtp.connect(rendezvous=tdtp.Rendezvous(HOST, PORT))`` and
    ``tdtp.listen(rendezvous=...)`` (``tdtp master|slave --rendezvous HOST:PORT``). ``config``
    bounds its tables and budgets (:class:`~tdtp.RelayConfig`)."""
    if host is not None and not isinstance(host, str):
        raise InvalidArgumentError(f"host must be an address, a host name or None, got {host!r}")
    _check_port(port, allow_zero=True)
    if config is not None and not isinstance(config, RelayConfig):
        raise ArgumentTypeError(f"config must be a tdtp.RelayConfig or None, got {config!r}")
    return Opener(lambda: _start(host or "0.0.0.0", port, config))


async def _start(host: str, port: int, config: RelayConfig | None) -> Relay:
    loop = asyncio.get_running_loop()
    core = RelayCore(config)
    server = Relay(core)
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        transport, protocol = await loop.create_datagram_endpoint(
            lambda: _RelayProtocol(core), local_addr=(host, port), family=family
        )
    except OSError as exc:
        raise address_error(exc, "relay on", host, port) from exc
    server._transport = transport
    server._protocol = protocol
    server._tick = loop.call_later(1.0, server._on_tick)
    logger.info("tdtp relay: listening on %s", format_address(server.address))
    return server
