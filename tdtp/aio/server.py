"""A slave's listening socket: :func:`listen` binds it, :class:`Server` serves every master on it.

One UDP socket for any number of masters, up to ``max_peers``: an OPEN from an unknown address goes
through the shared :class:`~tdtp.admission.Admission` (cookie, rate limit, keys) before any state
exists, and each admitted master gets an :class:`~tdtp.aio.endpoint.Endpoint`, found again by its
address for every datagram that follows. On the batched datagram layer the server takes each
``recvmmsg`` batch in one call (:class:`~tdtp.aio.demultiplexer.Demultiplexer`): one clock read, each datagram handed
to its session's core, then one flush per session touched and one ``sendmmsg`` for all of them.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import sys
from collections import deque
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

from tdtp.admission.admission import Admission, AdmissionStats, AdmittedOpen, Reply
from tdtp.admission.path_migration import MigrationStats
from tdtp.admission.rate_limit import TokenBucket
from tdtp.admission.slots import EvictionNotices, SessionSlots, SlotStats, Verdict
from tdtp.aio.capture import CaptureTarget, CapturingTransport, open_capture
from tdtp.aio.datagram_transport import BatchedDatagramTransport, datagram_endpoint
from tdtp.aio.demultiplexer import Demultiplexer, is_open
from tdtp.aio.endpoint import (
    DataCallback,
    Endpoint,
    WatchdogCallback,
    format_address,
)
from tdtp.aio.impairment import ImpairedTransport
from tdtp.aio.opening import (
    Opener,
    _check_common,
    _check_port,
    _deliver_to,
    _limit_write_buffer,
    _peer_key,
    _released,
    address_error,
)
from tdtp.aio.outbox import SocketOutbox
from tdtp.aio.timer import TimerPreference, monotonic
from tdtp.aio.traversal import Traversal, is_rendezvous, local_candidates, move_session
from tdtp.config import ConnectionConfig, Role
from tdtp.errors import (
    ArgumentTypeError,
    ConnectionStateError,
    InvalidArgumentError,
    InvalidKeyError,
    ServerClosedError,
)
from tdtp.netem import NetemSpec
from tdtp.protection.keys import KeyInput, KeyRing, KeysInput, as_key_ring
from tdtp.rendezvous.client import PathChange, RendezvousClient
from tdtp.rendezvous.settings import Meeting, Rendezvous, meeting
from tdtp.session.connection import Connection
from tdtp.session.events import Address
from tdtp.wire.control import NONCE_SIZE, CloseReason, ControlCode, OpenFlags
from tdtp.wire.header import HEADER_SIZE, PacketType

_MP_CHALLENGE_BITS = int(PacketType.CONTROL) << 6


def is_path_challenge(data: bytes) -> bool:
    """Whether a datagram is an MP_CHALLENGE (a multipath master opening a path), by its prefix."""
    return (
        len(data) >= HEADER_SIZE + 1 + NONCE_SIZE
        and data[0] & 0xC0 == _MP_CHALLENGE_BITS
        and data[HEADER_SIZE] == ControlCode.MP_CHALLENGE
    )


__all__ = ["Server", "ServerStats", "listen"]


logger = logging.getLogger("tdtp")


@dataclass(slots=True)
class ServerStats:
    """What the listening socket saw outside any connection."""

    datagrams_unattached: int = 0
    """Datagrams from addresses without a connection that were not an OPEN (the session datagrams
    among them were answered with a RESET when big enough and within budget: ``admission``)."""
    peers_refused: int = 0
    """Admitted OPENs answered with REJECT ``BUSY``: ``max_peers`` connections were open, or the
    accept backlog was full."""
    peers_accepted: int = 0
    """Connections established (the master confirmed the session)."""
    peers_evicted: int = 0
    """Sessions closed (``EVICTED``) to make room for a new master: each one's master was gone
    (silent for ``reclaim_after``), or was the same master (same key) opening again from another
    address (PROTOCOL.md 5.1, rule 2.7)."""
    eviction_notices: int = 0
    """CLOSE ``EVICTED`` repeated to an evicted master's later datagrams (it was away when the
    first one left), and CLOSE ``TAKEN_OVER`` to a displaced master's (PROTOCOL.md 5.9)."""
    peers_in_use: int = 0
    """Exclusive server: admitted OPENs answered with REJECT ``IN_USE`` (another master commands)."""
    takeovers: int = 0
    """Exclusive server: sessions ended because another master took control."""
    admission: AdmissionStats = field(default_factory=AdmissionStats)
    """The front door: OPENs seen, cookies and rejects sent, drops by reason, bytes in and out."""
    slots: SlotStats = field(default_factory=SlotStats)
    """The slot policy: sessions reclaimed, OPENs refused because every master was live or their
    source held its share of ``max_peers`` (:mod:`tdtp.admission.slots`)."""
    migration: MigrationStats = field(default_factory=MigrationStats)
    """Path migration: datagrams from unknown addresses, trials, challenges, sessions moved."""
    path_challenges: int = 0
    """Multipath: MP_CHALLENGEs from addresses no session holds (a master opening a path)."""
    paths_learned: int = 0
    """Of those, the ones a session took: its master's new address joined the session."""
    path_challenges_unclaimed: int = 0
    """Of those, the ones no multipath session's nonce matched, or over ``path_budget`` per
    second (dropped, unanswered)."""


class _ServerProtocol(asyncio.DatagramProtocol):
    def __init__(self, server: Server) -> None:
        self.server = server
        self.closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def datagram_received(self, data: bytes, addr: Address) -> None:
        self.server._datagram_received(data, addr)

    def error_received(self, exc: Exception) -> None:
        pass  # an ICMP error about one master says nothing about the others

    def pause_writing(self) -> None:
        # One socket for every master: while it is backed up, every endpoint holds its data.
        for endpoint in self.server.endpoints:
            endpoint.pause_writing()

    def resume_writing(self) -> None:
        for endpoint in self.server.endpoints:
            endpoint.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.closed.done():
            self.closed.set_result(None)


class Server:
    """A slave's listening socket. Iterate it (``async for endpoint in server``) or call
    :meth:`accept` to get an endpoint for each master that connects.

    Every OPEN goes through one shared :class:`~tdtp.admission.Admission`: no state is kept for a
    master until it proves it receives at its address (a cookie) and, on a keyed server, holds a key
    of the ring. A validated master that finds the server full (``max_peers`` connections, or
    ``backlog`` established ones nobody accepted yet) is refused at once with REJECT ``BUSY``,
    unless a session's master is gone (:mod:`tdtp.admission.slots`); one source holds at most its
    share of the slots.
    """

    def __init__(
        self,
        *,
        config: ConnectionConfig | None,
        max_peers: int,
        timer: TimerPreference,
        on_data: DataCallback | None,
        on_watchdog: WatchdogCallback | None = None,
        backlog: int = 16,
        keys: KeyRing | None = None,
        exclusive: bool = False,
        takeover_after: int = 3,
        role: Role = Role.SLAVE,
    ) -> None:
        if not isinstance(role, Role):
            raise ArgumentTypeError(
                f"role must be tdtp.Role.SLAVE or tdtp.Role.MASTER, got {role!r}"
            )
        self.role = role
        """What this listening end is: a slave (robot) that masters dial, by default, or a master
        (operator) that its slaves dial."""
        if isinstance(max_peers, bool) or not isinstance(max_peers, int) or max_peers < 1:
            raise InvalidArgumentError(f"max_peers must be an integer >= 1, got {max_peers!r}")
        if not isinstance(exclusive, bool):
            raise ArgumentTypeError(f"exclusive must be True or False, got {exclusive!r}")
        if (
            isinstance(takeover_after, bool)
            or not isinstance(takeover_after, int)
            or not 1 <= takeover_after <= 1000
        ):
            raise InvalidArgumentError(
                f"takeover_after must be an integer from 1 to 1000 (watchdog periods), got "
                f"{takeover_after!r}"
            )
        self._exclusive = exclusive
        self._takeover_after = takeover_after
        if isinstance(backlog, bool) or not isinstance(backlog, int) or backlog < 1:
            raise InvalidArgumentError(f"backlog must be an integer >= 1, got {backlog!r}")
        self._config = config
        self._max_peers = max_peers
        self._backlog = backlog
        self._timer = timer
        self._on_data = on_data
        self._on_watchdog = on_watchdog
        self._admission = Admission(config, keys, role=role)
        policy = self._admission.config
        self._slots = SessionSlots(policy, max_peers)
        self._notices = EvictionNotices(max_peers, policy.idle_timeout, policy.silence_timeout)
        self._protocol: _ServerProtocol | None = None
        self._transport: asyncio.DatagramTransport | None = None
        self._sender: asyncio.DatagramTransport | ImpairedTransport | None = None
        self._outbox: SocketOutbox | None = None
        """The socket's outbox on the batched layer (nothing between the endpoints and it)."""
        self._peers: dict[tuple[object, object], Endpoint] = {}
        """Every address a session holds: its master's, and (multipath) each of its paths'."""
        self._sessions: dict[Endpoint, None] = {}
        """The sessions, each once (in the order they opened)."""
        self._path_budget = TokenBucket(
            self._admission.config.admission.migration_trials_per_second,
            self._admission.config.admission.migration_trials_per_second / 10.0,
        )
        """MP_CHALLENGEs from unknown addresses looked at per second (each may cost an AEAD check)."""
        self._pending: deque[Endpoint] = deque()
        """Endpoints of admitted masters nobody has accepted yet, opening or established."""
        self._waiters: list[asyncio.Future[None]] = []
        """Tasks waiting in accept(): each one looks again when a master is established."""
        self._closed = False
        self._traversal: Traversal | None = None
        """Through a rendezvous (``listen(rendezvous=...)``): the client that meets the dialer."""
        self._rendezvous_endpoint: Endpoint | None = None
        """The session that came through the rendezvous (its paths are the client's)."""
        self.stats = ServerStats(
            admission=self._admission.stats,
            migration=self._admission.paths.stats,
            slots=self._slots.stats,
        )

    @property
    def sockname(self) -> Address:
        """The bound address, e.g. to learn the port after ``listen(port=0)``."""
        if self._transport is None:
            raise ConnectionStateError("the server is not bound; create it with tdtp.listen()")
        sockname: Address = self._transport.get_extra_info("sockname")
        return sockname

    @property
    def port(self) -> int:
        """The UDP port the server listens on (the one the system chose for ``port=0``)."""
        return int(self.sockname[1])

    @property
    def keyed(self) -> bool:
        """Whether this server accepts keyed sessions only."""
        return self._admission.keys is not None

    @property
    def rendezvous(self) -> Traversal | None:
        """Listening through a rendezvous: its path, candidates tried (``.report()``); else None."""
        return self._traversal

    @property
    def endpoints(self) -> list[Endpoint]:
        """The masters connected (or connecting) now."""
        return list(self._sessions)

    async def accept(self) -> Endpoint:
        """The next master's endpoint, once its connection is established."""
        loop = asyncio.get_running_loop()
        while True:
            endpoint = self._next_established()
            if endpoint is not None:
                return endpoint
            if self._closed:
                raise ServerClosedError("the server is closed; no more masters are accepted")
            waiter: asyncio.Future[None] = loop.create_future()
            self._waiters.append(waiter)
            try:
                await waiter
            finally:
                if waiter in self._waiters:
                    self._waiters.remove(waiter)

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
            except ServerClosedError:
                return

    async def close(self, *, restarting: bool = False) -> None:
        """Close every connection (each peer gets a CLOSE) and the socket, and return once the port
        is free (an emulated link first lets its last datagrams out). Idempotent.

        ``restarting=True``: the slave stops but will be back soon (a service restart); the CLOSE
        says ``RESTARTING`` and reconnecting masters reopen at once (PROTOCOL.md 5.2). Otherwise
        it says ``NORMAL``: the sessions are over for good, and masters do not reopen."""
        if not isinstance(restarting, bool):
            raise ArgumentTypeError(f"restarting must be True or False, got {restarting!r}")
        if not self._closed:
            self._closed = True
            if self._traversal is not None:
                self._traversal.close()
            for endpoint in list(self._sessions):
                await endpoint.close(restarting=restarting)
            if self._sender is not None:
                self._sender.close()
            self._wake()
            logger.info("tdtp slave: stopped listening on %s", self._where())
        if self._protocol is not None and self._transport is not None:
            await _released(self._protocol.closed, self._transport)

    def __repr__(self) -> str:
        state = "closed" if self._closed else "listening"
        keyed = " keyed" if self.keyed else ""
        return f"<Server {self._where()} {state}{keyed} masters={len(self._sessions)}/{self._max_peers}>"

    def _where(self) -> str:
        if self._transport is None:
            return "(unbound)"
        return format_address(self._transport.get_extra_info("sockname"))

    async def __aenter__(self) -> Server:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    # ------------------------------------------------------------------ internals

    def _wake(self) -> None:
        for waiter in self._waiters:
            if not waiter.done():
                waiter.set_result(None)
        self._waiters.clear()

    def _datagram_received(self, data: bytes, addr: Address) -> None:
        key = addr[:2]  # _peer_key(addr), inline: (host, port) of an IPv4 or IPv6 address
        endpoint = self._peers.get(key)
        if endpoint is not None:
            # endpoint.datagram_received(data, addr), inline: one Python call less per datagram
            now = monotonic()
            endpoint._conn.receive_datagram(data, addr, now=now)
            endpoint.flush(now)
            if key in self._peers or not is_open(data):
                return
            # The connection ended on this OPEN: its master restarted and opens anew.
        if self._closed:
            return
        traversal = self._traversal
        if traversal is not None and self._through_rendezvous(traversal, data, addr):
            return
        # Only an OPEN may lead to state, and only once admitted. Anything else may be a master
        # whose address changed (path migration, within a bounded budget) or, when no session
        # claims it, a master whose session died with a restart of ours: it gets a RESET.
        if not is_open(data):
            self.stats.datagrams_unattached += 1
            self._on_unattached(data, key, addr)
            return
        assert self._sender is not None
        now = monotonic()
        verdict = self._admission.admit(data, addr, now)
        if isinstance(verdict, Reply):
            self._sender.sendto(verdict.datagram, addr)
        elif isinstance(verdict, AdmittedOpen):
            self._open(verdict, key, addr, now)

    def _rendezvous_received(self, data: bytes, addr: Address) -> None:
        """The socket's receiver when listening through a rendezvous: the client's messages first,
        whatever address they come from (a session's too), then as usual."""
        traversal = self._traversal
        if traversal is not None and is_rendezvous(data):
            traversal.receive(data, addr)
            return
        self._datagram_received(data, addr)

    def _through_rendezvous(self, traversal: Traversal, data: bytes, addr: Address) -> bool:
        """A datagram of the rendezvous session from another of its paths (taken as from the path
        in use). False: it is not."""
        endpoint = self._rendezvous_endpoint
        if endpoint is None or endpoint.is_closed or is_open(data):
            return False
        if (str(addr[0]), int(addr[1])) not in traversal.client.accepted:
            return False
        peer = endpoint.peer
        assert peer is not None
        now = monotonic()
        endpoint.connection.receive_datagram(data, peer, now=now)
        endpoint.flush(now)
        return True

    def _move_rendezvous_session(self, change: PathChange) -> None:
        endpoint = self._rendezvous_endpoint
        if endpoint is None or endpoint.is_closed:
            return
        old = endpoint.peer
        move_session(endpoint, change)
        new = endpoint.peer
        if old is not None and new is not None and old != new:
            # Keyed by the path in use: the other path's datagrams come in through the rendezvous.
            if self._peers.get(_peer_key(old)) is endpoint:
                del self._peers[_peer_key(old)]
            self._peers[_peer_key(new)] = endpoint

    def _learn_path(self, data: bytes, key: tuple[object, object], addr: Address) -> bool:
        """An MP_CHALLENGE from an address no session holds: the master of a multipath session
        opening a path (PROTOCOL.md 5.11), found by the nonce in the clear. True when it was one."""
        if not is_path_challenge(data):
            return False
        stats = self.stats
        stats.path_challenges += 1
        now = monotonic()
        nonce = data[HEADER_SIZE + 1 : HEADER_SIZE + 1 + NONCE_SIZE]
        if self._path_budget.take(now):
            for endpoint in self._sessions:
                conn = endpoint.connection
                paths = conn.multipath
                if paths is None or conn.master_nonce != nonce:
                    continue
                conn.receive_datagram(data, addr, now=now)
                paths = conn.multipath
                if paths is not None and paths.has_path(0, addr):
                    self._peers[key] = endpoint
                    stats.paths_learned += 1
                endpoint.flush(now)
                return True
        stats.path_challenges_unclaimed += 1
        return True

    def _on_unattached(self, data: bytes, key: tuple[object, object], addr: Address) -> None:
        """A datagram from an address no session holds: a multipath session's new path, or a
        master that moved (PROTOCOL.md 5.8)?"""
        assert self._sender is not None
        if self._learn_path(data, key, addr):
            return
        now = monotonic()
        notices = self._notices
        if notices and notices.holds(key, now):
            # An evicted master back from its silence: it hears why (CLOSE EVICTED, when due),
            # not a RESET that would tell it the slave restarted.
            close = notices.answer(key, len(data), now)
            if close is not None:
                self.stats.eviction_notices += 1
                self._sender.sendto(close, addr)
            return
        peers = self._peers
        paths = self._admission.paths
        outcome = paths.on_unattached(
            data, addr, now, [endpoint.connection for endpoint in self._sessions]
        )
        if outcome is None:
            # Only a datagram no session may own gets a RESET (PROTOCOL.md 5.7): one that might be
            # the datagram of a master that moved does not (PathMigration.unclaimed).
            if paths.unclaimed:
                reset = self._admission.reset(data, now)
                if reset is not None:
                    self._sender.sendto(reset, addr)
            return
        if isinstance(outcome, bytes):
            self._sender.sendto(outcome, addr)  # a PATH_CHALLENGE
            return
        for old_key, endpoint in peers.items():
            if endpoint.connection is outcome:
                del peers[old_key]
                peers[key] = endpoint
                logger.info(
                    "tdtp slave: a master moved from %s:%s to %s",
                    old_key[0],
                    old_key[1],
                    format_address(addr),
                )
                endpoint.flush(now)
                return

    def _exclusive_refuses(self, admitted: AdmittedOpen, addr: Address, now: float) -> bool:
        """Exclusive server (PROTOCOL.md 5.9): the master commanding the slave keeps it unless it
        has been silent for ``takeover_after`` watchdog periods, or the new master is keyed and
        asks with TAKEOVER; then it is ended (``taken_over``). True: refused with REJECT IN_USE."""
        holders = [ep for ep in self._sessions if not ep.is_closed]
        if not holders:
            return False
        takeover = admitted.key is not None and bool(admitted.body.flags & OpenFlags.TAKEOVER)
        silence = self._takeover_after * self._admission.config.silence_timeout
        if not takeover and any(ep.connection.quiet_for(now) < silence for ep in holders):
            assert self._sender is not None
            self.stats.peers_in_use += 1
            self._sender.sendto(self._admission.reject(admitted, CloseReason.IN_USE), addr)
            logger.info("tdtp slave: refused %s (exclusive, in use)", format_address(addr))
            return True
        for endpoint in holders:
            self.stats.takeovers += 1
            logger.info(
                "tdtp slave: %s takes control from %s%s",
                format_address(addr),
                format_address(endpoint.peer),
                " (takeover flag)" if takeover else " (silent)",
            )
            close = endpoint.connection.close(now=now, taken_over=True)
            endpoint.flush(now)
            peer = endpoint.peer
            if close is not None and peer is not None:
                # Its datagrams still on their way get this CLOSE again, never a RESET (which
                # would say "restarted": PROTOCOL.md 5.9), as an evicted master's do.
                self._notices.add(_peer_key(peer), close, now)
        return False

    def _open(
        self, admitted: AdmittedOpen, key: tuple[object, object], addr: Address, now: float
    ) -> None:
        assert self._sender is not None
        if self._exclusive and self._exclusive_refuses(admitted, addr, now):
            return
        backlog_full = self._on_data is None and len(self._pending) >= self._backlog
        placement = (
            None
            if backlog_full
            else self._slots.place(
                admitted.key, addr, [ep.connection for ep in self._sessions], now
            )
        )
        if (
            placement is None
            or placement.verdict is Verdict.BUSY
            or placement.verdict is Verdict.SHARE
        ):
            self.stats.peers_refused += 1
            self._sender.sendto(self._admission.reject(admitted, CloseReason.BUSY), addr)
            logger.info(
                "tdtp slave: refused %s (busy: %d masters, %d waiting to be accepted%s)",
                format_address(addr),
                len(self._sessions),
                len(self._pending),
                "; its source holds its share"
                if placement is not None and placement.verdict is Verdict.SHARE
                else "",
            )
            return
        if placement.holder is not None:
            self._evict(placement.holder, placement.detail, now)
        self._notices.forget(key)
        conn = Connection(self._config, role=self.role, dials=False, admission=self._admission)
        endpoint = Endpoint(
            conn,
            self._sender,
            connected=False,
            timer=self._timer,
            on_data=self._on_data,
            on_watchdog=self._on_watchdog,
            on_closed=self._forget,
            on_established=self._on_established,
            outbox=self._outbox,
        )
        self._peers[key] = endpoint
        self._sessions[endpoint] = None
        traversal = self._traversal
        if traversal is not None and (str(addr[0]), int(addr[1])) in traversal.client.accepted:
            self._rendezvous_endpoint = endpoint
        pending = self._pending
        if len(pending) >= self._backlog:
            # Callback style (on_data): the session is served either way; accept() sees the
            # newest ``backlog`` ones.
            pending.popleft()
        pending.append(endpoint)
        conn.accept_open(admitted, addr, now=now)
        endpoint.flush(now)

    def _evict(self, holder: Connection, detail: str, now: float) -> None:
        """End the session the slot policy chose (its master is gone, or restarted elsewhere) and
        remember its CLOSE, to repeat it to that master's later datagrams."""
        found = next(((w, ep) for w, ep in self._peers.items() if ep.connection is holder), None)
        if found is None:  # pragma: no cover - the policy chooses among the sessions it was given
            return
        where, endpoint = found
        self.stats.peers_evicted += 1
        logger.info("tdtp slave: %s evicted: %s", format_address(endpoint.peer), detail)
        close = endpoint.evict(detail, now)
        if close is not None:
            self._notices.add(where, close, now)

    def _on_established(self, endpoint: Endpoint) -> None:
        self.stats.peers_accepted += 1
        if self._traversal is not None and endpoint is self._rendezvous_endpoint:
            peer = endpoint.peer
            assert peer is not None
            self._traversal.in_session(peer)
        self._wake()

    def _forget(self, endpoint: Endpoint) -> None:
        peer = endpoint.peer
        if peer is not None and self._peers.get(_peer_key(peer)) is endpoint:
            del self._peers[_peer_key(peer)]
        if endpoint.connection.multipath is not None:  # its paths' addresses too
            for key in [key for key, holder in self._peers.items() if holder is endpoint]:
                del self._peers[key]
        self._sessions.pop(endpoint, None)
        if endpoint in self._pending:
            self._pending.remove(endpoint)


def listen(
    host: str | None = "127.0.0.1",
    port: int = 0,
    *,
    config: ConnectionConfig | None = None,
    max_peers: int = 256,
    backlog: int = 16,
    timer: TimerPreference = "auto",
    on_data: DataCallback | None = None,
    on_watchdog: WatchdogCallback | None = None,
    netem: NetemSpec | str | None = None,
    netem_seed: int | None = None,
    key: KeyInput | None = None,
    keys: KeysInput | None = None,
    pcap: CaptureTarget | None = None,
    reuse_port: bool = False,
    exclusive: bool = False,
    takeover_after: int = 3,
    role: Role = Role.SLAVE,
    rendezvous: Rendezvous | None = None,
) -> Opener[Server]:
    """Bind a slave's UDP socket. ``port=0`` picks a free port (see :attr:`Server.port`).

    ``async with tdtp.listen(host, port) as server: async for ep in server: ...`` (or
    ``server = await tdtp.listen(...)``). Arguments are checked at once
    (:class:`~tdtp.InvalidArgumentError`); :class:`~tdtp.AddressError` says why the address cannot
    be bound (in use, not local, not resolvable).

    At most ``max_peers`` masters are served at once, and at most ``backlog`` established ones wait
    for :meth:`Server.accept` (with ``on_data`` the sessions are served anyway and accept() sees the
    newest ``backlog``); a master beyond either is refused at once (REJECT ``BUSY``), unless a
    session's master is gone (silent for ``config.admission.reclaim_after``, 10 s): its slot is
    given to the new master (docs/PROTOCOL.md 5.1, rule 2.7). One source holds at most
    ``config.admission.source_share`` of the slots. ``on_data`` and ``on_watchdog`` apply to every
    endpoint (see :func:`connect`).

    ``key`` (one pre-shared key) or ``keys`` (a :class:`~tdtp.KeyRing`, several keys, or a mapping
    of master name to secret) makes the server keyed: it accepts only masters holding one of the
    keys, and every datagram of their sessions is authenticated. Without keys anyone who can reach
    the port can open a session.

    ``netem`` impairs everything the slave sends (all its masters share the one emulated link).
    ``pcap`` (a path, or a shared :class:`~tdtp.capture.pcap.PcapWriter`) records every datagram the
    socket sends and receives, every master's and the strangers' alike, until the server closes.

    ``reuse_port=True`` (Linux, BSD) binds with ``SO_REUSEPORT``, so that several processes can
    each listen on the same port: the kernel hands a master's datagrams, by its address, always to
    the same one. A process per core, each with its own server, spreads the masters over every core
    (README, "Sessions at scale"). Every process must pass ``reuse_port=True``.

    ``exclusive=True``: at most one master commands the slave at a time (docs/PROTOCOL.md 5.9). A new
    master is refused (REJECT ``IN_USE``) unless the one in control has been silent for
    ``takeover_after`` watchdog periods (``silence_timeout`` each; 1 to 1000, default 3), or the new
    one is keyed and connects with ``ConnectionConfig(takeover=True)``: then the old session ends with
    the cause ``taken_over`` and the new master takes control.

    ``role=Role.MASTER`` makes this end the master (the operator's station) that its slaves dial
    (``tdtp.connect(..., role=Role.SLAVE)``): a robot behind a NAT reaches it without any port
    forward at its end. Admission, keys, ``max_peers`` and ``exclusive`` work as above with the
    roles swapped (an exclusive master takes one slave at a time).

    ``rendezvous=tdtp.Rendezvous(relay_host, relay_port)`` also waits for the dialer at a relay
    (``tdtp relay``), so that a peer behind a NAT reaches this end behind another: the session runs
    on a direct path when the two can punch one, else through the relay (docs/NAT.md). It meets one
    peer: keyed, give one key (the name is derived from it) or a name; unkeyed, a name. ``host``
    then defaults to every interface.
    """
    if host is not None and not isinstance(host, str):
        raise InvalidArgumentError(f"host must be an address, a host name or None, got {host!r}")
    if not isinstance(reuse_port, bool):
        raise ArgumentTypeError(f"reuse_port must be True or False, got {reuse_port!r}")
    if reuse_port and not hasattr(socket, "SO_REUSEPORT"):
        raise InvalidArgumentError(
            f"reuse_port=True needs SO_REUSEPORT, which {sys.platform} does not have; run one "
            "process per port instead"
        )
    _check_port(port, allow_zero=True)
    spec = _check_common(config, timer, on_data, on_watchdog, netem)
    if key is not None and keys is not None:
        raise InvalidKeyError("pass key= (one key) or keys= (several), not both")
    chosen = keys if keys is not None else key
    ring = as_key_ring(chosen) if chosen is not None else None
    met: Meeting | None = None
    if rendezvous is not None:
        if not isinstance(rendezvous, Rendezvous):
            raise ArgumentTypeError(
                f"rendezvous must be a tdtp.Rendezvous(host, port, ...), got {rendezvous!r}"
            )
        if netem is not None or pcap is not None:
            raise InvalidArgumentError("netem= and pcap= are not available with rendezvous=")
        if ring is not None and len(ring) != 1 and rendezvous.name is None:
            raise InvalidKeyError(
                "a rendezvous meets one peer: give the listener one key (the name is derived from "
                "it), or Rendezvous(..., name=...)"
            )
        met = meeting(next(iter(ring)) if ring is not None else None, rendezvous.name)
        if host == "127.0.0.1":
            host = None  # the default: the relay and the peer are elsewhere
    server = Server(
        config=config,
        max_peers=max_peers,
        timer=timer,
        on_data=on_data,
        on_watchdog=on_watchdog,
        backlog=backlog,
        keys=ring,
        exclusive=exclusive,
        takeover_after=takeover_after,
        role=role,
    )
    bound_host = host

    async def start() -> Server:
        opened = await _listen(server, bound_host, port, spec, netem_seed, timer, pcap, reuse_port)
        if rendezvous is not None and met is not None:
            await _meet(opened, rendezvous, met)
        return opened

    return Opener(start)


async def _meet(server: Server, settings: Rendezvous, met: Meeting) -> None:
    """Register the listening socket at the relay and start hole punching from it."""
    loop = asyncio.get_running_loop()
    try:
        infos = await loop.getaddrinfo(settings.host, settings.port, type=socket.SOCK_DGRAM)
    except OSError as exc:
        await server.close()
        raise address_error(exc, "reach the relay at", settings.host, settings.port) from exc
    remote = infos[0][4]
    relay_addr: Address = (str(remote[0]), int(remote[1]))
    sender = server._sender
    transport = server._transport
    protocol = server._protocol
    assert sender is not None and transport is not None and protocol is not None
    # Per datagram through the rendezvous's receiver (no batch demultiplexer): its messages can
    # come from a session's own address.
    if isinstance(transport, BatchedDatagramTransport):
        transport.batch_receiver = None
    _deliver_to(protocol, server._rendezvous_received, None)
    local = local_candidates(relay_addr, server.sockname)
    client = RendezvousClient(settings, met, listener=True, relay=relay_addr, local=local)
    traversal = Traversal(client, sender.sendto, server._move_rendezvous_session)
    server._traversal = traversal
    traversal.start()
    logger.info(
        "tdtp %s: waiting at the rendezvous %s", server.role.value, format_address(relay_addr)
    )


async def _listen(
    server: Server,
    host: str | None,
    port: int,
    netem: NetemSpec | None,
    netem_seed: int | None,
    timer: TimerPreference,
    pcap: CaptureTarget | None,
    reuse_port: bool = False,
) -> Server:
    loop = asyncio.get_running_loop()
    family = socket.AF_INET6 if host is not None and ":" in host else socket.AF_UNSPEC
    capture = open_capture(pcap) if pcap is not None else None
    try:
        transport, protocol = await datagram_endpoint(
            loop,
            lambda: _ServerProtocol(server),
            local_addr=(host or "0.0.0.0", port),
            family=family,
            reuse_port=reuse_port or None,
        )
    except OSError as exc:
        if capture is not None and capture[1]:
            capture[0].close()
        raise address_error(exc, "listen on", host or "0.0.0.0", port) from exc
    except BaseException:
        if capture is not None and capture[1]:
            capture[0].close()
        raise
    _limit_write_buffer(transport)
    server._transport = transport
    server._protocol = protocol
    socket_side: asyncio.DatagramTransport = transport
    recorder: CapturingTransport | None = None
    if capture is not None:
        socket_side = recorder = CapturingTransport(transport, capture[0], owned=capture[1])
    _deliver_to(protocol, server._datagram_received, recorder)
    server._sender = (
        socket_side
        if netem is None
        else ImpairedTransport(socket_side, netem, seed=netem_seed, timer=timer)
    )
    if isinstance(transport, BatchedDatagramTransport) and recorder is None:
        if netem is None:
            server._outbox = transport.outbox
        transport.batch_receiver = Demultiplexer(
            server._peers, server._datagram_received, server._outbox
        )
    logger.info(
        "tdtp %s: listening on %s%s",
        server.role.value,
        server._where(),
        " (keyed)" if server.keyed else "",
    )
    return server
