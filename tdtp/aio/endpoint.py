"""One TDTP association on asyncio: a thin shell around the sans-IO :class:`~tdtp.Connection`.

The shell does three things after every input (a datagram, a timer expiry, a sample from the application):
hand it to the connection with ``now``, transmit whatever the connection wants sent, and re-arm the single
deadline timer if the connection's next deadline moved. Nothing else decides anything here, so a user can
never forget to flush and the asyncio layer behaves exactly like the core under fake time.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import AsyncIterator, Callable
from typing import Protocol

from tdtp.aio.timer import DeadlineTimer, create_timer, monotonic
from tdtp.connection import Connection, State
from tdtp.events import Address, ConnectionClosed, ConnectionEstablished, DataReceived
from tdtp.stats import ConnectionStats

DataCallback = Callable[[DataReceived], None]


class EndpointClosedError(ConnectionError):
    """The association is over; :attr:`event` says why (peer closed, idle timeout, ...)."""

    def __init__(self, event: ConnectionClosed) -> None:
        super().__init__(f"TDTP connection closed ({event.cause.value}): {event.detail}")
        self.event = event


class DatagramSender(Protocol):
    def sendto(self, data: bytes, addr: Address | None = ..., /) -> None: ...


class Endpoint:
    """A master's or slave's end of one association. Create it with :func:`tdtp.aio.connect` or take it
    from a :class:`tdtp.aio.Server`; do not construct it directly."""

    def __init__(
        self,
        conn: Connection,
        transport: DatagramSender,
        *,
        connected: bool,
        timer: str = "auto",
        on_data: DataCallback | None = None,
        on_closed: Callable[[Endpoint], None] | None = None,
        on_established: Callable[[Endpoint], None] | None = None,
    ) -> None:
        self._conn = conn
        self._transport = transport
        self._connected = connected
        loop = asyncio.get_running_loop()
        self._loop = loop
        self._timer: DeadlineTimer = create_timer(loop, self._on_timer, prefer=timer)
        self._on_data = on_data
        self._on_closed = on_closed
        self._on_established = on_established
        self._queue: deque[DataReceived] = deque()
        self._max_queue = conn.config.max_pending_events
        self._waiter: asyncio.Future[None] | None = None
        self._established: asyncio.Future[None] = loop.create_future()
        self._closed: asyncio.Future[ConnectionClosed] = loop.create_future()
        self._close_event: ConnectionClosed | None = None
        self.send_errors = 0
        """Datagrams the socket refused (full buffer, ICMP unreachable): lost like any other."""

    # ------------------------------------------------------------------ public API

    @property
    def connection(self) -> Connection:
        """The sans-IO core underneath (for inspection; drive it only through this endpoint)."""
        return self._conn

    @property
    def peer(self) -> Address | None:
        return self._conn.peer

    @property
    def stats(self) -> ConnectionStats:
        """The core's live counters plus srtt, loss-event rate p and the allowed rate."""
        return self._conn.stats

    @property
    def timer_kind(self) -> str:
        """Which deadline timer paces this endpoint: ``"timerfd"`` or ``"call_at"``."""
        return self._timer.kind

    @property
    def established(self) -> bool:
        """Whether the association was established (it may have closed since)."""
        return self._established.done() and self._established.exception() is None

    @property
    def is_closed(self) -> bool:
        return self._conn.state is State.CLOSED

    def set_data_callback(self, on_data: DataCallback | None) -> None:
        """Deliver samples to ``on_data`` as they arrive instead of queueing them for :meth:`recv`.
        Samples already queued are handed to it at once. ``None`` switches back to queueing."""
        self._on_data = on_data
        if on_data is not None:
            queue = self._queue
            while queue:
                on_data(queue.popleft())

    def send(self, payload: bytes) -> None:
        """Offer the newest sample. Never blocks: the pacer sends it when the rate controller allows,
        and a newer sample offered before then replaces it (counted as superseded).

        Raises :class:`~tdtp.ConnectionClosedError` after the association ended.
        """
        now = monotonic()
        self._conn.send(payload, now=now)
        self._flush(now)

    async def recv(self) -> DataReceived:
        """The next sample from the peer. Raises :class:`EndpointClosedError` once the association is
        over and every sample that arrived before has been taken."""
        queue = self._queue
        while True:
            if queue:
                return queue.popleft()
            if self._close_event is not None:
                raise EndpointClosedError(self._close_event)
            waiter = self._loop.create_future()
            self._waiter = waiter
            try:
                await waiter
            finally:
                self._waiter = None

    def __aiter__(self) -> AsyncIterator[DataReceived]:
        return self._iterate()

    async def _iterate(self) -> AsyncIterator[DataReceived]:
        while True:
            try:
                yield await self.recv()
            except EndpointClosedError:
                return

    async def close(self) -> None:
        """Send CLOSE to the peer and release the timer. Idempotent."""
        if not self.is_closed:
            self._conn.close(now=monotonic())
            self._flush()
        self._release()

    async def wait_closed(self) -> ConnectionClosed:
        """Wait until the association ends, for whatever reason, and say why."""
        return await asyncio.shield(self._closed)

    async def __aenter__(self) -> Endpoint:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    # ------------------------------------------------------------------ driven by the transport

    def datagram_received(self, data: bytes, addr: Address) -> None:
        now = monotonic()
        self._conn.receive_datagram(data, addr, now=now)
        self._flush(now)

    def _on_timer(self) -> None:
        now = monotonic()
        self._conn.handle_timer(now=now)
        self._flush(now)

    async def wait_established(self) -> None:
        await asyncio.shield(self._established)

    # ------------------------------------------------------------------ internals

    def _flush(self, now: float | None = None) -> None:
        conn = self._conn
        datagrams = conn.datagrams_to_send(now=monotonic() if now is None else now)
        if datagrams:
            sendto = self._transport.sendto
            try:
                if self._connected:
                    for data, _addr in datagrams:
                        sendto(data)
                else:
                    for data, addr in datagrams:
                        sendto(data, addr)
            except OSError:
                # A full socket buffer or an ICMP error: the datagram is lost like any other.
                self.send_errors += 1
        self._drain_events()
        if conn.state is State.CLOSED:
            self._release()
            return
        deadline = conn.get_timer()
        armed = self._timer.deadline
        if armed is None or (deadline is not None and deadline < armed):
            # Only an earlier deadline re-arms. Most inputs push the deadline *later* (keep-alive
            # and idle timers move with every packet); an expiry at the older, earlier time just runs
            # handle_timer, which is harmless, and re-arms then. That saves a timerfd_settime
            # system call per packet.
            self._timer.arm(deadline)

    def _drain_events(self) -> None:
        conn = self._conn
        on_data = self._on_data
        queue = self._queue
        while (event := conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                if on_data is not None:
                    on_data(event)
                    continue
                if len(queue) >= self._max_queue:
                    queue.popleft()  # latest-value semantics: the oldest unread sample goes
                    conn.stats.events_discarded += 1
                queue.append(event)
            elif isinstance(event, ConnectionEstablished):
                if not self._established.done():
                    self._established.set_result(None)
                if self._on_established is not None:
                    callback, self._on_established = self._on_established, None
                    callback(self)
            else:
                self._close_event = event
                if not self._closed.done():
                    self._closed.set_result(event)
                if not self._established.done():
                    self._established.set_exception(EndpointClosedError(event))
                    self._established.exception()  # mark retrieved: connect() reports it itself
        waiter = self._waiter
        if waiter is not None and not waiter.done() and (queue or self._close_event is not None):
            waiter.set_result(None)

    def _release(self) -> None:
        self._drain_events()
        self._timer.close()
        if self._on_closed is not None:
            callback, self._on_closed = self._on_closed, None
            callback(self)
