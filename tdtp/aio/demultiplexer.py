"""A server's receive batches, handed to its sessions by source address (the batched datagram layer).

One :class:`Demultiplexer` per :class:`~tdtp.Server` socket takes every ``recvmmsg`` batch in one call
(the layer's ``on_receive``): one clock read per batch, each datagram of a known session straight to
its core in order, then one flush per session touched, with the loop's outbox held so that what they
all send leaves in one ``sendmmsg`` (a batch of one datagram is answered at once instead:
:attr:`~tdtp.aio.outbox.LoopOutbox.direct`). OPENs and datagrams from addresses no session holds go to
the server's front door, one at a time.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Final

from tdtp.aio.endpoint import Endpoint, rx_time_of
from tdtp.aio.outbox import SocketOutbox
from tdtp.session.events import Address
from tdtp.session.state import CLOSED
from tdtp.wire.control import ControlCode
from tdtp.wire.header import HEADER_SIZE, PacketType

__all__ = ["Demultiplexer", "is_open"]

monotonic: Final = time.monotonic
"""= tdtp.aio.timer.monotonic: a static of the compiled module, not a globals lookup per batch."""
_CONTROL_BITS: Final = int(PacketType.CONTROL) << 6
_OPEN: Final = int(ControlCode.OPEN)


def is_open(data: bytes) -> bool:
    """Whether a datagram is an OPEN (a new master knocking), from its first six bytes."""
    return len(data) > HEADER_SIZE and data[0] & 0xC0 == _CONTROL_BITS and data[5] == _OPEN


class Demultiplexer:
    """A server's receive batches, by source address (the batched layer's receiver for a
    :class:`~tdtp.Server`): one clock read per batch; each datagram of a known session straight to
    its core, in order; then one flush per session touched, with the loop's outbox held so that
    what they all send leaves in one ``sendmmsg``. OPENs and datagrams from addresses no session
    holds go to ``unattached`` (the server's front door), one at a time."""

    def __init__(
        self,
        peers: dict[tuple[object, object], Endpoint],
        unattached: Callable[[bytes, Address], None],
        outbox: SocketOutbox | None,
    ) -> None:
        self._peers = peers
        self._unattached = unattached
        self._outbox = outbox
        self._batches = 0

    def __call__(
        self,
        datas: list[bytes],
        addrs: list[Address],
        stamps: list[int] | None,
        classes: list[int] | None,
    ) -> None:
        now = monotonic()
        wall = time.time_ns() if stamps is not None else 0
        out = self._outbox
        owner = out.owner if out is not None else None
        count = len(datas)
        if owner is not None:
            # A wake-up: what this batch makes us send leaves in one sendmmsg (one datagram's
            # answers leave at once: nothing to batch them with).
            owner.hold_batch(count)
        try:
            peers = self._peers
            # The sessions this batch touched, in order, each once: a list, and the batch's number
            # on each endpoint (no dict built and grown per batch).
            self._batches = batch = self._batches + 1
            touched: list[Endpoint] = []
            last: Address | None = None
            endpoint: Endpoint | None = None
            for i in range(len(datas)):
                data = datas[i]
                addr = addrs[i]
                if addr is not last:  # the engine hands one tuple for a run from one source
                    last = addr
                    # An IPv4 address is its own key (the server keys a peer by the tuple the
                    # engine gave its OPEN, which the engine gives again: found by identity).
                    endpoint = peers.get(addr if len(addr) == 2 else (addr[0], addr[1]))
                if endpoint is None or is_open(data) or endpoint._conn.state is CLOSED:
                    self._unattached(data, addr)
                    last = None  # the table may have changed
                    continue
                conn = endpoint._conn
                conn.receive_datagram(
                    data,
                    addr,
                    now=now,
                    rx_time=rx_time_of(stamps[i], now, wall) if stamps is not None else None,
                    ecn=classes[i] & 3 if classes is not None and classes[i] >= 0 else None,
                )
                if conn.state is CLOSED:
                    endpoint.flush(now)  # released: later datagrams from there are strangers
                    if endpoint._demux_batch == batch:
                        touched.remove(endpoint)
                    endpoint._demux_batch = 0
                    last = None
                elif endpoint._demux_batch != batch:
                    endpoint._demux_batch = batch
                    touched.append(endpoint)
            for endpoint in touched:
                endpoint.flush(now)
        finally:
            if owner is not None:
                owner.release_batch(count)
