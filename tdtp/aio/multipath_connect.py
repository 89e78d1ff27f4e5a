"""Opening a multipath master: ``tdtp.connect(..., local_addresses=[...])`` (docs/PROTOCOL.md 5.11).

One socket per local address, each connected to its path's remote end: the session opens on the
first; once it is established, :class:`~tdtp.aio.multipath.PathSet` opens a path from each of the
others. ``path_netem`` impairs a path both ways in-process (``tdtp demo --path``), on the master's
side, so that each path has its own emulated network while the slave runs as it would anywhere.
"""

from __future__ import annotations

import asyncio
import dataclasses
import random
import socket
from collections.abc import Callable, Sequence

from tdtp.aio.endpoint import DataCallback, Endpoint, WatchdogCallback, format_address
from tdtp.aio.impairment import ImpairedTransport, impaired_receiver
from tdtp.aio.multipath import LocalAddress, PathSet, open_socket
from tdtp.aio.opening import address_error, established, refused_text
from tdtp.aio.reconnect import ReconnectPolicy
from tdtp.aio.timer import TimerPreference, monotonic
from tdtp.config import ConnectionConfig, MultipathConfig, Role
from tdtp.errors import PortUnreachableError
from tdtp.netem import NetemSpec
from tdtp.protection.keys import PresharedKey
from tdtp.session.connection import Connection
from tdtp.session.events import Address
from tdtp.session.state import State

__all__ = ["connect_multipath", "multipath_config"]


def multipath_config(config: ConnectionConfig | None) -> ConnectionConfig:
    """``config`` with a :class:`MultipathConfig` (the defaults if it has none)."""
    config = config if config is not None else ConnectionConfig()
    if config.multipath is None:
        config = dataclasses.replace(config, multipath=MultipathConfig())
    return config


async def connect_multipath(
    host: str,
    port: int,
    locals_: Sequence[LocalAddress],
    *,
    config: ConnectionConfig,
    timer: TimerPreference,
    on_data: DataCallback | None,
    on_watchdog: WatchdogCallback | None,
    rng: random.Random | None,
    path_netem: Sequence[NetemSpec | None],
    netem_seed: int | None,
    key: PresharedKey | None,
    reconnect: ReconnectPolicy | None,
) -> Endpoint:
    """:func:`tdtp.connect` with local addresses: the session on the first, a path from each."""
    loop = asyncio.get_running_loop()
    try:
        infos = await loop.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    except OSError as exc:
        raise address_error(exc, "connect to", host, port) from exc
    slave = (str(infos[0][4][0]), int(infos[0][4][1]))
    conn = Connection(config, role=Role.MASTER, rng=rng, key=key)
    remotes = [spec.remote if spec.remote is not None else slave for spec in locals_]
    holder: list[Endpoint] = []
    path_set: PathSet | None = None
    first = locals_[0]
    spec0 = path_netem[0] if path_netem else None

    def arrived(data: bytes, addr: Address) -> None:
        holder[0].datagram_received(data, addr)

    receive0: Callable[[bytes, Address], None] = arrived
    if spec0 is not None:
        seed = None if netem_seed is None else netem_seed + 1
        receive0, _line = impaired_receiver(arrived, spec0, seed=seed, timer=timer)

    def refused(exc: Exception) -> None:
        # The slave's host answered our OPEN with ICMP port unreachable: nobody listens.
        opening = bool(holder) and holder[0].connection.state is State.OPENING
        if opening and isinstance(exc, ConnectionRefusedError):
            where = format_address((host, port))
            holder[0].fail_open(PortUnreachableError(refused_text(where, Role.SLAVE)))

    try:
        transport, _ = await open_socket(loop, first, remotes[0], receive0, refused)
    except OSError as exc:
        raise address_error(exc, f"bind {first} and connect to", host, port) from exc
    sender: asyncio.DatagramTransport | ImpairedTransport = transport
    if spec0 is not None:
        sender = ImpairedTransport(transport, spec0, seed=netem_seed, timer=timer)

    def closed(_: Endpoint) -> None:
        sender.close()
        if path_set is not None:
            path_set.close()

    endpoint = Endpoint(
        conn,
        sender,
        connected=True,
        timer=timer,
        on_data=on_data,
        on_watchdog=on_watchdog,
        on_closed=closed,
        reconnect=reconnect,
        new_connection=lambda: Connection(config, role=Role.MASTER, rng=rng, key=key),
    )
    holder.append(endpoint)
    path_set = endpoint.paths
    path_set._netem_seed = netem_seed
    path_set._timer = timer
    try:
        for number, spec in enumerate(locals_[1:], start=1):
            netem = path_netem[number] if number < len(path_netem) else None
            await path_set.bind(number, spec, remotes[number], netem)
    except OSError as exc:
        endpoint.fail_open(exc)  # lets go of the timer and every socket bound so far
        raise address_error(exc, f"bind {locals_[number]} and connect to", host, port) from exc
    conn.connect(remotes[0], now=monotonic())
    endpoint.flush()
    return await established(endpoint, format_address((host, port)), port, transport.close)
