"""The asyncio entry points: :func:`connect` for a master, :func:`listen` for a slave.

``connect`` gives one :class:`~tdtp.aio.endpoint.Endpoint` on its own connected UDP socket (the kernel
drops datagrams from anyone but the slave). ``listen`` (:mod:`tdtp.aio.server`) binds one UDP socket for
any number of masters, up to ``max_peers``, and hands out an endpoint for each master whose OPEN arrives.

Both check their arguments at once (a port of 70000 or ``timer="timefd"`` raises before anything is
bound) and return an :class:`~tdtp.aio.opening.Opener`: ``await`` it, or use it directly as
``async with``, as aioquic's and websockets' ``connect`` allow.
"""

from __future__ import annotations

import asyncio
import logging
import random
import socket
from collections.abc import Sequence

from tdtp.aio.capture import CaptureTarget, CapturingTransport, open_capture
from tdtp.aio.datagram_transport import BatchedDatagramTransport, datagram_endpoint
from tdtp.aio.endpoint import (
    DataCallback,
    Endpoint,
    WatchdogCallback,
    format_address,
)
from tdtp.aio.impairment import ImpairedTransport
from tdtp.aio.multipath import LocalAddress, check_path_netem, parse_local_address
from tdtp.aio.multipath_connect import connect_multipath, multipath_config
from tdtp.aio.opening import (
    Opener,
    _check_common,
    _check_port,
    _deliver_to,
    _limit_write_buffer,
    _released,
    address_error,
    established,
    refused_text,
)
from tdtp.aio.reconnect import ReconnectPolicy, as_policy
from tdtp.aio.server import Server, ServerStats, listen
from tdtp.aio.timer import TimerPreference, monotonic
from tdtp.aio.traversal import dial_via_rendezvous
from tdtp.config import ConnectionConfig, Role
from tdtp.errors import (
    ArgumentTypeError,
    ConnectError,
    InvalidArgumentError,
    PortUnreachableError,
)
from tdtp.netem import NetemSpec
from tdtp.protection.keys import OneKeyInput, PresharedKey, as_key
from tdtp.rendezvous.settings import Rendezvous, meeting
from tdtp.session.connection import Connection
from tdtp.session.events import Address
from tdtp.session.state import State

__all__ = [
    "ConnectError",
    "Opener",
    "Server",
    "ServerStats",
    "_limit_write_buffer",
    "address_error",
    "connect",
    "listen",
]

logger = logging.getLogger("tdtp")


class _DialerProtocol(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.endpoint: Endpoint | None = None
        self.where = ""
        self.peer_role = Role.SLAVE
        self.closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def datagram_received(self, data: bytes, addr: Address) -> None:
        endpoint = self.endpoint
        if endpoint is not None:
            endpoint.datagram_received(data, addr)

    def error_received(self, exc: Exception) -> None:
        endpoint = self.endpoint
        if endpoint is None:
            return
        if isinstance(exc, ConnectionRefusedError) and endpoint.connection.state is State.OPENING:
            endpoint.fail_open(PortUnreachableError(refused_text(self.where, self.peer_role)))
            return
        # Once established, an ICMP error alone does not end the session (a slave restarting, a
        # route flapping): the watchdog and the outage limit decide.
        endpoint.send_errors += 1

    def pause_writing(self) -> None:
        if self.endpoint is not None:
            self.endpoint.pause_writing()

    def resume_writing(self) -> None:
        if self.endpoint is not None:
            self.endpoint.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.closed.done():
            self.closed.set_result(None)


def connect(
    host: str | None = None,
    port: int | None = None,
    *,
    rendezvous: Rendezvous | None = None,
    role: Role = Role.MASTER,
    config: ConnectionConfig | None = None,
    local_addr: tuple[str, int] | None = None,
    timer: TimerPreference = "auto",
    on_data: DataCallback | None = None,
    on_watchdog: WatchdogCallback | None = None,
    rng: random.Random | None = None,
    netem: NetemSpec | str | None = None,
    netem_seed: int | None = None,
    key: OneKeyInput | None = None,
    pcap: CaptureTarget | None = None,
    reconnect: bool | ReconnectPolicy | None = False,
    local_addresses: Sequence[str | tuple[str, int] | LocalAddress] | None = None,
    path_netem: Sequence[NetemSpec | str | None] | None = None,
) -> Opener[Endpoint]:
    """Dial the peer listening at ``host``:``port`` and wait until it accepts the session.

    ``async with tdtp.connect(host, port) as ep:`` (or ``ep = await tdtp.connect(host, port)``).
    By default this end is the master and dials a slave (``tdtp.listen``). ``role=Role.SLAVE``
    makes it a slave (a robot) that dials its master (``tdtp.listen(role=Role.MASTER)``): the way
    to reach a robot behind a NAT or firewall that takes no incoming datagrams. Either way the
    listening side validates the dialer's address, checks its key and may be exclusive exactly
    as a listening slave does; a listener of the same role refuses with ``role_conflict``.
    Arguments are checked at once (:class:`~tdtp.InvalidArgumentError`). Raises
    :class:`~tdtp.AddressError` when ``host`` cannot be resolved, :class:`~tdtp.PortUnreachableError`
    as soon as the slave's host reports that nothing listens on ``port``, and
    :class:`~tdtp.ConnectError` when the slave does not answer within ``config.open_timeout`` or
    refuses.

    ``on_data`` receives every sample as it arrives (instead of the reads), ``on_watchdog`` every
    :class:`~tdtp.PeerSilent` / :class:`~tdtp.PeerResumed`. ``netem`` impairs everything this master
    sends, in tc-netem's language (``"delay 20ms 5ms loss 1%"``), emulated in-process (see
    :mod:`tdtp.aio.impairment`).

    ``key`` (a :class:`~tdtp.PresharedKey`, its secret bytes, or ``tdtp.load_key(path)``: a key
    file's first key, or ``load_key(path, name=...)``) opens a keyed session: every datagram
    authenticated, payloads encrypted unless ``config.encrypt`` is False. The slave must hold the
    same key. A collection of exactly one key (``tdtp.load_keys(path)`` of a one-key file) is
    taken as that key; one of several raises :class:`~tdtp.InvalidKeyError` saying how to choose.

    ``pcap`` (a path, or a shared :class:`~tdtp.capture.pcap.PcapWriter`) records every datagram the socket
    sends and receives, with UDP/IP headers, for Wireshark (``tools/wireshark/tdtp.lua``).

    ``reconnect=True`` (or a :class:`~tdtp.ReconnectPolicy`) keeps the endpoint alive across
    sessions: when the slave restarts (a verified RESET), the session idles out, or the slave is
    silent for ``after_silence``, a new session opens on the same socket and the application's
    loops go on; ``ep.reconnects`` says how often and why (:mod:`tdtp.aio.reconnect`). The first
    open still raises as above.

    ``local_addresses`` opens a **multipath** session (docs/PROTOCOL.md 5.11): one socket per
    entry (``"10.0.1.1"``, ``"10.0.1.1:7001"``, an interface ``"%wwan0"``, each optionally
    ``"=HOST:PORT"`` for a remote end other than ``host:port``); the session opens on the first and
    a path from each other one joins once the slave has answered on it. Every sample then goes on
    every working path (``MultipathConfig(scheduler="adaptive")``: on the best one while it
    behaves), the first copy wins, and the session rides out any path's failure. ``ep.paths`` has
    each path's figures and events. ``path_netem`` (one per local address) impairs each path both
    ways in-process (``netem`` is then not allowed).

    ``rendezvous=tdtp.Rendezvous(relay_host, relay_port)`` (instead of ``host`` and ``port``) meets
    a peer that listens with the same rendezvous (``tdtp.listen(rendezvous=...)``) through a relay
    (``tdtp relay``): both may sit behind NATs. The session opens on a direct path when one works
    within ``direct_wait``, else through the relay, and moves between them as they come and go
    (``ep.rendezvous.report()``; docs/NAT.md). A keyed pair meets under a name derived from its
    key; an unkeyed one gives ``Rendezvous(..., name=...)``. Not with ``netem`` or ``pcap``.
    """
    policy = as_policy(reconnect)
    if not isinstance(role, Role):
        raise ArgumentTypeError(f"role must be tdtp.Role.MASTER or tdtp.Role.SLAVE, got {role!r}")
    if rendezvous is not None:
        if local_addresses is not None or path_netem is not None:
            raise InvalidArgumentError(
                "rendezvous= meets the peer on one socket: not with local_addresses or path_netem"
            )
        return _connect_rendezvous(
            host, port, rendezvous, role, config, local_addr, timer, on_data, on_watchdog, rng,
            netem, key, pcap, policy,
        )  # fmt: skip
    if not isinstance(host, str) or not host:
        raise InvalidArgumentError(f"host must be a host name or address, got {host!r}")
    port = _check_port(port, allow_zero=False)
    _check_local(local_addr)
    spec = _check_common(config, timer, on_data, on_watchdog, netem)
    dialer_key = as_key(key) if key is not None else None  # checked now, as the rest
    if local_addresses is not None or path_netem is not None:
        if isinstance(local_addresses, str) or not local_addresses:
            raise InvalidArgumentError(
                "local_addresses must be a non-empty list of local addresses, e.g. "
                "['10.0.1.1', '10.0.2.1'] (a string is one address: put it in a list)"
            )
        locals_ = [parse_local_address(entry) for entry in local_addresses]
        if local_addr is not None or netem is not None or pcap is not None:
            raise InvalidArgumentError(
                "with local_addresses, give the first path's address as its first entry (not "
                "local_addr), impair paths with path_netem (not netem); pcap is not supported"
            )
        specs = check_path_netem(path_netem, len(locals_))
        chosen = multipath_config(config)
        return Opener(
            lambda: connect_multipath(
                host,
                port,
                locals_,
                config=chosen,
                timer=timer,
                on_data=on_data,
                on_watchdog=on_watchdog,
                rng=rng,
                path_netem=specs,
                netem_seed=netem_seed,
                key=dialer_key,
                reconnect=policy,
            )
        )
    return Opener(
        lambda: _connect(
            host,
            port,
            role=role,
            config=config,
            local_addr=local_addr,
            timer=timer,
            on_data=on_data,
            on_watchdog=on_watchdog,
            rng=rng,
            netem=spec,
            netem_seed=netem_seed,
            key=dialer_key,
            pcap=pcap,
            reconnect=policy,
        )
    )


async def _connect(
    host: str,
    port: int,
    *,
    role: Role,
    config: ConnectionConfig | None,
    local_addr: tuple[str, int] | None,
    timer: TimerPreference,
    on_data: DataCallback | None,
    on_watchdog: WatchdogCallback | None,
    rng: random.Random | None,
    netem: NetemSpec | None,
    netem_seed: int | None,
    key: PresharedKey | None,
    pcap: CaptureTarget | None,
    reconnect: ReconnectPolicy | None = None,
) -> Endpoint:
    loop = asyncio.get_running_loop()
    try:
        infos = await loop.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    except OSError as exc:
        raise address_error(exc, "connect to", host, port) from exc
    family, _, _, _, remote = infos[0]
    conn = Connection(config, role=role, dials=True, rng=rng, key=key)
    capture = open_capture(pcap) if pcap is not None else None
    # Both loops want (host, port) here and resolve it again themselves; the core compares only
    # host and port, so an IPv6 peer's 4-tuple source address still matches ``remote``.
    try:
        transport, protocol = await datagram_endpoint(
            loop,
            _DialerProtocol,
            remote_addr=(str(remote[0]), int(remote[1])),
            local_addr=local_addr,
            family=family,
        )
    except OSError as exc:
        if capture is not None and capture[1]:
            capture[0].close()
        raise address_error(exc, "connect to", host, port) from exc
    except BaseException:
        if capture is not None and capture[1]:
            capture[0].close()
        raise
    _limit_write_buffer(transport)
    protocol.where = format_address((host, port))
    protocol.peer_role = Role.SLAVE if role is Role.MASTER else Role.MASTER
    socket_side: asyncio.DatagramTransport = transport
    recorder: CapturingTransport | None = None
    if capture is not None:
        socket_side = recorder = CapturingTransport(transport, capture[0], owned=capture[1])
    sender: asyncio.DatagramTransport | ImpairedTransport = socket_side
    if netem is not None:
        sender = ImpairedTransport(socket_side, netem, seed=netem_seed, timer=timer)

    def _close_transport(_: Endpoint) -> None:
        sender.close()  # an impaired one lets the datagrams inside its link out first

    async def _wait_transport_closed() -> None:
        await _released(protocol.closed, transport)

    # On the batched layer, with nothing between the endpoint and the socket: batches both ways.
    batched = transport if isinstance(transport, BatchedDatagramTransport) else None
    direct = batched is not None and sender is transport
    endpoint = Endpoint(
        conn,
        sender,
        connected=True,
        timer=timer,
        on_data=on_data,
        on_watchdog=on_watchdog,
        on_closed=_close_transport,
        transport_closed=_wait_transport_closed,
        reconnect=reconnect,
        new_connection=lambda: Connection(config, role=role, dials=True, rng=rng, key=key),
        outbox=batched.outbox if batched is not None and direct else None,
    )
    protocol.endpoint = endpoint
    _deliver_to(protocol, endpoint.datagram_received, recorder)
    if batched is not None and recorder is None:
        batched.batch_receiver = endpoint.receive_batch
    conn.connect(remote, now=monotonic())
    endpoint.flush()

    def unreachable() -> None:
        transport.close()
        logger.info("tdtp %s: nothing listens at %s", role.value, protocol.where)

    return await established(endpoint, protocol.where, port, unreachable)


def _check_local(local_addr: object) -> None:
    if local_addr is not None:
        if not (isinstance(local_addr, tuple) and len(local_addr) == 2):
            raise InvalidArgumentError(
                f"local_addr must be a (host, port) tuple, got {local_addr!r}"
            )
        _check_port(local_addr[1], allow_zero=True)


def _connect_rendezvous(
    host: object,
    port: object,
    rendezvous: object,
    role: Role,
    config: ConnectionConfig | None,
    local_addr: tuple[str, int] | None,
    timer: TimerPreference,
    on_data: DataCallback | None,
    on_watchdog: WatchdogCallback | None,
    rng: random.Random | None,
    netem: NetemSpec | str | None,
    key: OneKeyInput | None,
    pcap: CaptureTarget | None,
    policy: ReconnectPolicy | None,
) -> Opener[Endpoint]:
    """``connect(rendezvous=...)``: the checks, then :func:`tdtp.aio.traversal.dial_via_rendezvous`."""
    if not isinstance(rendezvous, Rendezvous):
        raise ArgumentTypeError(
            f"rendezvous must be a tdtp.Rendezvous(host, port, ...), got {rendezvous!r}"
        )
    if host is not None or port is not None:
        raise InvalidArgumentError(
            "give the peer's host and port, or rendezvous= (where both meet), not both"
        )
    if netem is not None or pcap is not None:
        raise InvalidArgumentError("netem= and pcap= are not available with rendezvous=")
    _check_local(local_addr)
    _check_common(config, timer, on_data, on_watchdog, None)
    chosen = as_key(key) if key is not None else None
    meeting(chosen, rendezvous.name)  # an unkeyed rendezvous without a name fails here
    return Opener(
        lambda: dial_via_rendezvous(
            rendezvous,
            role=role,
            config=config,
            key=chosen,
            local_addr=local_addr,
            timer=timer,
            on_data=on_data,
            on_watchdog=on_watchdog,
            rng=rng,
            reconnect=policy,
        )
    )
