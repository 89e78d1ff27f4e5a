"""One TDTP association on asyncio: a thin shell around the sans-IO :class:`~tdtp.Connection`.

The shell does three things after every input (a datagram, a timer expiry, a sample from the application):
hand it to the connection with ``now``, transmit whatever the connection wants sent, and re-arm the single
deadline timer if the connection's next deadline moved. Nothing else decides anything here, so a user can
never forget to flush and the asyncio layer behaves exactly like the core under fake time.

Reading. Samples wait in one bounded queue (``max_pending_events``). A control loop wants the newest
sample, not the oldest: :meth:`Endpoint.latest`, :meth:`Endpoint.recv_latest` and ``async for sample in
ep`` skip to the newest and count what they skip (``stats.samples_skipped``); :meth:`Endpoint.recv` and
:meth:`Endpoint.stream` give every sample in order. ``on_data`` callbacks get each sample as it arrives.

Writing. The endpoint watches its socket's send buffer (``pause_writing`` / ``resume_writing`` from the
transport, whose high-water mark is set to zero): while the operating system cannot take datagrams, data
is held in the core, where a newer sample supersedes it, instead of queueing in the event loop.

The watchdog. :attr:`Endpoint.peer_silent`, :meth:`Endpoint.wait_silent`, :meth:`Endpoint.wait_resumed`
and ``on_watchdog`` callbacks report the core's :class:`~tdtp.session.events.PeerSilent` and
:class:`~tdtp.session.events.PeerResumed` events, so a slave can hold its machine while its master is silent.

Control messages. :meth:`Endpoint.send_control` queues a message on the session's reliable control
channel; the peer reads them, each exactly once and in order, with :meth:`Endpoint.recv_control`,
``async for message in ep.control_messages()``, or a callback (:meth:`Endpoint.set_control_callback`).
Unread messages count against the channel's receive bound (``control_window``): an application that
stops reading makes the peer retransmit, then give up, instead of growing a queue here.

Callbacks that raise. An exception from ``on_data`` or ``on_watchdog`` goes to the loop's exception
handler (logged by default, as asyncio logs a failed callback) and the session goes on: its timer is
re-armed and the next samples and events are delivered.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import TYPE_CHECKING, Final, Protocol

from tdtp.aio.datagram_transport import layer_description, layer_under
from tdtp.aio.loop_timers import TimerEntry, loop_timers
from tdtp.aio.multipath import PathSet
from tdtp.aio.outbox import SocketOutbox
from tdtp.aio.reconnect import Reconnector, ReconnectPolicy, ReconnectRecord
from tdtp.aio.sample_iteration import samples_until_closed
from tdtp.errors import (
    ArgumentTypeError,
    ConnectionClosedError,
    ConnectionStateError,
    EndpointClosedError,
    ReconnectingError,
)
from tdtp.netem import NetemLink
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
from tdtp.session.state import CLOSED, ESTABLISHED, State
from tdtp.session.stats import ConnectionStats

if TYPE_CHECKING:
    from tdtp.aio.traversal import Traversal

__all__ = [
    "ControlCallback",
    "DataCallback",
    "Endpoint",
    "EndpointClosedError",
    "WatchdogCallback",
    "WatchdogEvent",
]


monotonic: Final = time.monotonic
"""= tdtp.aio.timer.monotonic: a static of the compiled module, not a globals lookup per packet."""

DataCallback = Callable[[DataReceived], None]
WatchdogEvent = PeerSilent | PeerResumed
WatchdogCallback = Callable[[WatchdogEvent], None]
ControlCallback = Callable[[ControlReceived | ControlExpired], None]

logger = logging.getLogger("tdtp")


class DatagramSender(Protocol):
    def sendto(self, data: bytes, addr: Address | None = None, /) -> None: ...


_NO_SEQ: Final = -(1 << 40)
"""Below every sequence number: ``_newest_seq`` before the first sample."""


def format_address(addr: Address | None) -> str:
    """``host:port`` (``[v6]:port`` for IPv6), or ``-`` when there is none yet."""
    if addr is None:
        return "-"
    host, port = addr[0], addr[1]
    return f"[{host}]:{port}" if ":" in str(host) else f"{host}:{port}"


def rx_time_of(stamp: int, now: float, wall_ns: int) -> float | None:
    """A kernel receive time (``SO_TIMESTAMPNS``: ns on the realtime clock, -1 for none) on the
    :func:`~tdtp.aio.timer.monotonic` clock, given both clocks read at ``now`` / ``wall_ns``."""
    if stamp < 0:
        return None
    return now - (wall_ns - stamp) * 1e-9


class Endpoint:
    """A master's or slave's end of one association. Create it with :func:`tdtp.connect` or take it
    from a :class:`tdtp.Server`; do not construct it directly."""

    def __init__(
        self,
        conn: Connection,
        transport: DatagramSender,
        *,
        connected: bool,
        timer: str = "auto",
        on_data: DataCallback | None = None,
        on_watchdog: WatchdogCallback | None = None,
        on_closed: Callable[[Endpoint], None] | None = None,
        on_established: Callable[[Endpoint], None] | None = None,
        transport_closed: Callable[[], Awaitable[None]] | None = None,
        reconnect: ReconnectPolicy | None = None,
        new_connection: Callable[[], Connection] | None = None,
        outbox: SocketOutbox | None = None,
        reopen_to: Callable[[], Address | None] | None = None,
    ) -> None:
        self._conn = conn
        self._socket = transport
        self._sendto = transport.sendto  # bound once: looked up by name per datagram otherwise
        # On the batched datagram layer: the socket's outbox, which takes what is sent while the
        # loop serves a wake-up (tdtp.aio.outbox) and sends it with one sendmmsg at its end.
        self._out = outbox
        self._queue_out = outbox.append if outbox is not None else None
        self._connected = connected
        loop = asyncio.get_running_loop()
        self._loop = loop
        # One timer per loop for all endpoints (tdtp.aio.loop_timers); this is our entry in it.
        self._timer: TimerEntry = loop_timers(loop, timer).entry(self._on_timer)
        self._on_data = on_data
        self._on_watchdog = on_watchdog
        self._on_closed = on_closed
        self._on_established = on_established
        self.rendezvous: Traversal | None = None
        """Met through a rendezvous: its path, candidates tried (``.report()``); else ``None``."""
        self._transport_closed = transport_closed
        self._queue: deque[DataReceived] = deque()
        self._max_queue = conn.config.max_pending_events
        self._newest: DataReceived | None = None
        self._newest_seq = _NO_SEQ  # its seq, kept natively (DataReceived is a plain class)
        self._data_waiters: list[asyncio.Future[None]] = []
        self._watch_waiters: list[asyncio.Future[None]] = []
        self._control: deque[ControlReceived] = deque()
        self._control_waiters: list[asyncio.Future[None]] = []
        self._on_control: ControlCallback | None = None
        self.control_expired: ControlExpired | None = None
        """The control channel gave up on unacknowledged messages (they are in it), else ``None``."""
        self._established: asyncio.Future[None] = loop.create_future()
        self._closed: asyncio.Future[ConnectionClosed] = loop.create_future()
        self._close_event: ConnectionClosed | None = None
        self._silence: PeerSilent | None = None
        self._resumed: PeerResumed | None = None
        self._send_errors = 0
        self._reconnect = (
            Reconnector(reconnect, new_connection, loop, reopen_to)
            if reconnect is not None and new_connection is not None
            else None
        )
        self.reconnects = (
            self._reconnect.record if self._reconnect is not None else ReconnectRecord()
        )
        """What reconnecting did (a master with ``reconnect=``): sessions reopened and why, samples
        of the sessions before the current one. All zero otherwise."""
        self._closing = False
        self._demux_batch = 0
        """The server's receive batch that last handed us a datagram (its Demultiplexer's count)."""
        self._path_set: PathSet | None = None  # a multipath session's paths, once asked for
        size = getattr(transport, "get_write_buffer_size", None)
        if size is not None and size() > 0:
            conn.pause_sending()  # a shared socket that is backed up already

    @property
    def _transport(self) -> DatagramSender:
        """What this endpoint sends through (the socket's transport or the datagram layer)."""
        return self._socket

    @_transport.setter
    def _transport(self, transport: DatagramSender) -> None:
        self._socket = transport
        self._sendto = transport.sendto

    # ------------------------------------------------------------------ introspection

    @property
    def connection(self) -> Connection:
        """The sans-IO core underneath (for inspection; drive it only through this endpoint)."""
        return self._conn

    @property
    def peer(self) -> Address | None:
        """The peer's address once known (a slave's master, a master's slave), else ``None``."""
        return self._conn.peer

    @property
    def paths(self) -> PathSet:
        """A multipath session's paths: their figures, events, and ``add`` / ``remove``."""
        if self._path_set is None:
            self._path_set = PathSet(self)
        return self._path_set

    @property
    def stats(self) -> ConnectionStats:
        """The core's live counters plus srtt, loss-event rate p and the allowed rate."""
        return self._conn.stats

    @property
    def send_errors(self) -> int:
        """Datagrams the socket refused with an error (ICMP unreachable reported on a send, no
        buffer space): lost like any other. Datagrams held back while the send buffer is full are
        in ``stats.samples_blocked`` instead."""
        return self._send_errors + self._conn.transmit_errors

    @send_errors.setter
    def send_errors(self, value: int) -> None:
        self._send_errors = value - self._conn.transmit_errors

    @property
    def timer_kind(self) -> str:
        """Which deadline timer paces this endpoint: ``"timerfd"`` or ``"call_at"``."""
        return self._timer.kind

    @property
    def sockets(self) -> str:
        """What carries this endpoint's datagrams: ``"datagram layer (compiled, coalescing)"``
        (the C engine, segmenting bursts; :mod:`tdtp.aio.datagram`), ``"datagram layer
        (compiled)"``, ``"datagram layer (pure)"``, or ``"loop's transport"``."""
        return layer_description(layer_under(self._socket))

    @property
    def datagram_layer_stats(self) -> dict[str, int] | None:
        """The datagram layer's counters for this endpoint's socket (system calls, datagrams and
        bytes each way, coalesced sends and receives, errors by kind; shared by every session of
        a :class:`~tdtp.Server`), or ``None`` on the loop's transport."""
        layer = layer_under(self._socket)
        return None if layer is None else layer.stats

    @property
    def netem_link(self) -> NetemLink | None:
        """The emulated link this endpoint sends through (``netem=`` on connect or listen), or
        ``None``: its ``stats``, and with a trace its ``trace_queue``."""
        link: NetemLink | None = getattr(getattr(self._socket, "line", None), "link", None)
        return link

    @property
    def established(self) -> bool:
        """Whether the association was established (it may have closed since)."""
        return self._established.done() and self._established.exception() is None

    @property
    def is_closed(self) -> bool:
        """Whether the session has ended (:attr:`close_event` says why)."""
        return self._conn.state is State.CLOSED

    @property
    def close_event(self) -> ConnectionClosed | None:
        """Why the association ended (cause and detail), once it has."""
        return self._conn.close_event

    @property
    def peer_silent(self) -> bool:
        """True while nothing has arrived from the peer for ``silence_timeout`` (the watchdog), and
        while there is no session to hear it in: once closed, and while reconnecting."""
        return self._conn.peer_silent or self.reconnects.reopening

    @property
    def write_paused(self) -> bool:
        """True while the socket's send buffer is backed up and data is held back."""
        return self._conn.sending_paused

    @property
    def unread(self) -> int:
        """Samples received and not yet taken by a read (at most ``max_pending_events``)."""
        return len(self._queue)

    def __repr__(self) -> str:
        conn = self._conn
        state = conn.state.value
        if conn.peer_silent:
            state += ", peer silent"
        if conn.sending_paused:
            state += ", send buffer full"
        srtt = conn.stats.srtt
        return (
            f"<Endpoint {conn.role.value} peer={format_address(conn.peer)} {state}"
            f" srtt={srtt * 1e3:.3f}ms unread={len(self._queue)}>"
        )

    # ------------------------------------------------------------------ callbacks

    def set_data_callback(self, on_data: DataCallback | None) -> None:
        """Deliver samples to ``on_data`` as they arrive instead of queueing them for the reads.
        Samples already queued are handed to it at once. ``None`` switches back to queueing."""
        self._on_data = on_data
        if on_data is not None:
            queue = self._queue
            while queue:
                on_data(queue.popleft())

    def set_watchdog_callback(self, on_watchdog: WatchdogCallback | None) -> None:
        """Call ``on_watchdog`` with every :class:`~tdtp.PeerSilent` and :class:`~tdtp.PeerResumed`
        (synchronously, as the event happens: hold or release the machine there)."""
        self._on_watchdog = on_watchdog

    def set_control_callback(self, on_control: ControlCallback | None) -> None:
        """Hand every control message (:class:`~tdtp.ControlReceived`, in order) and a
        :class:`~tdtp.ControlExpired` to ``on_control`` as they happen instead of queueing the
        messages for :meth:`recv_control`; messages already queued go to it at once."""
        self._on_control = on_control
        if on_control is not None:
            queue = self._control
            while queue:
                on_control(queue.popleft())
            self._conn.control_held(0)

    # ------------------------------------------------------------------ sending

    def send(self, payload: bytes | bytearray | memoryview) -> None:
        """Offer the newest sample. Never blocks: the pacer sends it when the rate controller allows,
        and a newer sample offered before then replaces it (counted as superseded). While the
        socket's send buffer is full the sample waits too, and is superseded the same way.

        Raises :class:`~tdtp.PayloadTypeError` for anything but bytes, bytearray or memoryview,
        :class:`~tdtp.PayloadTooLargeError` above the connection's maximum, and
        :class:`~tdtp.EndpointClosedError`, naming the cause, once the association is over."""
        now = monotonic()
        conn = self._conn
        out = self._out
        queue_out = self._queue_out
        transmit = self._sendto
        if out is not None and queue_out is not None:
            owner = out.owner
            if owner.depth:
                transmit = queue_out  # leaves with the rest of the wake-up in one sendmmsg
            elif not owner.direct:
                # On the batched layer, outside a wake-up of ours (an application task): what this
                # pass of the loop sends leaves in one sendmmsg once the callbacks ready now ran.
                owner.hold_until_ready_ran(self._loop)
                transmit = queue_out
            # else: answering the one datagram this wake-up received: to the socket at once
        try:
            # The common case leaves at once: encoded and handed to the socket (or to the outbox)
            # before the connection's bookkeeping (the round trip does not wait for it).
            sent = conn.send_direct(payload, transmit, connected=self._connected, now=now)
        except ConnectionClosedError as exc:
            event = exc.event
            if event is None:
                raise
            raise EndpointClosedError(event) from None
        except ConnectionStateError:
            if not self.reconnects.reopening:
                raise
            # No session while a new one opens: the sample is superseded by the next, not queued.
            self.reconnects.samples_dropped += 1
            return
        if not sent or conn.timer_hint < self._timer.deadline:
            self.flush(now)

    def send_control(self, message: bytes | bytearray | memoryview) -> None:
        """Queue a message on the reliable control channel: the peer gets it exactly once and in
        order, however the network loses, duplicates or reorders it, and samples keep flowing
        meanwhile. Raises as :meth:`send` does (the size limit is ``control_max_message``),
        :class:`~tdtp.ControlQueueFullError` while ``control_window`` messages wait for their
        acknowledgement, and :class:`~tdtp.ControlChannelFailedError` once one was given up."""
        now = monotonic()
        try:
            self._conn.send_control(message, now=now)
        except ConnectionClosedError as exc:
            if exc.event is None:
                raise
            raise EndpointClosedError(exc.event) from None
        except ConnectionStateError:
            record = self.reconnects
            if not record.reopening:
                raise
            why = f" ({record.lost[0]})" if record.lost is not None else ""
            raise ReconnectingError(
                f"no session to send the control message on: the last one ended{why} and the "
                "next is opening; the message was not queued: send it again once the endpoint "
                "is established (await ep.wait_resumed())"
            ) from None
        self.flush(now)

    async def recv_control(self) -> ControlReceived:
        """The peer's next control message, in the order it sent them. Raises
        :class:`EndpointClosedError` once the association is over and every message is read."""
        queue = self._control
        while True:
            if queue:
                message = queue.popleft()
                self._conn.control_held(len(queue))
                return message
            if self._close_event is not None:
                raise EndpointClosedError(self._close_event)
            await self._wait(self._control_waiters)

    def control_messages(self) -> AsyncIterator[ControlReceived]:
        """``async for message in ep.control_messages()``: every control message, in order."""
        return samples_until_closed(self.recv_control)

    # ------------------------------------------------------------------ reading

    def latest(self) -> DataReceived | None:
        """The newest sample received so far, without waiting; ``None`` before the first. Newest by
        sequence number: one the reorder wait still holds behind a gap counts
        (:attr:`Connection.newest_held`), so a control loop never waits for a gap.

        It returns the same sample again until a newer one arrives (compare ``seq`` to tell). Unread
        older samples are skipped, and counted in ``stats.samples_skipped``: this is the read for a
        control loop that runs at its own rate.
        """
        self._take_newest()
        newest = self._newest
        # A sample held by the reorder wait is newer than anything delivered: a latest-value
        # reader gets it now instead of a gap's wait later (it is still delivered in order).
        held = self._conn.newest_held
        if held is not None and held.seq > self._newest_seq:
            self._newest = newest = held
            self._newest_seq = held.seq
        return newest

    async def recv_latest(self) -> DataReceived:
        """Wait for a sample newer than any read before and return the newest, skipping (and
        counting in ``stats.samples_skipped``) the older ones still unread. Raises
        :class:`EndpointClosedError` once the association is over and nothing is unread."""
        while True:
            sample = self._take_newest()
            if sample is not None:
                return sample
            if self._close_event is not None:
                raise EndpointClosedError(self._close_event)
            await self._wait(self._data_waiters)

    async def recv(self) -> DataReceived:
        """The next sample in arrival order: every sample, oldest first.

        Samples wait in a queue of at most ``max_pending_events`` (4096); an application that reads
        slower than they arrive gets ever older samples until the queue is full, then the oldest are
        discarded (``stats.events_discarded``). A control loop wants :meth:`recv_latest` or
        ``async for sample in ep`` instead. Raises :class:`EndpointClosedError` once the association
        is over and every sample that arrived before has been taken.
        """
        queue = self._queue
        while True:
            if queue:
                return queue.popleft()
            if self._close_event is not None:
                raise EndpointClosedError(self._close_event)
            await self._wait(self._data_waiters)

    def __aiter__(self) -> AsyncIterator[DataReceived]:
        """``async for sample in ep``: the newest sample each time the loop asks (latest value);
        samples that arrived meanwhile are skipped and counted. Ends when the association does."""
        return samples_until_closed(self.recv_latest)

    def stream(self) -> AsyncIterator[DataReceived]:
        """``async for sample in ep.stream()``: every sample in arrival order (see :meth:`recv`)."""
        return samples_until_closed(self.recv)

    def _take_newest(self) -> DataReceived | None:
        queue = self._queue
        if not queue:
            return None
        sample = queue[-1]
        skipped = len(queue) - 1
        queue.clear()
        if skipped:
            self._conn.stats.samples_skipped += skipped
        return sample

    # ------------------------------------------------------------------ the watchdog

    async def wait_silent(self) -> PeerSilent:
        """Wait until the peer has been silent for ``silence_timeout`` (at once if it is silent now)
        and return that :class:`~tdtp.PeerSilent`. Raises :class:`EndpointClosedError` if the
        association ends first: the peer is then gone for good."""
        while True:
            if self._close_event is not None:
                raise EndpointClosedError(self._close_event)
            silence = self._silence
            if silence is not None:
                return silence
            await self._wait(self._watch_waiters)

    async def wait_resumed(self) -> PeerResumed | None:
        """Wait until a silent peer is heard again and return the :class:`~tdtp.PeerResumed`;
        ``None`` at once if the peer is not silent. Raises :class:`EndpointClosedError` if the
        association ends first (the silence outlasted ``idle_timeout``)."""
        silence = self._silence
        if silence is None:
            return None
        while self._silence is silence:
            if self._close_event is not None:
                raise EndpointClosedError(self._close_event)
            await self._wait(self._watch_waiters)
        return self._resumed

    # ------------------------------------------------------------------ ending

    async def close(self, *, restarting: bool = False) -> None:
        """Send CLOSE to the peer and release the timer (and a master's socket). Idempotent.

        ``restarting=True``: this side stops but will be back soon (a service restart): the CLOSE
        says ``RESTARTING``, and a reconnecting master reopens at once (PROTOCOL.md 5.2). The
        default says ``NORMAL``: the session is over for good."""
        if not isinstance(restarting, bool):
            raise ArgumentTypeError(f"restarting must be True or False, got {restarting!r}")
        self._closing = True
        if self._reconnect is not None:
            self._reconnect.cancel()
        if not self.is_closed:
            self._conn.close(now=monotonic(), restarting=restarting)
            self.flush()
        self._release()
        closed = self._transport_closed
        if closed is not None:
            self._transport_closed = None
            await closed()

    async def wait_closed(self) -> ConnectionClosed:
        """Wait until the association ends, for whatever reason, and say why."""
        return await asyncio.shield(self._closed)

    async def __aenter__(self) -> Endpoint:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    # ------------------------------------------------------------------ driven by the transport

    def datagram_received(self, data: bytes, addr: Address) -> None:
        """The transport's hand-off: one datagram from ``addr``, taken in and answered at once."""
        now = monotonic()
        self._conn.receive_datagram(data, addr, now=now)
        self.flush(now)

    def receive_batch(
        self,
        datas: list[bytes],
        addrs: list[Address],
        stamps: list[int] | None,
        classes: list[int] | None,
    ) -> None:
        """A batch from the datagram layer (one ``recvmmsg``), oldest first: one clock read, every
        datagram handed to the core in order, one flush. ``stamps`` are the kernel's receive times
        (``SO_TIMESTAMPNS``, ns on the realtime clock) and ``classes`` the TOS / traffic class
        bytes, parallel to ``datas`` (-1 where the kernel gave none), or ``None``."""
        now = monotonic()
        wall = time.time_ns() if stamps is not None else 0
        out = self._out
        owner = out.owner if out is not None else None
        count = len(datas)
        if owner is not None:
            # A wake-up: what this batch makes us send leaves in one sendmmsg (one datagram's
            # answers leave at once: nothing to batch them with).
            owner.hold_batch(count)
        try:
            conn = self._conn
            for i in range(len(datas)):
                rx_time = rx_time_of(stamps[i], now, wall) if stamps is not None else None
                ecn = classes[i] & 3 if classes is not None and classes[i] >= 0 else None
                conn.receive_datagram(datas[i], addrs[i], now=now, rx_time=rx_time, ecn=ecn)
                if conn.state is CLOSED:
                    self.flush(now)  # ended (or reopening): what follows finds the next session
                    conn = self._conn
            self.flush(now)
        finally:
            if owner is not None:
                owner.release_batch(count)

    def pause_writing(self) -> None:
        """The socket's send buffer is backed up: hold data until :meth:`resume_writing`."""
        if not self._conn.sending_paused:
            self._conn.pause_sending()
            if logger.isEnabledFor(logging.DEBUG):
                logger.debug("%r: send buffer full, holding data", self)

    def resume_writing(self) -> None:
        """The send buffer has drained: the newest held sample may leave."""
        if self._conn.sending_paused:
            self._conn.resume_sending()
            if not self.is_closed:
                self.flush()

    def evict(self, detail: str, now: float) -> bytes | None:
        """Slave side: end this session so that a new master can have its slot (the server's slot
        policy chose it; the session closes as ``EVICTED``, its master gets a CLOSE ``EVICTED``,
        which is returned so that the server can repeat it)."""
        close = self._conn.evict(detail, now=now)
        self.flush(now)
        self._release()
        return close

    def fail_open(self, exc: BaseException) -> None:
        """The transport reported an error that ends a connection still opening (e.g. ICMP port
        unreachable): :meth:`wait_established` raises ``exc``, and the endpoint lets go of its
        timer and socket at once (nobody listens: there is no one to send a CLOSE to)."""
        if not self._established.done():
            self._established.set_exception(exc)
            self._established.exception()  # retrieved: connect() reports it itself
            self._release()

    def _on_timer(self) -> None:
        now = monotonic()
        self._conn.handle_timer(now=now)
        self.flush(now)

    async def wait_established(self) -> None:
        """Wait until the opening handshake completes; raises what ended it otherwise."""
        await asyncio.shield(self._established)

    def flush(self, now: float | None = None) -> None:
        """Hand the core's events to the application, send what is due and re-arm the timer: what
        follows every input. The endpoint's own entry points (:meth:`send`, :meth:`datagram_received`,
        the timer) do it themselves; a driver that feeds :attr:`connection` directly (the server and
        its demultiplexer) calls it after each batch. ``now``: the clock read with the input, if any.
        """
        conn = self._conn
        event = conn.next_event()  # (rather than asking pending_events first: one call less)
        if event is not None and conn.state is ESTABLISHED:
            # The application first: a sample its callback sends in answer leaves at once (with
            # the ACK the connection owes riding on it) instead of after the connection's own
            # datagrams. Not once the session ends: its CLOSE leaves before the application hears
            # (the event taken waits until then).
            self._drain_events(event)
            if conn is not self._conn:
                return
            event = None
            now = None  # the callbacks took time, and what they sent was stamped after `now`
        datagrams = conn.datagrams_to_send(now=monotonic() if now is None else now)
        out = self._out
        if datagrams and out is not None and out.owner.depth:
            out.extend(datagrams, self._connected)  # one sendmmsg when the wake-up ends
        elif datagrams:
            sendto = self._sendto
            connected = self._connected
            for data, addr in datagrams:
                try:
                    if connected:
                        sendto(data)
                    else:
                        sendto(data, addr)
                except OSError:
                    # No buffer space or an ICMP error reported on this send: lost like any other.
                    self._send_errors += 1
        if self._path_set is not None:
            self._path_set.flush()  # what leaves through a multipath master's other sockets
        if event is None:
            event = conn.next_event()
        if event is not None:
            self._drain_events(event)
            if conn is not self._conn:
                return  # the session ended and a new one is opening: it flushes on its own
        timer = self._timer
        if conn.timer_hint < timer.deadline:
            # Something may be due before the armed deadline (the connection says so instead of
            # being asked after every input). Only an earlier deadline re-arms: most inputs push
            # deadlines *later* (keep-alive and watchdog move with every packet); an expiry at the
            # older, earlier time just runs handle_timer, which is harmless, and re-arms then.
            if conn.state is CLOSED:
                self._release()
                return
            deadline = conn.get_timer()
            if deadline is not None and deadline < timer.deadline:
                timer.arm(deadline)

    # ------------------------------------------------------------------ internals

    def _drain_events(self, event: Event | None = None) -> None:
        """Take the connection's events, ``event`` (the first, already taken) and those after it."""
        conn = self._conn
        on_data = self._on_data
        if event is None:
            event = conn.next_event()
        while event is not None:
            if isinstance(event, DataReceived):
                seq = event.seq
                if seq > self._newest_seq:
                    self._newest = event
                    self._newest_seq = seq
                if on_data is not None:
                    try:
                        on_data(event)
                    except Exception as exc:  # the application's error: reported, then on
                        self._callback_failed("on_data", exc)
                else:
                    queue = self._queue
                    if len(queue) >= self._max_queue:
                        queue.popleft()  # bounded: the oldest unread sample goes
                        conn.stats.events_discarded += 1
                    queue.append(event)
                    if self._data_waiters:
                        out = self._out
                        if out is not None and out.owner.depth:
                            # The readers woken now answer within this wake-up's batch.
                            out.owner.hold_until_ready_ran(self._loop)
                        self._wake(self._data_waiters)
            elif isinstance(event, ControlReceived | ControlExpired):
                self._on_control_event(event)
            elif isinstance(event, PathChanged):
                self.paths.on_event(event)
            else:
                self._on_other_event(event)
            event = conn.next_event()

    def _on_control_event(self, event: ControlReceived | ControlExpired) -> None:
        if isinstance(event, ControlExpired):
            self.control_expired = event
            logger.warning("%s: %s", self._name(), event.detail)
        on_control = self._on_control
        if on_control is not None:
            try:
                on_control(event)
            except Exception as exc:  # the application's error: reported, then on
                self._callback_failed("on_control", exc)
            return
        if isinstance(event, ControlReceived):
            self._control.append(event)
            self._conn.control_held(len(self._control))
            if self._control_waiters:
                self._wake(self._control_waiters)

    def _call_watchdog(self, event: PeerSilent | PeerResumed) -> None:
        on_watchdog = self._on_watchdog
        if on_watchdog is not None:
            try:
                on_watchdog(event)
            except Exception as exc:  # the application's error: reported, then on
                self._callback_failed("on_watchdog", exc)

    def _callback_failed(self, name: str, exc: Exception) -> None:
        """An application callback raised: report it as asyncio reports a failed callback (the
        loop's exception handler logs it) and go on. The session must not stop being served (its
        timer re-armed, its other events delivered) because a callback failed once."""
        self._loop.call_exception_handler(
            {
                "message": f"{self._name()}: the {name} callback raised",
                "exception": exc,
                "endpoint": self,
            }
        )

    def _on_other_event(
        self, event: ConnectionEstablished | ConnectionClosed | PeerSilent | PeerResumed
    ) -> None:
        if isinstance(event, PeerSilent):
            self._silence = event
            wait = self._reconnect.silence_wait(event) if self._reconnect is not None else None
            if wait is not None:
                self._loop.call_later(wait, self._silence_check, self._conn, event)
            logger.warning(
                "%s: nothing heard from the peer for %.3f s",
                self._name(),
                event.detected_at - event.since,
            )
            self._wake(self._watch_waiters)
            self._call_watchdog(event)
        elif isinstance(event, PeerResumed):
            self._silence = None
            self._resumed = event
            logger.info("%s: peer heard again after %.3f s", self._name(), event.silent_for)
            self._wake(self._watch_waiters)
            self._call_watchdog(event)
        elif isinstance(event, ConnectionEstablished):
            logger.info("%s: connection established", self._name())
            if self.reconnects.reopening:
                self._reopened()
            if not self._established.done():
                self._established.set_result(None)
            if self._on_established is not None:
                self._on_established(self)  # every session: a reconnecting one's next ones too
        else:
            reconnect = self._reconnect
            if reconnect is not None and reconnect.may_reopen(
                event, established=self.established, closing=self._closing
            ):
                self._reopen(reconnect, event)
                return
            self._close_event = event
            self.reconnects.reopening = False  # (a reconnection that gave up)
            logger.info(
                "%s: connection closed (%s: %s)", self._name(), event.cause.value, event.detail
            )
            if not self._closed.done():
                self._closed.set_result(event)
            if not self._established.done():
                self._established.set_exception(EndpointClosedError(event))
                self._established.exception()  # mark retrieved: connect() reports it itself
            self._wake(self._data_waiters)
            self._wake(self._watch_waiters)
            self._wake(self._control_waiters)

    # ------------------------------------------------------------------ reconnecting (a master)

    def _reopen(self, reconnect: Reconnector, event: ConnectionClosed) -> None:
        """The session ended for a reason a new one can cure: open the next on the same socket
        (tdtp.aio.reconnect). While there is none, the watchdog says the peer is silent."""
        old = self._conn
        if not self.reconnects.reopening:
            why = "silence" if event.cause is CloseCause.LOCAL_CLOSE else event.cause.value
            logger.warning(
                "%s: session lost (%s: %s); opening a new one", self._name(), why, event.detail
            )
            if self._silence is None:
                now = monotonic()
                self._silence = silence = PeerSilent(now - old.quiet_for(now), now)
                self._wake(self._watch_waiters)
                self._call_watchdog(silence)
        self._conn = reconnect.reopen(old, event, self._start_reopen)

    def _start_reopen(self) -> None:
        reconnect = self._reconnect
        if reconnect is not None and not self._closing and reconnect.open(self._conn, monotonic()):
            self.flush()

    def _reopened(self) -> None:
        now = monotonic()
        if self._reconnect is not None:
            self._reconnect.reopened(now)
        logger.info("%s: reconnected (%d so far)", self._name(), self.reconnects.count)
        silence = self._silence
        if silence is not None:
            # The application held its machine on PeerSilent: the peer is back, in a new session.
            self._silence = None
            self._resumed = resumed = PeerResumed(now - silence.since, now)
            self._wake(self._watch_waiters)
            self._call_watchdog(resumed)

    def _silence_check(self, conn: Connection, event: PeerSilent) -> None:
        """``after_silence`` after the slave went silent: if it still is, open a new session."""
        if conn is not self._conn or self._closing or conn.silent_since != event.since:
            return
        if conn.state is not State.ESTABLISHED or self._reconnect is None:
            return
        self._reconnect.silence_reopen = True
        conn.close(now=monotonic())
        self.flush()

    def _name(self) -> str:
        return f"tdtp {self._conn.role.value} {format_address(self._conn.peer)}"

    async def _wait(self, waiters: list[asyncio.Future[None]]) -> None:
        waiter: asyncio.Future[None] = self._loop.create_future()
        waiters.append(waiter)
        try:
            await waiter
        finally:
            if waiter in waiters:
                waiters.remove(waiter)

    @staticmethod
    def _wake(waiters: list[asyncio.Future[None]]) -> None:
        for waiter in waiters:
            if not waiter.done():
                waiter.set_result(None)
        waiters.clear()

    def _release(self) -> None:
        self._drain_events()
        self._timer.close()
        if self._on_closed is not None:
            callback, self._on_closed = self._on_closed, None
            callback(self)
