"""Capturing an endpoint's traffic into a pcap file: ``tdtp.connect(..., pcap=...)`` and
``tdtp.listen(..., pcap=...)``.

A :class:`CapturingTransport` sits right on the UDP socket, below any netem impairment, so the file
holds what really left and arrived at the socket, with the socket's addresses and ports. Receiving is
recorded by the datagram protocol (``tdtp.aio.api`` swaps in a capturing one only when asked): with
capture off nothing on the per-packet path changes.
"""

from __future__ import annotations

import asyncio
import os
from typing import Any

from tdtp.capture.pcap import PcapWriter
from tdtp.session.events import Address

CaptureTarget = str | os.PathLike[str] | PcapWriter
"""Where to capture: a path (a new file, closed with the endpoint or server) or an open
:class:`~tdtp.capture.pcap.PcapWriter` (shared, closed by its owner)."""


def open_capture(target: CaptureTarget) -> tuple[PcapWriter, bool]:
    """The writer for ``target`` and whether the caller owns (must close) it. Raises
    :class:`~tdtp.capture.pcap.CaptureError` when the file cannot be created."""
    if isinstance(target, PcapWriter):
        return target, False
    return PcapWriter(target), True


class CapturingTransport(asyncio.DatagramTransport):
    """A datagram transport that records every datagram it sends, and every datagram its
    protocol reports received, into a :class:`~tdtp.capture.pcap.PcapWriter`."""

    def __init__(
        self, transport: asyncio.DatagramTransport, writer: PcapWriter, *, owned: bool
    ) -> None:
        super().__init__()
        self._transport = transport
        self.writer = writer
        self._owned = owned
        self._local: tuple[Any, ...] = transport.get_extra_info("sockname") or ("0.0.0.0", 0)
        self._peer: tuple[Any, ...] | None = transport.get_extra_info("peername")

    def sendto(self, data: Any, addr: Any = None, /) -> None:
        if addr is None:
            self._transport.sendto(data)
            destination = self._peer
        else:
            self._transport.sendto(data, addr)
            destination = addr
        if destination is not None:  # not reached when sendto raised: nothing left
            self.writer.write_udp(self._local, destination, bytes(data))

    def received(self, data: bytes, addr: Address) -> None:
        """Record a datagram the socket delivered from ``addr``."""
        self.writer.write_udp(addr, self._local, data)

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return self._transport.get_extra_info(name, default)

    def is_closing(self) -> bool:
        return self._transport.is_closing()

    def close(self) -> None:
        self._transport.close()
        if self._owned:
            self.writer.close()
        else:
            self.writer.flush()

    def abort(self) -> None:
        self._transport.abort()
        if self._owned:
            self.writer.close()
