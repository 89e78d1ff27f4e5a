"""The one exception the wire codecs raise on bytes that do not parse."""

from __future__ import annotations


class MalformedPacketError(ValueError):
    """Bytes that are not a valid TDTP datagram.

    ``reason`` is a short machine-readable tag (``"truncated"``, ``"bad_control"``) that the
    connection uses as the drop counter's key; the message says what was wrong in words.
    """

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
