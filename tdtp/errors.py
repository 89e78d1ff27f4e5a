"""Exceptions raised to the *caller*. Peer input never raises; it is dropped and counted.

Every exception tdtp raises on purpose derives from :class:`TdtpError`, so ``except tdtp.TdtpError``
catches them all. Where a standard exception fits too it is a second base: argument mistakes are also
:class:`ValueError` or :class:`TypeError`, a connection that is over or could not be opened is also
:class:`ConnectionError`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tdtp.session.events import ConnectionClosed


class TdtpError(Exception):
    """Base class of every exception tdtp raises on purpose."""


class InvalidArgumentError(TdtpError, ValueError):
    """An argument or configuration value is out of range or of the wrong kind; the message names it
    and says what is accepted."""


class ArgumentTypeError(TdtpError, TypeError):
    """An argument is of the wrong type; the message names it and says what is accepted."""


class PayloadTypeError(ArgumentTypeError):
    """``send()`` was given something other than a bytes-like object (bytes, bytearray, memoryview)."""


class AddressError(TdtpError, OSError):
    """A host name could not be resolved, or a socket could not be bound to the address (in use, not
    an address of this host). The original :class:`OSError` is the ``__cause__``."""


class ConnectionStateError(TdtpError):
    """The call is not valid in the connection's current state (e.g. sending before the open)."""


class ConnectionClosedError(ConnectionStateError):
    """The connection is over; create a new one (or reconnect) to send again.

    :attr:`event` says why it ended when that is known (the peer closed, its silence outlasted
    ``idle_timeout``, ...).
    """

    def __init__(self, message: str, event: ConnectionClosed | None = None) -> None:
        super().__init__(message)
        self.event = event


class PayloadTooLargeError(TdtpError, ValueError):
    """A payload exceeds the connection's maximum; split it or raise ``max_payload`` on both ends."""


class EmptyPayloadError(TdtpError, ValueError):
    """A sample must have at least one byte: TDTP never sends an empty DATA packet."""


class ControlQueueFullError(TdtpError):
    """The control channel already holds ``control_window`` messages the peer has not acknowledged;
    send again once some are (the peer may be slow to read them, or unreachable for a while)."""


class ControlChannelFailedError(ConnectionStateError):
    """A control message went unacknowledged for ``control_timeout`` and was given up (the
    ``ControlExpired`` event said which): in-order delivery cannot go on past it, so the channel
    takes no more messages. Open a new connection for a fresh one."""


class InvalidKeyError(TdtpError, ValueError):
    """Key material or a key argument is unusable: too short, malformed, or given to the wrong role."""


class EndpointClosedError(ConnectionClosedError, ConnectionError):
    """An asyncio endpoint's association is over; :attr:`event` says why (peer closed, idle timeout,
    closed by this application, ...). Raised by ``send``, ``recv`` and the waits once the association
    has ended."""

    event: ConnectionClosed

    def __init__(self, event: ConnectionClosed) -> None:
        super().__init__(f"TDTP connection closed ({event.cause.value}): {event.detail}", event)


class ReconnectingError(ConnectionStateError):
    """A reconnecting endpoint (``tdtp.connect(..., reconnect=...)``) has no session right now: the
    last one ended and the next is opening. A control message is refused at once rather than queued
    for a session that may open much later, or on a slave that restarted since (docs/PROTOCOL.md
    5.10); send it again once the endpoint is established (``await ep.wait_resumed()``)."""


class ConnectError(TdtpError, ConnectionError):
    """The slave did not accept: no answer within ``open_timeout``, or an explicit refusal."""


class PortUnreachableError(ConnectError):
    """Nothing listens at the slave's address: the host answered the OPEN with an ICMP port
    unreachable (``ECONNREFUSED``). Start the slave, or check the host and port."""


class ServerClosedError(TdtpError, ConnectionError):
    """The listening server is closed; no more masters will be accepted."""


class DatagramLayerClosedError(ConnectionStateError):
    """The datagram layer (:mod:`tdtp.aio.datagram`) was closed; open a new one to send again."""


class DatagramEngineUnavailableError(TdtpError, RuntimeError):
    """The compiled datagram engine was asked for (``engine="compiled"``) but cannot run here: not
    built (no C compiler, ``TDTP_PURE_BUILD``), switched off (``TDTP_PURE_PYTHON``), or older than its
    source (``make build``). The message says which."""
