"""tdtp: the Teleoperation Data Transport Protocol.

A 5-byte header, acknowledgements piggybacked on the reverse supermedia flow, and trinomial flow control.
The core (:class:`Connection`) is sans-IO: it never touches sockets or reads a clock.
"""

from tdtp.config import AckMode, ConnectionConfig, Role
from tdtp.connection import Connection, State
from tdtp.errors import (
    ConnectionClosedError,
    ConnectionStateError,
    PayloadTooLargeError,
    TdtpError,
)
from tdtp.events import (
    Address,
    CloseCause,
    ConnectionClosed,
    ConnectionEstablished,
    DataReceived,
    Event,
)
from tdtp.stats import ConnectionStats, DirectionStats, DropReason
from tdtp.wire import HEADER_SIZE

__version__ = "0.1.0"

__all__ = [
    "HEADER_SIZE",
    "AckMode",
    "Address",
    "CloseCause",
    "Connection",
    "ConnectionClosed",
    "ConnectionClosedError",
    "ConnectionConfig",
    "ConnectionEstablished",
    "ConnectionStateError",
    "ConnectionStats",
    "DataReceived",
    "DirectionStats",
    "DropReason",
    "Event",
    "PayloadTooLargeError",
    "Role",
    "State",
    "TdtpError",
    "__version__",
]
