"""Exceptions raised to the *caller* for API misuse. Peer input never raises; it is dropped and counted."""

from __future__ import annotations


class TdtpError(Exception):
    """Base class of every exception tdtp raises on purpose."""


class ConnectionStateError(TdtpError):
    """The call is not valid in the connection's current state (e.g. sending before the open)."""


class ConnectionClosedError(ConnectionStateError):
    """The connection is over; create a new one (or reconnect) to send again."""


class PayloadTooLargeError(TdtpError, ValueError):
    """A payload exceeds the connection's maximum; split it or raise ``max_payload`` on both ends."""


class EmptyPayloadError(TdtpError, ValueError):
    """A sample must have at least one byte: TDTP never sends an empty DATA packet."""


class InvalidKeyError(TdtpError, ValueError):
    """Key material or a key argument is unusable: too short, malformed, or given to the wrong role."""
