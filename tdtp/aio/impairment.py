"""Network impairment on real sockets: a netem link between an endpoint and its socket.

The kernel here has no ``sch_netem``, so tdtp emulates it in-process. A :class:`DelayLine` holds a
sans-IO :class:`~tdtp.netem.NetemLink` (delay, jitter, loss, duplication, corruption, reordering, rate
and queue limit with netem's semantics) and hands each datagram on when the link delivers it. Deliveries
are timed by the same precise deadline timer that paces data packets (timerfd where available), so an
emulated 20 ms delay is 20 ms, not 20 ms plus up to one millisecond of timer rounding.

Two places to put one:

* :class:`ImpairedTransport` wraps a socket's ``sendto``: what this side sends is impaired.
* :func:`impaired_receiver` wraps a ``datagram_received`` callback: what this side receives is impaired.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from tdtp.aio.timer import DeadlineTimer, create_timer, monotonic
from tdtp.netem import NetemLink, NetemSpec, parse_netem
from tdtp.session.events import Address

DeliverFn = Callable[[bytes, Address | None], None]


def as_spec(spec: NetemSpec | str) -> NetemSpec:
    """A spec from netem syntax (``"delay 20ms 5ms loss 1%"``) or as is."""
    return parse_netem(spec) if isinstance(spec, str) else spec


class DelayLine:
    """Datagrams in at :meth:`put`, out through ``deliver`` at the link's delivery times."""

    def __init__(
        self,
        link: NetemLink,
        deliver: DeliverFn,
        *,
        loop: asyncio.AbstractEventLoop | None = None,
        timer: str = "auto",
    ) -> None:
        self.link = link
        self._deliver = deliver
        loop = loop if loop is not None else asyncio.get_running_loop()
        self._timer: DeadlineTimer = create_timer(loop, self._on_timer, prefer=timer)
        self._on_drained: Callable[[], None] | None = None
        self.errors = 0
        """Deliveries the socket refused (full buffer, ICMP error): lost like any other datagram."""

    @property
    def pending(self) -> int:
        """Datagrams still inside the emulated link."""
        return self.link.pending

    def put(self, data: bytes, addr: Address | None = None) -> None:
        now = monotonic()
        self.link.send(data, now, addr)
        self._run(now)

    def change(self, spec: NetemSpec | str) -> None:
        """Impair what is put from now on with ``spec`` (``tc qdisc change``); see
        :meth:`NetemLink.change`. ``"loss 100%"`` takes the link down, the old spec brings it back."""
        self.link.change(as_spec(spec))
        self._run(monotonic())

    def close_when_drained(self, callback: Callable[[], None]) -> None:
        """Call ``callback`` once every datagram inside the link has been delivered (or now)."""
        self._on_drained = callback
        self._run(monotonic())

    def close(self) -> None:
        """Stop at once; datagrams still inside the link are discarded."""
        self._timer.close()

    def _on_timer(self) -> None:
        self._run(monotonic())

    def _run(self, now: float) -> None:
        deliver = self._deliver
        for data, tag in self.link.deliver(now):
            try:
                deliver(data, tag)  # type: ignore[arg-type]  # tags are the addresses put() stored
            except OSError:
                self.errors += 1
        if self._timer.closed:
            return
        upcoming = self.link.next_delivery()
        if upcoming is None and self._on_drained is not None:
            self._timer.close()
            callback, self._on_drained = self._on_drained, None
            callback()
            return
        self._timer.arm(upcoming)


class ImpairedTransport:
    """A datagram transport whose ``sendto`` goes through an emulated link first."""

    def __init__(
        self,
        transport: asyncio.DatagramTransport,
        spec: NetemSpec | str,
        *,
        seed: int | None = None,
        timer: str = "auto",
    ) -> None:
        self._transport = transport
        self.line = DelayLine(NetemLink(as_spec(spec), seed=seed), self._send, timer=timer)

    def _send(self, data: bytes, addr: Address | None) -> None:
        if addr is None:
            self._transport.sendto(data)
        else:
            self._transport.sendto(data, addr)

    def sendto(self, data: bytes, addr: Address | None = None, /) -> None:
        if self._transport.is_closing():
            return
        self.line.put(data, addr)

    def change(self, spec: NetemSpec | str) -> None:
        """Impair from now on with ``spec`` (``tc qdisc change``), e.g. ``"loss 100%"`` for an
        outage and the original spec to end it."""
        self.line.change(spec)

    def get_extra_info(self, name: str, default: object = None) -> object:
        return self._transport.get_extra_info(name, default)

    def get_write_buffer_size(self) -> int:
        """The socket's buffer (the emulated link's queue is the link's business, not a backlog)."""
        size: int = getattr(self._transport, "get_write_buffer_size", lambda: 0)()
        return size

    def is_closing(self) -> bool:
        return self._transport.is_closing()

    def close(self) -> None:
        """Close the socket once the datagrams inside the link are out (a CLOSE still leaves)."""
        self.line.close_when_drained(self._transport.close)


def impaired_receiver(
    receive: Callable[[bytes, Address], None],
    spec: NetemSpec | str,
    *,
    seed: int | None = None,
    timer: str = "auto",
) -> tuple[Callable[[bytes, Address], None], DelayLine]:
    """Wrap a ``datagram_received``-style callback so that what arrives is impaired first."""

    def deliver(data: bytes, addr: Address | None) -> None:
        if addr is not None:
            receive(data, addr)

    line = DelayLine(NetemLink(as_spec(spec), seed=seed), deliver, timer=timer)
    return line.put, line
