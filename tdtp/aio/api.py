"""The asyncio entry points: :func:`connect` for a master, :func:`listen` for a slave.

``connect`` gives one :class:`~tdtp.aio.endpoint.Endpoint` on its own connected UDP socket (the kernel
drops datagrams from anyone but the slave). ``listen`` binds one UDP socket for any number of masters, up
to ``max_peers``, and hands out an endpoint for each master whose OPEN arrives.
"""

from __future__ import annotations

import asyncio
import random
import socket
from collections import deque
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

from tdtp.admission.admission import Admission, AdmissionStats, AdmittedOpen, Reply
from tdtp.aio.capture import CaptureTarget, CapturingTransport, open_capture
from tdtp.aio.endpoint import DataCallback, Endpoint, EndpointClosedError
from tdtp.aio.impairment import ImpairedTransport
from tdtp.aio.timer import monotonic
from tdtp.config import ConnectionConfig, Role
from tdtp.connection import Connection
from tdtp.errors import InvalidKeyError
from tdtp.events import Address
from tdtp.netem import NetemSpec
from tdtp.protection.keys import KeyInput, KeyRing, KeysInput, as_key_ring
from tdtp.wire.control import CloseReason, ControlCode
from tdtp.wire.header import HEADER_SIZE, PacketType

_CONTROL_TYPE_BITS = int(PacketType.CONTROL) << 6
_OPEN = int(ControlCode.OPEN)


class ConnectError(ConnectionError):
    """The slave did not accept: no answer within ``open_timeout``, or an explicit refusal."""


def _peer_key(addr: Address) -> tuple[object, object]:
    return addr[0], addr[1]


class _MasterProtocol(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.endpoint: Endpoint | None = None

    def datagram_received(self, data: bytes, addr: Address) -> None:
        endpoint = self.endpoint
        if endpoint is not None:
            endpoint.datagram_received(data, addr)

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable and friends: the idle timeout decides whether the peer is gone.
        if self.endpoint is not None:
            self.endpoint.send_errors += 1


class _CapturingMasterProtocol(_MasterProtocol):
    """Records each datagram into the pcap capture first (used only with ``pcap=``)."""

    capture: CapturingTransport | None = None

    def datagram_received(self, data: bytes, addr: Address) -> None:
        if self.capture is not None:
            self.capture.received(data, addr)
        super().datagram_received(data, addr)


async def connect(
    host: str,
    port: int,
    *,
    config: ConnectionConfig | None = None,
    local_addr: tuple[str, int] | None = None,
    timer: str = "auto",
    on_data: DataCallback | None = None,
    rng: random.Random | None = None,
    netem: NetemSpec | str | None = None,
    netem_seed: int | None = None,
    key: KeyInput | None = None,
    pcap: CaptureTarget | None = None,
) -> Endpoint:
    """Open a master connection to the slave at ``host``:``port`` and wait until it is accepted.

    Use it as ``async with await tdtp.aio.connect(host, port) as ep:``. Raises :class:`ConnectError`
    when the slave does not answer within ``config.open_timeout`` or refuses.

    ``key`` (a :class:`~tdtp.PresharedKey` or its secret bytes) opens a keyed session: every
    datagram authenticated, payloads encrypted unless ``config.encrypt`` is False. The slave must
    hold the same key.

    ``netem`` impairs everything this master sends, in tc-netem's language
    (``"delay 20ms 5ms loss 1%"``), emulated in-process (see :mod:`tdtp.aio.impairment`).

    ``pcap`` (a path, or a shared :class:`~tdtp.pcap.PcapWriter`) records every datagram the socket
    sends and receives, with UDP/IP headers, for Wireshark (``tools/wireshark/tdtp.lua``).
    """
    loop = asyncio.get_running_loop()
    infos = await loop.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    if not infos:
        raise ConnectError(f"cannot resolve {host!r}")
    family, _, _, _, remote = infos[0]
    capture = open_capture(pcap) if pcap is not None else None
    # Both loops want (host, port) here and resolve it again themselves; the core compares only
    # host and port, so an IPv6 peer's 4-tuple source address still matches ``remote``.
    try:
        transport, protocol = await loop.create_datagram_endpoint(
            _MasterProtocol if capture is None else _CapturingMasterProtocol,
            remote_addr=(str(remote[0]), int(remote[1])),
            local_addr=local_addr,
            family=family,
        )
    except BaseException:
        if capture is not None and capture[1]:
            capture[0].close()
        raise
    conn = Connection(config, role=Role.MASTER, rng=rng, key=key)
    socket_side: asyncio.DatagramTransport = transport
    if capture is not None:
        socket_side = CapturingTransport(transport, capture[0], owned=capture[1])
        assert isinstance(protocol, _CapturingMasterProtocol)
        protocol.capture = socket_side
    sender: asyncio.DatagramTransport | ImpairedTransport = socket_side
    if netem is not None:
        sender = ImpairedTransport(socket_side, netem, seed=netem_seed, timer=timer)

    def _close_transport(_: Endpoint) -> None:
        sender.close()  # an impaired one lets the datagrams inside its link out first

    endpoint = Endpoint(
        conn, sender, connected=True, timer=timer, on_data=on_data, on_closed=_close_transport
    )
    protocol.endpoint = endpoint
    conn.connect(remote, now=monotonic())
    endpoint._flush()
    try:
        await endpoint.wait_established()
    except EndpointClosedError as exc:
        sender.close()
        raise ConnectError(f"could not open a TDTP connection to {host}:{port}: {exc}") from exc
    except BaseException:
        await endpoint.close()
        raise
    return endpoint


@dataclass(slots=True)
class ServerStats:
    """What the listening socket saw outside any connection."""

    datagrams_unattached: int = 0
    """Datagrams from addresses without a connection that were not an OPEN."""
    peers_refused: int = 0
    """Admitted OPENs answered with REJECT ``BUSY``: ``max_peers`` connections were open, or the
    accept backlog was full."""
    peers_accepted: int = 0
    """Connections established (the master confirmed the session)."""
    admission: AdmissionStats = field(default_factory=AdmissionStats)
    """The front door: OPENs seen, cookies and rejects sent, drops by reason, bytes in and out."""


class _ServerProtocol(asyncio.DatagramProtocol):
    def __init__(self, server: Server) -> None:
        self.server = server

    def datagram_received(self, data: bytes, addr: Address) -> None:
        self.server._datagram_received(data, addr)

    def error_received(self, exc: Exception) -> None:
        pass  # an ICMP error about one master says nothing about the others


class _CapturingServerProtocol(_ServerProtocol):
    """Records each datagram into the pcap capture first (used only with ``pcap=``)."""

    capture: CapturingTransport | None = None

    def datagram_received(self, data: bytes, addr: Address) -> None:
        if self.capture is not None:
            self.capture.received(data, addr)
        super().datagram_received(data, addr)


class Server:
    """A slave's listening socket. Iterate it (``async for endpoint in server``) or call
    :meth:`accept` to get an endpoint for each master that connects.

    Every OPEN goes through one shared :class:`~tdtp.admission.Admission`: no state is kept for a
    master until it proves it receives at its address (a cookie) and, on a keyed server, holds a key
    of the ring. A validated master finds the server full (``max_peers`` connections, or ``backlog``
    established ones nobody accepted yet) is refused at once with REJECT ``BUSY``.
    """

    def __init__(
        self,
        *,
        config: ConnectionConfig | None,
        max_peers: int,
        backlog: int,
        timer: str,
        on_data: DataCallback | None,
        keys: KeyRing | None,
    ) -> None:
        if max_peers < 1:
            raise ValueError(f"max_peers must be at least 1, got {max_peers}")
        if backlog < 1:
            raise ValueError(f"backlog must be at least 1, got {backlog}")
        self._config = config
        self._max_peers = max_peers
        self._backlog = backlog
        self._timer = timer
        self._on_data = on_data
        self._admission = Admission(config, keys)
        self._transport: asyncio.DatagramTransport | None = None
        self._sender: asyncio.DatagramTransport | ImpairedTransport | None = None
        self._peers: dict[tuple[object, object], Endpoint] = {}
        self._pending: deque[Endpoint] = deque()
        """Endpoints of admitted masters nobody has accepted yet, opening or established."""
        self._waiter: asyncio.Future[None] | None = None
        self._closed = False
        self.stats = ServerStats(admission=self._admission.stats)

    @property
    def sockname(self) -> Address:
        """The bound address, e.g. to learn the port after ``listen(port=0)``."""
        if self._transport is None:
            raise RuntimeError("the server is not bound")
        sockname: Address = self._transport.get_extra_info("sockname")
        return sockname

    @property
    def port(self) -> int:
        return int(self.sockname[1])

    @property
    def keyed(self) -> bool:
        """Whether this server accepts keyed sessions only."""
        return self._admission.keys is not None

    @property
    def endpoints(self) -> list[Endpoint]:
        """The masters connected (or connecting) now."""
        return list(self._peers.values())

    async def accept(self) -> Endpoint:
        """The next master's endpoint, once its connection is established."""
        loop = asyncio.get_running_loop()
        while True:
            endpoint = self._next_established()
            if endpoint is not None:
                return endpoint
            if self._closed:
                raise ConnectionError("the server is closed")
            waiter = loop.create_future()
            self._waiter = waiter
            try:
                await waiter
            finally:
                self._waiter = None

    def _next_established(self) -> Endpoint | None:
        pending = self._pending
        for endpoint in pending:
            if endpoint.established:
                pending.remove(endpoint)
                return endpoint
        return None

    def __aiter__(self) -> AsyncIterator[Endpoint]:
        return self._iterate()

    async def _iterate(self) -> AsyncIterator[Endpoint]:
        while True:
            try:
                yield await self.accept()
            except ConnectionError:
                return

    async def close(self) -> None:
        """Close every connection (each peer gets a CLOSE) and the socket. Idempotent."""
        if self._closed:
            return
        self._closed = True
        for endpoint in list(self._peers.values()):
            await endpoint.close()
        if self._sender is not None:
            self._sender.close()
        self._wake()

    async def __aenter__(self) -> Server:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    # ------------------------------------------------------------------ internals

    def _wake(self) -> None:
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _datagram_received(self, data: bytes, addr: Address) -> None:
        key = _peer_key(addr)
        endpoint = self._peers.get(key)
        if endpoint is not None:
            endpoint.datagram_received(data, addr)
            if key in self._peers or not _is_open(data):
                return
            # The connection ended on this OPEN: its master restarted and opens anew.
        if self._closed:
            return
        # Only an OPEN may lead to state, and only once admitted: anything else costs nothing.
        if not _is_open(data):
            self.stats.datagrams_unattached += 1
            return
        assert self._sender is not None
        now = monotonic()
        verdict = self._admission.admit(data, addr, now)
        if isinstance(verdict, Reply):
            self._sender.sendto(verdict.datagram, addr)
        elif isinstance(verdict, AdmittedOpen):
            self._open(verdict, key, addr, now)

    def _open(
        self, admitted: AdmittedOpen, key: tuple[object, object], addr: Address, now: float
    ) -> None:
        assert self._sender is not None
        if len(self._peers) >= self._max_peers or (
            self._on_data is None and len(self._pending) >= self._backlog
        ):
            self.stats.peers_refused += 1
            self._sender.sendto(self._admission.reject(admitted, CloseReason.BUSY), addr)
            return
        conn = Connection(self._config, role=Role.SLAVE, admission=self._admission)
        endpoint = Endpoint(
            conn,
            self._sender,
            connected=False,
            timer=self._timer,
            on_data=self._on_data,
            on_closed=self._forget,
            on_established=self._on_established,
        )
        self._peers[key] = endpoint
        pending = self._pending
        if len(pending) >= self._backlog:
            # Callback style (on_data): the session is served either way; accept() sees the
            # newest ``backlog`` ones.
            pending.popleft()
        pending.append(endpoint)
        conn.accept_open(admitted, addr, now=now)
        endpoint._flush(now)

    def _on_established(self, endpoint: Endpoint) -> None:
        self.stats.peers_accepted += 1
        self._wake()

    def _forget(self, endpoint: Endpoint) -> None:
        peer = endpoint.peer
        if peer is not None and self._peers.get(_peer_key(peer)) is endpoint:
            del self._peers[_peer_key(peer)]
        if endpoint in self._pending:
            self._pending.remove(endpoint)


def _is_open(data: bytes) -> bool:
    return len(data) > HEADER_SIZE and data[0] & 0xC0 == _CONTROL_TYPE_BITS and data[5] == _OPEN


async def listen(
    host: str | None = "127.0.0.1",
    port: int = 0,
    *,
    config: ConnectionConfig | None = None,
    max_peers: int = 256,
    backlog: int = 16,
    timer: str = "auto",
    on_data: DataCallback | None = None,
    netem: NetemSpec | str | None = None,
    netem_seed: int | None = None,
    key: KeyInput | None = None,
    keys: KeysInput | None = None,
    pcap: CaptureTarget | None = None,
) -> Server:
    """Bind a slave's UDP socket. ``port=0`` picks a free port (see :attr:`Server.port`).

    Use it as ``async with await tdtp.aio.listen(host, port) as server: async for ep in server: ...``.
    At most ``max_peers`` masters are served at once, and at most ``backlog`` established ones wait
    for :meth:`Server.accept` (with ``on_data`` the sessions are served anyway and accept() sees the
    newest ``backlog``); a master beyond either is refused at once (REJECT ``BUSY``).

    ``key`` (one pre-shared key) or ``keys`` (a :class:`~tdtp.KeyRing`, several keys, or a mapping
    of master name to secret) makes the server keyed: it accepts only masters holding one of the
    keys, and every datagram of their sessions is authenticated. Without keys anyone who can reach
    the port can open a session.

    ``netem`` impairs everything the slave sends (all its masters share the one emulated link).

    ``pcap`` (a path, or a shared :class:`~tdtp.pcap.PcapWriter`) records every datagram the
    socket sends and receives, every master's and the strangers' alike, until the server closes.
    """
    if key is not None and keys is not None:
        raise InvalidKeyError("pass key= (one key) or keys= (several), not both")
    chosen = keys if keys is not None else key
    ring = as_key_ring(chosen) if chosen is not None else None
    loop = asyncio.get_running_loop()
    server = Server(
        config=config,
        max_peers=max_peers,
        backlog=backlog,
        timer=timer,
        on_data=on_data,
        keys=ring,
    )
    family = socket.AF_INET6 if host is not None and ":" in host else socket.AF_UNSPEC
    capture = open_capture(pcap) if pcap is not None else None
    protocol_class = _ServerProtocol if capture is None else _CapturingServerProtocol
    try:
        transport, protocol = await loop.create_datagram_endpoint(
            lambda: protocol_class(server), local_addr=(host or "0.0.0.0", port), family=family
        )
    except BaseException:
        if capture is not None and capture[1]:
            capture[0].close()
        raise
    server._transport = transport
    socket_side: asyncio.DatagramTransport = transport
    if capture is not None:
        socket_side = CapturingTransport(transport, capture[0], owned=capture[1])
        assert isinstance(protocol, _CapturingServerProtocol)
        protocol.capture = socket_side
    server._sender = (
        socket_side
        if netem is None
        else ImpairedTransport(socket_side, netem, seed=netem_seed, timer=timer)
    )
    return server
