"""One ``sendmmsg`` per socket for everything an event loop's endpoints send during one wake-up.

On the batched datagram layer (:mod:`tdtp.aio.datagram`) each socket has a :class:`SocketOutbox`, and
each loop one :class:`LoopOutbox` that knows whether a *wake-up* is in progress: a receive batch being
handed to the endpoints, the shared deadline timer serving every session due
(:class:`~tdtp.aio.loop_timers.LoopTimers`), or the tasks a tick of a
:class:`~tdtp.aio.loop_timers.TickGroup` woke. While one is (``LoopOutbox.depth > 0``), an endpoint
appends what it sends to its socket's outbox instead of calling the socket; when the wake-up ends, every
outbox that holds datagrams is sent with one ``send_batch`` (one ``sendmmsg``).

Nothing waits for a batch to fill: the flush comes at the end of the wake-up that produced the
datagrams, so a ping-pong's answer leaves as soon as the receive batch that asked for it has been
handled. A receive batch of one datagram is not held at all (:attr:`LoopOutbox.direct`): with
nothing to batch its answer with, the answer goes to the socket at once, and the sender's
bookkeeping and the rest of the wake-up run while it travels. A send from anywhere else (an application task, a callback of its own) goes to the socket at
once, as before.
"""

from __future__ import annotations

import asyncio
import weakref
from collections.abc import Callable

from tdtp.errors import DatagramLayerClosedError
from tdtp.session.events import Address

__all__ = ["LoopOutbox", "SocketOutbox", "current_outbox", "loop_outbox"]

Item = tuple[bytes, Address | None]


class SocketOutbox:
    """The datagrams queued for one socket during the current wake-up."""

    def __init__(
        self, owner: LoopOutbox, send_batch: Callable[[list[Item]], int], limit: int
    ) -> None:
        self.owner = owner
        self._send_batch = send_batch
        self._limit = limit
        self.items: list[Item] = []
        self.queued = False
        self.closed = False

    def append(self, data: bytes, addr: Address | None = None, /) -> None:
        """Queue one datagram (the shape of a transport's ``sendto``); a full batch leaves at once
        (the outbox is bounded by the layer's batch)."""
        items = self.items
        items.append((data, addr))
        if not self.queued:
            self.queued = True
            self.owner.dirty.append(self)
        if len(items) >= self._limit:
            self.flush()

    def extend(self, datagrams: list[tuple[bytes, Address]], connected: bool) -> None:
        """Queue what a connection's ``datagrams_to_send`` returned (no address on a connected
        socket)."""
        if connected:
            self.items.extend([(data, None) for data, _ in datagrams])
        else:
            self.items.extend(datagrams)
        if not self.queued:
            self.queued = True
            self.owner.dirty.append(self)
        if len(self.items) >= self._limit:
            self.flush()

    def flush(self) -> None:
        items, self.items = self.items, []
        self.queued = False
        if items and not self.closed:
            self.owner.batches += 1
            self.owner.datagrams += len(items)
            try:
                self._send_batch(items)
            except DatagramLayerClosedError:
                self.closed = True  # closed during the wake-up: lost, as on any closed socket

    def close(self) -> None:
        self.closed = True
        self.items = []


class LoopOutbox:
    """The wake-up in progress on one loop, and the socket outboxes it has filled."""

    def __init__(self) -> None:
        # No reference to the loop: the registry below maps the loop to this object weakly.
        self.depth = 0
        """Wake-ups in progress (nested: a receive batch inside a timer's callback, ...)."""
        self.direct = 0
        """Wake-ups in progress for a single received datagram, outside any other wake-up: what
        they send goes to the socket at once, before the bookkeeping that follows the send (a
        ping-pong's answer does not wait for it; one datagram in, one system call out, as before)."""
        self.dirty: list[SocketOutbox] = []
        self.batches = 0
        """``send_batch`` calls made by flushes."""
        self.datagrams = 0
        """Datagrams sent by flushes."""

    def socket(self, send_batch: Callable[[list[Item]], int], limit: int) -> SocketOutbox:
        """A socket's outbox: ``send_batch`` sends a list, at most ``limit`` are held."""
        return SocketOutbox(self, send_batch, limit)

    def hold(self) -> None:
        """A wake-up begins: sends are queued until the matching :meth:`release`."""
        self.depth += 1

    def release(self) -> None:
        """A wake-up ends: the last one sends every queued datagram, one batch per socket."""
        self.depth -= 1
        if self.depth <= 0:
            self.depth = 0
            dirty = self.dirty
            while dirty:  # a flush may queue more (an endpoint resumed): served in this loop
                self.dirty = []
                for outbox in dirty:
                    outbox.flush()
                dirty = self.dirty

    def hold_batch(self, count: int) -> None:
        """A receive batch of ``count`` datagrams is handed over: a wake-up (:meth:`hold`), except
        for a single datagram, whose answers leave at once (:attr:`direct`). Pair with
        :meth:`release_batch`."""
        if count == 1:
            self.direct += 1
        else:
            self.hold()

    def release_batch(self, count: int) -> None:
        """The batch of :meth:`hold_batch` has been handed over."""
        if count == 1:
            self.direct -= 1
        else:
            self.release()

    def hold_until_ready_ran(self, loop: asyncio.AbstractEventLoop) -> None:
        """Hold until the callbacks scheduled so far (the tasks a tick or a sample just woke, the
        rest of the task sending now) have run: the release is queued behind them with
        ``call_soon``."""
        self.depth += 1
        loop.call_soon(self.release)


_OUTBOXES: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, LoopOutbox] = (
    weakref.WeakKeyDictionary()
)


def loop_outbox(loop: asyncio.AbstractEventLoop) -> LoopOutbox:
    """The loop's outbox, created on first use (by a socket on the batched datagram layer)."""
    outbox = _OUTBOXES.get(loop)
    if outbox is None:
        _OUTBOXES[loop] = outbox = LoopOutbox()
    return outbox


def current_outbox(loop: asyncio.AbstractEventLoop) -> LoopOutbox | None:
    """The loop's outbox if a batched socket ever made one (the timers ask, and do nothing
    without one)."""
    return _OUTBOXES.get(loop)
