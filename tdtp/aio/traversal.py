"""NAT traversal on real sockets: a :class:`~tdtp.rendezvous.client.RendezvousClient` driven on an
endpoint's (or a server's) socket, and the dialer's way of opening through a rendezvous
(``tdtp.connect(rendezvous=...)``, docs/NAT.md).

The client's datagrams (REGISTER to the relay, PROBEs and PROBE_ACKs between the pair) share the
session's socket, so the holes they punch are the session's. Datagrams arrive through a *front*:
rendezvous messages (codes 21..24) go to the client; a session datagram from another path of the
same peer (the relay, or a direct path the client validated) is handed to the connection as if it
came from the path in use, so both paths are taken while the session moves between them; the
client's :class:`~tdtp.rendezvous.client.PathChange` events move the session's sending
(:meth:`~tdtp.session.connection.Connection.use_path`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import socket
from collections.abc import Callable

from tdtp.aio.datagram_transport import datagram_endpoint
from tdtp.aio.endpoint import (
    DataCallback,
    Endpoint,
    EndpointClosedError,
    WatchdogCallback,
    format_address,
)
from tdtp.aio.opening import _limit_write_buffer, _released, address_error
from tdtp.aio.reconnect import ReconnectPolicy
from tdtp.aio.timer import TimerPreference, monotonic
from tdtp.config import ConnectionConfig, Role
from tdtp.errors import ConnectError
from tdtp.protection.keys import PresharedKey, as_key
from tdtp.rendezvous.client import PathChange, PathKind, RendezvousClient
from tdtp.rendezvous.settings import Rendezvous, meeting
from tdtp.session.connection import Connection
from tdtp.session.events import Address
from tdtp.session.state import State
from tdtp.wire.rendezvous import Candidate

__all__ = ["Traversal", "dial_via_rendezvous", "is_rendezvous", "local_candidates"]

logger = logging.getLogger("tdtp")

_CONTROL = 2


def is_rendezvous(data: bytes) -> bool:
    """A REGISTER, REFERRAL, PROBE or PROBE_ACK (code 21..24): the client's, never the session's."""
    return len(data) > 5 and data[0] >> 6 == _CONTROL and 21 <= data[5] <= 24


def local_candidates(relay: Address, bound: Address) -> tuple[Candidate, ...]:
    """Our own address on the network we reach the relay through (a peer on the same network
    reaches us there without going through the NATs), with the socket's port."""
    host = str(bound[0])
    if host not in ("0.0.0.0", "::", ""):
        return ((host, int(bound[1])),)
    family = socket.AF_INET6 if ":" in str(relay[0]) else socket.AF_INET
    try:
        with socket.socket(family, socket.SOCK_DGRAM) as probe:
            probe.connect((relay[0], relay[1]))  # no datagram leaves: only the route is looked up
            host = probe.getsockname()[0]
    except OSError:
        return ()
    return ((host, int(bound[1])),)


class Traversal:
    """Runs one rendezvous client on a socket: its timer, its sends, its path changes."""

    def __init__(
        self,
        client: RendezvousClient,
        send: Callable[[bytes, Address], object],
        on_change: Callable[[PathChange], None],
    ) -> None:
        self.client = client
        self._send = send
        self._on_change = on_change
        self._loop = asyncio.get_running_loop()
        self._handle: asyncio.TimerHandle | None = None
        self._closed = False
        self.chosen: asyncio.Future[Address] = self._loop.create_future()
        """A dialer's answer: where to send the OPEN (a direct path, or the relay)."""
        self.started_at = monotonic()

    def start(self) -> None:
        now = monotonic()
        self.started_at = now
        self.client.start(now)
        self._run(now)

    def receive(self, data: bytes, addr: Address) -> None:
        if self._closed:
            return
        now = monotonic()
        self.client.receive(data, addr, now)
        self._run(now)

    def in_session(self, addr: Address) -> None:
        now = monotonic()
        self.client.in_session(addr, now)
        self._run(now)

    def close(self) -> None:
        """Leave the rendezvous (the relay frees our registration at once) and stop."""
        if self._closed:
            return
        self._closed = True
        if self._handle is not None:
            self._handle.cancel()
        if self.client.registered:
            with contextlib.suppress(OSError):
                self._send(self.client.leave(), self.client.relay)
        if not self.chosen.done():
            self.chosen.cancel()

    def _on_timer(self) -> None:
        self._handle = None
        if self._closed:
            return
        now = monotonic()
        self.client.handle_timer(now)
        self._run(now)

    def _run(self, now: float) -> None:
        client = self.client
        for datagram, addr in client.datagrams_to_send(now):
            with contextlib.suppress(OSError):  # lost like any datagram; the client resends
                self._send(datagram, addr)
        while client.events:
            self._on_change(client.events.popleft())
        if not self.chosen.done() and not client.listener:
            choice = client.choice(now)
            if choice is not None:
                self.chosen.set_result(choice)
        if self._handle is not None:
            self._handle.cancel()
        deadline = client.get_timer()
        self._handle = self._loop.call_later(max(0.0, deadline - now), self._on_timer)

    def report(self, first_sample_at: float | None = None) -> dict[str, object]:
        """The ``--json`` entry: path, candidates tried, times."""
        client = self.client
        stats = client.stats
        kind = client.path_kind()
        start = self.started_at

        def since(at: float | None) -> float | None:
            return None if at is None else round(at - start, 4)

        return {
            "started_at": round(start, 6),  # monotonic(): compare runs on one host
            "relay": format_address(client.relay),
            "path": None if kind is None else kind.value,
            "reflexive": None if client.reflexive is None else format_address(client.reflexive),
            "peer": None if client.peer is None else format_address(client.peer),
            "candidates_tried": stats.candidates_tried,
            "direct_paths_validated": stats.direct_paths,
            "direct_paths_lost": stats.direct_lost,
            "peer_known_s": since(stats.peer_known_at),
            "direct_s": since(stats.direct_at),
            "first_sample_s": since(first_sample_at),
            "probes_sent": stats.probes_sent,
            "probes_answered": stats.probes_answered,
            "drops": dict(stats.drops),
        }


class _Front(asyncio.DatagramProtocol):
    """The dialer's socket: rendezvous messages to the client, the rest to the endpoint."""

    def __init__(self) -> None:
        self.endpoint: Endpoint | None = None
        self.traversal: Traversal | None = None
        self.closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def datagram_received(self, data: bytes, addr: Address) -> None:
        traversal = self.traversal
        if traversal is not None and is_rendezvous(data):
            traversal.receive(data, addr)
            return
        endpoint = self.endpoint
        if endpoint is None:
            return
        peer = endpoint.connection.peer
        if (
            traversal is not None
            and peer is not None
            and (addr[0] != peer[0] or addr[1] != peer[1])
            and (str(addr[0]), int(addr[1])) in traversal.client.accepted
        ):
            addr = peer  # another path of the same peer: taken as the path in use
        endpoint.datagram_received(data, addr)

    def error_received(self, exc: Exception) -> None:
        pass  # an unconnected socket: errors about candidates that do not answer mean nothing

    def pause_writing(self) -> None:
        if self.endpoint is not None:
            self.endpoint.pause_writing()

    def resume_writing(self) -> None:
        if self.endpoint is not None:
            self.endpoint.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.closed.done():
            self.closed.set_result(None)


def move_session(endpoint: Endpoint | None, change: PathChange) -> None:
    """Apply a path change to an established session (samples then leave on the new path)."""
    if endpoint is None or endpoint.connection.state is not State.ESTABLISHED:
        return
    conn = endpoint.connection
    peer = conn.peer
    if peer is not None and (peer[0], peer[1]) == (change.addr[0], change.addr[1]):
        return
    conn.use_path(change.addr)
    logger.info(
        "tdtp %s: session moves to the %s path %s",
        conn.role.value,
        change.kind.value,
        format_address(change.addr),
    )
    endpoint.flush()


async def dial_via_rendezvous(
    settings: Rendezvous,
    *,
    role: Role,
    config: ConnectionConfig | None,
    key: PresharedKey | bytes | None,
    local_addr: tuple[str, int] | None,
    timer: TimerPreference,
    on_data: DataCallback | None,
    on_watchdog: WatchdogCallback | None,
    rng: random.Random | None,
    reconnect: ReconnectPolicy | None,
) -> Endpoint:
    """``tdtp.connect(rendezvous=...)``: register at the relay, wait for the peer, open the session
    on a direct path if one validates within ``direct_wait``, else through the relay."""
    loop = asyncio.get_running_loop()
    chosen_key = as_key(key) if key is not None else None
    met = meeting(chosen_key, settings.name)
    try:
        infos = await loop.getaddrinfo(settings.host, settings.port, type=socket.SOCK_DGRAM)
    except OSError as exc:
        raise address_error(exc, "reach the relay at", settings.host, settings.port) from exc
    family, _, _, _, remote = infos[0]
    relay_addr: Address = (str(remote[0]), int(remote[1]))
    bind = local_addr or (("::", 0) if family == socket.AF_INET6 else ("0.0.0.0", 0))
    try:
        transport, protocol = await datagram_endpoint(loop, _Front, local_addr=bind, family=family)
    except OSError as exc:
        raise address_error(exc, "bind", bind[0], bind[1]) from exc
    _limit_write_buffer(transport)
    local = local_candidates(relay_addr, transport.get_extra_info("sockname"))
    client = RendezvousClient(settings, met, listener=False, relay=relay_addr, local=local)

    def on_change(change: PathChange) -> None:
        move_session(protocol.endpoint, change)

    traversal = Traversal(client, transport.sendto, on_change)
    protocol.traversal = traversal

    def new_connection() -> Connection:
        return Connection(config, role=role, dials=True, rng=rng, key=chosen_key)

    def on_session(endpoint: Endpoint) -> None:
        peer = endpoint.connection.peer
        if peer is not None:
            traversal.in_session(peer)

    def reopen_to() -> Address:
        return client.choice(monotonic()) or client.relay

    def close_transport(_: Endpoint) -> None:
        traversal.close()
        transport.close()

    async def transport_closed() -> None:
        await _released(protocol.closed, transport)

    conn = new_connection()
    endpoint = Endpoint(
        conn,
        transport,
        connected=False,
        timer=timer,
        on_data=on_data,
        on_watchdog=on_watchdog,
        on_closed=close_transport,
        transport_closed=transport_closed,
        reconnect=reconnect,
        new_connection=new_connection,
        on_established=on_session,
        reopen_to=reopen_to,
    )
    endpoint.rendezvous = traversal
    traversal.start()
    where = f"the rendezvous at {format_address(relay_addr)}"
    try:
        choice = await asyncio.wait_for(asyncio.shield(traversal.chosen), settings.wait_for_peer)
    except TimeoutError:
        await endpoint.close()
        registered = "registered, but " if client.registered else "could not register: "
        raise ConnectError(
            f"could not open a TDTP connection through {where}: {registered}the peer did not "
            f"come within {settings.wait_for_peer:g} s (same relay, same name or key, the other "
            "role?)"
        ) from None
    except BaseException:
        await endpoint.close()
        raise
    protocol.endpoint = endpoint
    kind = PathKind.RELAYED if choice == relay_addr else PathKind.DIRECT
    logger.info(
        "tdtp %s: opening on the %s path %s", role.value, kind.value, format_address(choice)
    )
    conn.connect(choice, now=monotonic())
    endpoint.flush()
    try:
        await endpoint.wait_established()
    except EndpointClosedError as exc:
        await endpoint.close()
        raise ConnectError(f"could not open a TDTP connection through {where}: {exc}") from exc
    except BaseException:
        await endpoint.close()
        raise
    return endpoint
