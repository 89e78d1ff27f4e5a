"""The datagram layer behind asyncio's transport interface: what ``tdtp.connect`` and ``tdtp.listen`` run on.

:func:`create_datagram_endpoint` has the shape of ``loop.create_datagram_endpoint`` and returns a
:class:`BatchedDatagramTransport` over a :class:`~tdtp.aio.datagram.DatagramLayer`. Receiving, each
``recvmmsg`` batch goes to :attr:`BatchedDatagramTransport.batch_receiver` in one call when the
endpoint or server has set one (``Endpoint.receive_batch``, ``Server._batch_received``), else to the
protocol's ``datagram_received`` one datagram at a time (a pcap capture records them that way). The
batch is a wake-up of the loop's :class:`~tdtp.aio.outbox.LoopOutbox`: whatever the endpoints send
while handling it leaves in one ``sendmmsg`` when it ends. Kernel errors go to ``error_received``, a
full send buffer to ``pause_writing`` / ``resume_writing``, as with the loop's own transport. The
kernel's receive times (``SO_TIMESTAMPNS``) and the ECN bits are asked for and handed on.

Which transport (:func:`enabled`): the layer whenever its compiled engine is built, unless
``TDTP_DATAGRAM_LAYER=0``; the loop's own transport otherwise (no C compiler, ``TDTP_PURE_PYTHON=1``).
``TDTP_DATAGRAM_LAYER=1`` asks for the layer even on the pure-Python engine, ``=pure`` for the pure
engine even where the compiled one is built (for tests and benchmarks).
"""

from __future__ import annotations

import asyncio
import os
import socket
from collections.abc import Callable
from typing import Any, Final, Literal, TypeVar

from tdtp.aio.datagram import DatagramLayer, datagram_build_info, open_datagram_endpoint
from tdtp.aio.outbox import LoopOutbox, SocketOutbox, loop_outbox
from tdtp.session.events import Address

__all__ = [
    "ENV",
    "BatchedDatagramTransport",
    "create_datagram_endpoint",
    "datagram_endpoint",
    "enabled",
    "layer_description",
    "layer_under",
]

ENV: Final = "TDTP_DATAGRAM_LAYER"


BatchReceiver = Callable[[list[bytes], list[Address], list[int] | None, list[int] | None], None]


def enabled() -> bool:
    """Whether ``tdtp.connect`` / ``tdtp.listen`` run on the batched datagram layer: by default
    when its compiled engine is built; ``TDTP_DATAGRAM_LAYER=0`` never, ``1`` (or ``pure``) always."""
    value = os.environ.get(ENV, "")
    if value == "":
        return datagram_build_info().compiled
    return value != "0"


def layer_under(transport: object) -> DatagramLayer | None:
    """The datagram layer under ``transport`` and any wrappers around it (a pcap capture,
    in-process impairment: each holds the transport it wraps as ``_transport``), or ``None`` (the
    loop's own transport): what ``Endpoint.sockets`` and ``Endpoint.datagram_layer_stats`` read."""
    while transport is not None:
        layer = getattr(transport, "layer", None)
        if isinstance(layer, DatagramLayer):
            return layer
        transport = getattr(transport, "_transport", None)
    return None


def layer_description(layer: DatagramLayer | None) -> str:
    """What carries an endpoint's datagrams, in words: ``"datagram layer (compiled, coalescing)"``
    (the C engine, segmenting bursts), ``"datagram layer (compiled)"``, ``"datagram layer
    (pure)"``, or ``"loop's transport"`` (``layer`` is ``None``)."""
    if layer is None:
        return "loop's transport"
    if layer.engine == "compiled" and layer.stats.get("segmenting"):
        return "datagram layer (compiled, coalescing)"
    return f"datagram layer ({layer.engine})"


def _engine() -> Literal["auto", "pure"]:
    return "pure" if os.environ.get(ENV, "") == "pure" else "auto"


class BatchedDatagramTransport(asyncio.DatagramTransport):
    """An ``asyncio.DatagramTransport`` over a :class:`~tdtp.aio.datagram.DatagramLayer`."""

    def __init__(self, protocol: asyncio.DatagramProtocol) -> None:
        super().__init__()
        self._protocol = protocol
        self._layer: DatagramLayer | None = None
        self._closing = False
        self._loop_outbox: LoopOutbox = loop_outbox(asyncio.get_running_loop())
        self.outbox: SocketOutbox | None = None
        """This socket's share of the loop's outbox (set once attached)."""
        self._batch_receiver: BatchReceiver | None = None

    def _attach(self, layer: DatagramLayer) -> None:
        self._layer = layer
        self.sendto = layer.sendto  # type: ignore[method-assign,assignment]
        self.outbox = self._loop_outbox.socket(layer.send_batch, layer.batch)

    @property
    def layer(self) -> DatagramLayer | None:
        return self._layer

    @property
    def batch_receiver(self) -> BatchReceiver | None:
        """Takes each receive batch in one call, straight from the engine, when set (else the
        protocol's ``datagram_received`` gets each datagram). It is a wake-up of the loop's outbox
        of its own: it holds the outbox while it hands the batch on (``Endpoint.receive_batch``,
        ``tdtp.aio.endpoint.demultiplex``)."""
        return self._batch_receiver

    @batch_receiver.setter
    def batch_receiver(self, receiver: BatchReceiver | None) -> None:
        self._batch_receiver = receiver
        if self._layer is not None:
            self._layer.set_receiver(receiver if receiver is not None else self._on_receive)

    # -- called by the layer

    def _on_receive(
        self,
        datas: list[bytes],
        addrs: list[Address],
        stamps: list[int] | None,
        classes: list[int] | None,
    ) -> None:
        outbox = self._loop_outbox
        outbox.hold()  # a wake-up: what the endpoints send now leaves in one batch
        try:
            receive = self._protocol.datagram_received  # per batch: tdtp rebinds it
            for data, addr in zip(datas, addrs, strict=True):
                receive(data, addr)
        finally:
            outbox.release()

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
        if self.outbox is not None:
            self.outbox.flush()  # what the wake-up queued (a CLOSE) leaves before the socket
            self.outbox.close()
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
        timestamps=True,
        ecn=True,
        engine=_engine(),
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
