"""The datagram layer behind asyncio's transport interface: the opt-in switch of issue 23's first round.

:func:`create_datagram_endpoint` has the shape of ``loop.create_datagram_endpoint`` and returns a
:class:`BatchedDatagramTransport` over a :class:`~tdtp.aio.datagram.DatagramLayer`, so that
``tdtp.connect`` and ``tdtp.listen`` can run on the batched receive path without changing what they
do: each ``recvmmsg`` batch is handed to the protocol's ``datagram_received`` one datagram at a time,
kernel errors to ``error_received``, a full send buffer to ``pause_writing`` / ``resume_writing``.

It is off unless ``TDTP_DATAGRAM_LAYER=1`` is in the environment (:func:`enabled`). What it saves is
the receive side's system calls (one ``recvmmsg`` per batch instead of one ``recvfrom`` each) and
uvloop's per-datagram callback machinery; the per-datagram Python call into the protocol and the
per-datagram send remain until the endpoints take batches themselves (the integration round).
"""

from __future__ import annotations

import asyncio
import os
import socket
from collections.abc import Callable
from typing import Any, Final, TypeVar

from tdtp.aio.datagram import DatagramLayer, open_datagram_endpoint
from tdtp.session.events import Address

__all__ = [
    "ENV",
    "BatchedDatagramTransport",
    "create_datagram_endpoint",
    "datagram_endpoint",
    "enabled",
]

ENV: Final = "TDTP_DATAGRAM_LAYER"


def enabled() -> bool:
    """Whether ``TDTP_DATAGRAM_LAYER`` asks for the batched datagram layer (set, not ``0``)."""
    return os.environ.get(ENV, "") not in ("", "0")


class BatchedDatagramTransport(asyncio.DatagramTransport):
    """An ``asyncio.DatagramTransport`` over a :class:`~tdtp.aio.datagram.DatagramLayer`."""

    def __init__(self, protocol: asyncio.DatagramProtocol) -> None:
        super().__init__()
        self._protocol = protocol
        self._layer: DatagramLayer | None = None
        self._closing = False

    def _attach(self, layer: DatagramLayer) -> None:
        self._layer = layer
        self.sendto = layer.sendto  # type: ignore[method-assign,assignment]

    # -- called by the layer

    def _on_receive(
        self,
        datas: list[bytes],
        addrs: list[Address],
        stamps: list[int] | None,
        classes: list[int] | None,
    ) -> None:
        receive = self._protocol.datagram_received  # looked up per batch: tdtp rebinds it
        for data, addr in zip(datas, addrs, strict=True):
            receive(data, addr)

    def _on_error(self, exc: OSError) -> None:
        self._protocol.error_received(exc)

    def _on_pause(self) -> None:
        self._protocol.pause_writing()

    def _on_resume(self) -> None:
        self._protocol.resume_writing()

    # -- the transport interface

    def sendto(self, data: Any, addr: Any = None) -> None:  # replaced by the layer's own
        raise RuntimeError("the transport is not attached yet")

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        layer = self._layer
        if layer is None:
            return default
        sock = layer.socket
        if name == "sockname":
            return sock.getsockname() if not layer.is_closed else default
        if name == "peername":
            try:
                return sock.getpeername()
            except OSError:
                return default
        if name == "socket":
            return sock
        return default

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        """Accepted for compatibility: the layer pauses as soon as the kernel refuses a datagram."""

    def get_write_buffer_size(self) -> int:
        return self._layer.pending if self._layer is not None else 0

    def is_closing(self) -> bool:
        return self._closing

    def close(self) -> None:
        if self._closing:
            return
        self._closing = True
        if self._layer is not None:
            self._layer.close()
        asyncio.get_running_loop().call_soon(self._protocol.connection_lost, None)

    def abort(self) -> None:
        self.close()


async def create_datagram_endpoint(
    loop: asyncio.AbstractEventLoop,
    protocol_factory: Any,
    *,
    local_addr: tuple[str, int] | None = None,
    remote_addr: tuple[str, int] | None = None,
    family: int = 0,
    reuse_port: bool | None = None,
) -> tuple[BatchedDatagramTransport, Any]:
    """``loop.create_datagram_endpoint`` on the batched datagram layer (the arguments tdtp uses)."""
    protocol = protocol_factory()
    transport = BatchedDatagramTransport(protocol)
    if local_addr is None and remote_addr is not None:
        wildcard = "::" if family == socket.AF_INET6 or ":" in str(remote_addr[0]) else "0.0.0.0"
        local_addr = (wildcard, 0)
    layer = await open_datagram_endpoint(
        transport._on_receive,
        local_addr=local_addr,
        remote_addr=remote_addr,
        on_error=transport._on_error,
        on_pause=transport._on_pause,
        on_resume=transport._on_resume,
        reuse_port=bool(reuse_port),
    )
    transport._attach(layer)
    protocol.connection_made(transport)
    return transport, protocol


P = TypeVar("P", bound=asyncio.DatagramProtocol)


async def datagram_endpoint(
    loop: asyncio.AbstractEventLoop, protocol_factory: Callable[[], P], **kwargs: Any
) -> tuple[asyncio.DatagramTransport, P]:
    """The loop's ``create_datagram_endpoint``, or :func:`create_datagram_endpoint` when
    ``TDTP_DATAGRAM_LAYER`` is set: the one switch ``tdtp.connect`` and ``tdtp.listen`` go through."""
    if enabled():
        transport, protocol = await create_datagram_endpoint(loop, protocol_factory, **kwargs)
        return transport, protocol
    return await loop.create_datagram_endpoint(protocol_factory, **kwargs)
