"""tdtp: the Teleoperation Data Transport Protocol.

A 5-byte header, acknowledgements piggybacked on the reverse supermedia flow, and trinomial flow control.
The core (:class:`Connection`) is sans-IO: it never touches sockets or reads a clock. The asyncio entry
points (:func:`connect`, :func:`listen`) run it over real UDP sockets.
"""

from tdtp.aio.api import ConnectError, Server, ServerStats, connect, listen
from tdtp.aio.endpoint import Endpoint, EndpointClosedError
from tdtp.aio.ticker import Ticker
from tdtp.aio.timer import monotonic
from tdtp.config import AckMode, AdmissionConfig, ConnectionConfig, Role
from tdtp.connection import Connection, State
from tdtp.errors import (
    ConnectionClosedError,
    ConnectionStateError,
    EmptyPayloadError,
    InvalidKeyError,
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
from tdtp.protection.key_file import load_keys, write_key_file
from tdtp.protection.keys import KeyRing, PresharedKey
from tdtp.stats import ConnectionStats, DirectionStats, DropReason
from tdtp.wire import HEADER_SIZE, CipherSuite

__version__ = "0.1.0"

__all__ = [
    "HEADER_SIZE",
    "AckMode",
    "Address",
    "AdmissionConfig",
    "CipherSuite",
    "CloseCause",
    "ConnectError",
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
    "EmptyPayloadError",
    "Endpoint",
    "EndpointClosedError",
    "Event",
    "InvalidKeyError",
    "KeyRing",
    "PayloadTooLargeError",
    "PresharedKey",
    "Role",
    "Server",
    "ServerStats",
    "State",
    "TdtpError",
    "Ticker",
    "__version__",
    "connect",
    "listen",
    "load_keys",
    "monotonic",
    "write_key_file",
]
