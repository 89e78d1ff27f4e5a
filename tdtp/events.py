"""What a connection reports to its application, one frozen dataclass per kind of event."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

Address = tuple[Any, ...]
"""A socket address as asyncio reports it: ``(host, port)`` or ``(host, port, flowinfo, scope_id)``."""


class CloseCause(enum.Enum):
    LOCAL_CLOSE = "local_close"
    """This side called :meth:`~tdtp.connection.Connection.close`."""
    PEER_CLOSE = "peer_close"
    """The peer sent CLOSE."""
    IDLE_TIMEOUT = "idle_timeout"
    """Nothing arrived from the peer for ``idle_timeout``: the peer is gone or the path is down."""
    OPEN_TIMEOUT = "open_timeout"
    """The master's OPEN was never answered."""
    REJECTED = "rejected"
    """The slave refused the OPEN (busy, unknown key, unsupported version, ...): the detail says why."""
    REPLACED = "replaced"
    """The same master opened a new connection (it restarted): this older one is over."""
    KEY_EXHAUSTED = "key_exhausted"
    """A keyed session protected as many packets as its keys may (or saw too many forgeries)."""


@dataclass(frozen=True, slots=True)
class ConnectionEstablished:
    peer: Address


@dataclass(frozen=True, slots=True)
class DataReceived:
    """One supermedia sample from the peer."""

    payload: bytes
    seq: int
    """The sample's full (unwrapped) sequence number on this connection."""
    age: float | None
    """Estimated one-way age in seconds when it arrived: half the smoothed RTT (clocks are not
    synchronised, so the path is assumed symmetric); ``None`` before the first RTT sample."""
    received_at: float
    """The ``now`` it arrived at."""


@dataclass(frozen=True, slots=True)
class ConnectionClosed:
    cause: CloseCause
    detail: str


Event = ConnectionEstablished | DataReceived | ConnectionClosed
