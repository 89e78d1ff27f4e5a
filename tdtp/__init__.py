"""tdtp: the Teleoperation Data Transport Protocol.

A 5-byte header, acknowledgements piggybacked on the reverse supermedia flow, and trinomial flow control.
The core (:class:`Connection`) is sans-IO: it never touches sockets or reads a clock. The asyncio entry
points (:func:`connect`, :func:`listen`) run it over real UDP sockets.
"""

import logging

from tdtp._build import BuildInfo, build_info  # first: it decides which build of the core loads
from tdtp._build import restore_class_docstrings as _restore_class_docstrings
from tdtp._moved_modules import install as _install_moved_modules
from tdtp.aio.api import Server, ServerStats, connect, listen
from tdtp.aio.endpoint import Endpoint
from tdtp.aio.reconnect import ReconnectPolicy, ReconnectRecord
from tdtp.aio.rendezvous_relay import Relay, relay
from tdtp.aio.ticker import Ticker, TickHandle
from tdtp.aio.timer import monotonic
from tdtp.config import (
    AckMode,
    AdmissionConfig,
    ConnectionConfig,
    ControllerName,
    MultipathConfig,
    Role,
)
from tdtp.errors import (
    AddressError,
    ArgumentTypeError,
    ConnectError,
    ConnectionClosedError,
    ConnectionStateError,
    ControlChannelFailedError,
    ControlQueueFullError,
    EmptyPayloadError,
    EndpointClosedError,
    InvalidArgumentError,
    InvalidKeyError,
    PayloadTooLargeError,
    PayloadTypeError,
    PortUnreachableError,
    ReconnectingError,
    ServerClosedError,
    TdtpError,
)
from tdtp.protection.key_file import load_key, load_keys, write_key_file
from tdtp.protection.keys import KeyRing, PresharedKey
from tdtp.rendezvous.settings import RelayConfig, Rendezvous
from tdtp.session.connection import Connection
from tdtp.session.events import (
    Address,
    CloseCause,
    ConnectionClosed,
    ConnectionEstablished,
    ControlExpired,
    ControlReceived,
    DataReceived,
    Event,
    PathChanged,
    PeerResumed,
    PeerSilent,
)
from tdtp.session.multipath.path import PathStats
from tdtp.session.state import State
from tdtp.session.stats import ConnectionStats, DirectionStats, DropReason
from tdtp.wire import HEADER_SIZE, CipherSuite

# A library leaves logging's configuration to the application: without a handler of its own, the
# watchdog's warnings would go to stderr through logging's last-resort handler.
logging.getLogger("tdtp").addHandler(logging.NullHandler())

# The module paths that changed after 0.1.0 keep working, with a DeprecationWarning, for one release.
_install_moved_modules()

__version__ = "0.1.0"
"""The package version, kept in this one place: ``pyproject.toml`` reads it from here."""

__all__ = [
    "HEADER_SIZE",
    "AckMode",
    "Address",
    "AddressError",
    "AdmissionConfig",
    "ArgumentTypeError",
    "BuildInfo",
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
    "ControlChannelFailedError",
    "ControlExpired",
    "ControlQueueFullError",
    "ControlReceived",
    "ControllerName",
    "DataReceived",
    "DirectionStats",
    "DropReason",
    "EmptyPayloadError",
    "Endpoint",
    "EndpointClosedError",
    "Event",
    "InvalidArgumentError",
    "InvalidKeyError",
    "KeyRing",
    "MultipathConfig",
    "PathChanged",
    "PathStats",
    "PayloadTooLargeError",
    "PayloadTypeError",
    "PeerResumed",
    "PeerSilent",
    "PortUnreachableError",
    "PresharedKey",
    "ReconnectPolicy",
    "ReconnectRecord",
    "ReconnectingError",
    "Relay",
    "RelayConfig",
    "Rendezvous",
    "Role",
    "Server",
    "ServerClosedError",
    "ServerStats",
    "State",
    "TdtpError",
    "TickHandle",
    "Ticker",
    "__version__",
    "build_info",
    "connect",
    "listen",
    "load_key",
    "load_keys",
    "monotonic",
    "relay",
    "write_key_file",
]

# mypyc drops the docstrings of the classes it leaves plain Python (setup.py writes the others' into
# the compiled tables): put them back, so that help(tdtp.DataReceived) reads the same in both builds.
_restore_class_docstrings()
