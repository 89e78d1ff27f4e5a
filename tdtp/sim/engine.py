"""A discrete-event network simulator in virtual time: events, packets, nodes, links and routes.

* :class:`Simulator` keeps a heap of events ordered by ``(time, insertion order)``: two events due at
  the same instant run in the order they were scheduled, so a run is a pure function of its inputs.
* :class:`Timer` is a re-armable deadline on top of it (a TCP retransmission timer, a connection's
  ``get_timer()``): re-arming it later costs nothing, earlier pushes one event.
* :class:`Link` is one direction of a wire: a DropTail queue (``limit``, in packets) served at the
  link ``rate``, then a fixed propagation delay, both given in netem syntax
  (``"rate 1mbit delay 10ms limit 15"``). :meth:`Network.connect` makes the two directions of a
  symmetric link. With ``byte_limit`` the queue counts bytes instead, as ns-2's ``Queue/DropTail``
  with ``queue_in_bytes_`` does.
* A link can follow a recorded capacity instead of a rate: ``"delay 20ms trace FILE limit-bytes
  150000"`` serves the queue at the trace's opportunities with Mahimahi's semantics
  (:class:`~tdtp.netem.TraceQueue`, shared with :class:`~tdtp.netem.NetemLink`); its clock starts
  with the link, at the trace's ``offset``.
* :class:`Node` is a host or a router: packets addressed to it go to the agent bound to their
  destination port; others are forwarded on the static route to their destination
  (:meth:`Network.compute_routes`: fewest hops, ties broken by the order links were created).

The queue holds only the packets waiting for the wire and the one being serialised, as a router's
DropTail queue (ns-2's ``Queue/DropTail``) does; packets propagating are not counted. (netem's own
``delay`` would count them: its tfifo holds every delayed packet, so on a 1 Mbit/s link with 10 ms of
delay, about ten 125-byte packets on the wire would shrink a 15-packet queue to five.) With ``limit``
N the link holds at most N packets, the one being serialised included, exactly as ns-2's DropTail
with ``limit_`` N (it drops an arrival when ``length + 1 >= limit_``, the packet on the wire not
counted). Serialisation follows netem's rate rule, and the drop decision is the one a
:class:`~tdtp.netem.NetemLink` with the same rate and limit makes; the link does it itself, one event
per busy period rather than two per packet, because the simulator spends most of its time here.

A byte-counted queue (``byte_limit`` B) drops an arrival of ``size`` bytes when the bytes *waiting*
(the packet being serialised not counted) plus ``size`` reach B: ns-2's test
``byteLength() + size >= limit_ * mean_pktsize_``. A packet-counted queue gives a 40-byte ACK the same
slot as a 1040-byte segment; a byte-counted one charges it 40 bytes.

Packets do not need real bytes: a :class:`Packet` carries its size in bytes on the wire (IP header
included) and any payload object (a TDTP datagram, a TCP segment).
"""

from __future__ import annotations

import dataclasses
import heapq
import math
import random
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any, Final, Protocol

from tdtp.errors import InvalidArgumentError
from tdtp.netem import NetemSpec, RateSpec, TraceQueue, parse_netem
from tdtp.netem.spec import RandomLoss

__all__ = [
    "Agent",
    "DropListener",
    "Link",
    "LinkStats",
    "Network",
    "Node",
    "Packet",
    "Simulator",
    "Timer",
]


class Simulator:
    """Virtual time and the event heap.

    Events are ``(time, order, callback, args)``; :meth:`run` pops them in ``(time, order)`` order and
    calls ``callback(*args)`` with :attr:`now` set to ``time``. Scheduling in the past is an error:
    virtual time never goes backwards.
    """

    __slots__ = ("_heap", "_order", "events_run", "now")

    def __init__(self) -> None:
        self.now = 0.0
        self._heap: list[tuple[float, int, Callable[..., None], tuple[Any, ...]]] = []
        self._order = 0
        self.events_run = 0
        """Events executed so far (a cost measure for benchmarks)."""

    def call_at(self, when: float, callback: Callable[..., None], *args: Any) -> None:
        """Run ``callback(*args)`` at virtual time ``when`` (at or after :attr:`now`)."""
        if when < self.now:
            if when < self.now - 1e-9 or math.isnan(when):
                raise InvalidArgumentError(
                    f"cannot schedule at t={when!r}, before the current time {self.now!r}: "
                    "virtual time only moves forward"
                )
            when = self.now
        self._order += 1
        heapq.heappush(self._heap, (when, self._order, callback, args))

    def call_later(self, delay: float, callback: Callable[..., None], *args: Any) -> None:
        """Call ``callback(*args)`` ``delay`` virtual seconds from now."""
        self.call_at(self.now + delay, callback, *args)

    def next_time(self) -> float | None:
        """When the next event is due, or ``None`` when nothing is scheduled."""
        return self._heap[0][0] if self._heap else None

    def run(self, until: float) -> None:
        """Run every event due at or before ``until``; then :attr:`now` is ``until``."""
        heap = self._heap
        pop = heapq.heappop
        count = 0
        while heap and heap[0][0] <= until:
            when, _, callback, args = pop(heap)
            self.now = when
            callback(*args)
            count += 1
        self.events_run += count
        self.now = max(self.now, until)


class Timer:
    """A deadline that can be moved at will; ``callback(now)`` runs when it is reached.

    Setting it earlier than the event already scheduled pushes a new event; setting it later (the common
    case: a TCP retransmission timer restarted by every ACK) only records the new deadline, and the early
    event re-schedules itself when it fires. Superseded events find they are not the one expected and do
    nothing, so there is no cancellation and the heap holds at most a few events per timer.
    """

    __slots__ = ("_callback", "_scheduled", "_sim", "deadline")

    def __init__(self, sim: Simulator, callback: Callable[[float], None]) -> None:
        self._sim = sim
        self._callback = callback
        self._scheduled = math.inf  # time of the earliest event of ours still in the heap
        self.deadline: float | None = None

    def set(self, when: float) -> None:
        """Fire at ``when`` (an earlier time than the one armed moves it; a later one is kept)."""
        self.deadline = when
        if when < self._scheduled:
            self._scheduled = when
            self._sim.call_at(when, self._fire, when)

    def cancel(self) -> None:
        """Disarm: nothing fires until the next :meth:`set`."""
        self.deadline = None

    @property
    def armed(self) -> bool:
        """Whether a deadline is set."""
        return self.deadline is not None

    def _fire(self, when: float) -> None:
        if when != self._scheduled:
            return  # superseded by an earlier event of ours
        self._scheduled = math.inf
        deadline = self.deadline
        if deadline is None:
            return
        if deadline > when:
            self._scheduled = deadline
            self._sim.call_at(deadline, self._fire, deadline)
            return
        self.deadline = None
        self._callback(self._sim.now)


class DropListener(Protocol):
    """Told when the network drops a packet it owns (a queue overflow or a random loss)."""

    def on_drop(self, packet: Packet, now: float) -> None: ...


class Packet:
    """One IP packet in flight. ``size`` is its length on the wire in bytes, IP header included."""

    __slots__ = ("dport", "dst", "owner", "payload", "sent_at", "size", "sport", "src")

    def __init__(
        self,
        src: str,
        sport: int,
        dst: str,
        dport: int,
        size: int,
        payload: object,
        sent_at: float,
        owner: DropListener | None = None,
    ) -> None:
        self.src = src
        self.sport = sport
        self.dst = dst
        self.dport = dport
        self.size = size
        self.payload = payload
        self.sent_at = sent_at
        self.owner = owner

    def __repr__(self) -> str:
        return (
            f"Packet({self.src}:{self.sport} -> {self.dst}:{self.dport}, {self.size} B, "
            f"sent {self.sent_at:.6f})"
        )


class Agent(Protocol):
    """Whatever is bound to a port of a host: it takes the packets addressed to that port."""

    def receive(self, packet: Packet, now: float) -> None: ...


@dataclasses.dataclass(slots=True)
class LinkStats:
    """What one direction of a link carried."""

    packets: int = 0
    """Packets offered to the link."""
    bytes: int = 0
    delivered: int = 0
    """Packets that reached the far end."""
    delivered_bytes: int = 0
    dropped: int = 0
    """Packets lost in the link: DropTail overflows plus random losses of the spec."""
    max_queue: int = 0
    """Most packets ever held (waiting or being serialised)."""


def split_spec(spec: NetemSpec) -> tuple[NetemSpec, float]:
    """``spec`` without its delay (the queue and the serialisation) and the delay as a propagation time.

    Only what a wired router link (or a recorded cellular one) does is supported: a fixed delay, a
    rate or a trace, a limit (in packets, or bytes with ``limit-bytes``) and uncorrelated random loss
    before the queue. Jitter, reordering, duplication, corruption and bursty or correlated
    loss raise :class:`ValueError`.
    """
    delay = spec.delay
    if delay is not None and delay.jitter:
        raise InvalidArgumentError(
            f"simulated links have a fixed propagation delay; jitter is not supported ({spec})"
        )
    for name in ("duplicate", "corrupt", "reorder"):
        if getattr(spec, name) is not None:
            raise InvalidArgumentError(f"simulated links do not support netem's {name!r} ({spec})")
    loss = spec.loss
    if loss is not None and not (isinstance(loss, RandomLoss) and not loss.correlation):
        raise InvalidArgumentError(
            f"simulated links support uncorrelated random loss only ({spec})"
        )
    if spec.rate is None and spec.trace is None:
        raise InvalidArgumentError(
            f"a simulated link needs a rate or a trace, e.g. 'rate 1mbit delay 10ms' ({spec})"
        )
    return dataclasses.replace(spec, delay=None), (delay.delay if delay is not None else 0.0)


class Link:
    """One direction of a wire from ``src`` to ``dst``: DropTail queue, serialisation, propagation.

    The queue is a FIFO served at the link rate, so a packet's departure time is known when it joins:
    ``max(now, departure of the packet before it) + size * 8 / rate`` (netem's rate rule). The link
    keeps the departure times of the packets it holds; a packet counts against ``limit`` until its
    last bit has left, exactly what a :class:`~tdtp.netem.NetemLink` with the same rate and limit does,
    and arrives at ``dst`` one propagation delay after it left. One event per link and busy period
    delivers the packets in order.
    """

    __slots__ = (
        "_byte_limit",
        "_departures",
        "_held_bytes",
        "_held_sizes",
        "_limit",
        "_loss",
        "_on_wire",
        "_rng",
        "_sim",
        "_trace",
        "_transmit",
        "_tx_times",
        "delay",
        "dst",
        "name",
        "rate_bps",
        "src",
        "stats",
    )

    def __init__(
        self,
        sim: Simulator,
        src: Node,
        dst: Node,
        spec: NetemSpec,
        *,
        seed: int = 0,
        byte_limit: int | None = None,
    ) -> None:
        queue_spec, delay = split_spec(spec)
        if byte_limit is not None and not (isinstance(byte_limit, int) and byte_limit > 0):
            raise ValueError(f"byte_limit must be a positive number of bytes, got {byte_limit!r}")
        self._sim = sim
        self.src = src
        self.dst = dst
        self.name = f"{src.name}->{dst.name}"
        self.delay: Final = delay
        rate, trace = queue_spec.rate, queue_spec.trace
        self._trace: TraceQueue | None = None
        if trace is not None:
            if byte_limit is not None:
                raise InvalidArgumentError(
                    "a trace link's queue takes its size from its spec: write 'limit-bytes N' "
                    f"there instead of byte_limit ({spec})"
                )
            # The trace's clock starts with the link, so that an offset means the same in every run.
            self._trace = TraceQueue.of(queue_spec, origin=sim.now)
            rate_bps = trace.trace.mean_rate_bps
            self._transmit = RateSpec(rate_bps).transmit_time  # not used: the trace serves
        else:
            assert rate is not None  # split_spec insists
            if queue_spec.limit_bytes is not None:
                if byte_limit is not None:
                    raise InvalidArgumentError(
                        f"give the queue's bytes once: limit-bytes or byte_limit ({spec})"
                    )
                byte_limit = queue_spec.limit_bytes
            rate_bps = rate.rate_bps
            self._transmit = rate.transmit_time
        self.rate_bps: Final = rate_bps
        """Bits per second: the rate, or a trace's mean capacity."""
        self._tx_times: dict[int, float] = {}  # serialisation time by packet size
        self._limit = queue_spec.limit
        self._byte_limit = byte_limit
        loss = queue_spec.loss
        self._loss = loss.p if isinstance(loss, RandomLoss) else 0.0
        self._rng = random.Random(seed)
        self._departures: deque[float] = deque()  # of the packets held, oldest first
        self._held_sizes: deque[int] = deque()  # byte-counted queue only
        self._held_bytes = 0
        self._on_wire: deque[tuple[float, Packet]] = deque()  # (arrival time at dst, packet)
        self.stats = LinkStats()

    @property
    def queued(self) -> int:
        """Packets in the queue now, the one being serialised included."""
        now = self._sim.now
        return sum(1 for departure in self._departures if departure > now)

    @property
    def limit(self) -> int:
        """The queue's limit in packets (ignored when :attr:`byte_limit` is set)."""
        return self._limit

    @property
    def byte_limit(self) -> int | None:
        """The queue's limit in bytes, or ``None`` when it counts packets (:attr:`limit`)."""
        return self._byte_limit

    def send(self, packet: Packet, now: float) -> None:
        """Offer ``packet`` to the link at ``now``: queued, or dropped (and its owner told)."""
        stats = self.stats
        size = packet.size
        stats.packets += 1
        stats.bytes += size
        departures = self._departures
        byte_limit = self._byte_limit
        while departures and departures[0] <= now:  # these have left: no longer queued
            departures.popleft()
            if byte_limit is not None:
                self._held_bytes -= self._held_sizes.popleft()
        held = len(departures)
        trace = self._trace
        departure = 0.0
        if self._loss and self._rng.random() < self._loss:
            dropped = True
        elif trace is not None:
            offered = trace.offer(now, size)
            dropped = offered is None
            departure = offered if offered is not None else 0.0
        elif byte_limit is None:
            dropped = held >= self._limit
        else:
            waiting = self._held_bytes - self._held_sizes[0] if held else 0
            dropped = waiting + size >= byte_limit
        if dropped:
            stats.dropped += 1
            owner = packet.owner
            if owner is not None:
                owner.on_drop(packet, now)
            return
        if trace is None:
            transmit = self._tx_times.get(size)
            if transmit is None:
                transmit = self._tx_times[size] = self._transmit(size)
            departure = (departures[-1] if held else now) + transmit
        departures.append(departure)
        if byte_limit is not None:
            self._held_sizes.append(size)
            self._held_bytes += size
        if held >= stats.max_queue:
            stats.max_queue = held + 1
        on_wire = self._on_wire
        on_wire.append((departure + self.delay, packet))
        if len(on_wire) == 1:
            self._sim.call_at(departure + self.delay, self._arrive)

    def _arrive(self) -> None:
        """Packets reach ``dst`` in order (the delay is fixed, departures are FIFO)."""
        sim = self._sim
        now = sim.now
        on_wire = self._on_wire
        dst = self.dst
        stats = self.stats
        while on_wire and on_wire[0][0] <= now:
            packet = on_wire.popleft()[1]
            stats.delivered += 1
            stats.delivered_bytes += packet.size
            dst.receive(packet, now)
        if on_wire:
            sim.call_at(on_wire[0][0], self._arrive)

    def __repr__(self) -> str:
        return f"Link({self.name}, {self.rate_bps:g} bit/s, {self.delay * 1000:g} ms)"


class Node:
    """A host or a router. Agents bind to ports; everything else is forwarded on its route."""

    __slots__ = ("_sim", "agents", "links", "name", "routes")

    def __init__(self, sim: Simulator, name: str) -> None:
        self._sim = sim
        self.name = name
        self.agents: dict[int, Agent] = {}
        self.links: list[Link] = []
        """Outgoing links, in creation order."""
        self.routes: dict[str, Link] = {}
        """Next hop by destination node name."""

    def bind(self, port: int, agent: Agent) -> None:
        """Attach ``agent`` to ``port``: packets for it are handed to ``agent.receive``."""
        if port in self.agents:
            raise InvalidArgumentError(f"port {port} of {self.name} is already bound")
        self.agents[port] = agent

    def send(self, packet: Packet, now: float) -> None:
        """Put a packet on the route to its destination (delivered locally if that is us)."""
        if packet.dst == self.name:
            self.receive(packet, now)
            return
        link = self.routes.get(packet.dst)
        if link is None:
            raise LookupError(f"{self.name} has no route to {packet.dst!r}")
        link.send(packet, now)

    def receive(self, packet: Packet, now: float) -> None:
        """A packet arrived: to the agent bound to its port if it is for this node, else routed on."""
        if packet.dst != self.name:
            self.send(packet, now)
            return
        agent = self.agents.get(packet.dport)
        if agent is not None:
            agent.receive(packet, now)

    def __repr__(self) -> str:
        return f"Node({self.name})"


class Network:
    """Nodes, links and static routes around one :class:`Simulator`."""

    def __init__(self, sim: Simulator | None = None, *, seed: int = 0) -> None:
        self.sim = sim if sim is not None else Simulator()
        self.seed = seed
        self.nodes: dict[str, Node] = {}
        self.links: list[Link] = []

    def node(self, name: str) -> Node:
        """The node called ``name``, created on first use."""
        node = self.nodes.get(name)
        if node is None:
            node = self.nodes[name] = Node(self.sim, name)
        return node

    def connect(
        self,
        a: str,
        b: str,
        spec: NetemSpec | str,
        reverse: NetemSpec | str | None = None,
        *,
        byte_limit: int | None = None,
    ) -> tuple[Link, Link]:
        """A duplex link: ``spec`` from ``a`` to ``b`` and ``reverse`` (default: the same) back.

        Specs are netem syntax or :class:`NetemSpec`: ``"rate 1mbit delay 10ms limit 15"``. With
        ``byte_limit`` both directions' queues count bytes (the specs' ``limit`` is then ignored).
        """
        forward_spec = parse_netem(spec) if isinstance(spec, str) else spec
        if reverse is None:
            back_spec = forward_spec
        else:
            back_spec = parse_netem(reverse) if isinstance(reverse, str) else reverse
        node_a, node_b = self.node(a), self.node(b)
        made = []
        for src, dst, link_spec in ((node_a, node_b, forward_spec), (node_b, node_a, back_spec)):
            link = Link(
                self.sim,
                src,
                dst,
                link_spec,
                seed=self.seed + len(self.links),
                byte_limit=byte_limit,
            )
            src.links.append(link)
            self.links.append(link)
            made.append(link)
        return made[0], made[1]

    def link(self, a: str, b: str) -> Link:
        """The link from ``a`` to ``b``."""
        for candidate in self.nodes[a].links:
            if candidate.dst.name == b:
                return candidate
        raise LookupError(f"no link from {a!r} to {b!r}")

    def compute_routes(self) -> None:
        """Static shortest-path routes (fewest hops) from every node to every other node."""
        for source in self.nodes.values():
            source.routes.clear()
            first_hop: dict[str, Link] = {}
            frontier: deque[Node] = deque([source])
            seen = {source.name}
            while frontier:
                node = frontier.popleft()
                for link in node.links:
                    nxt = link.dst
                    if nxt.name in seen:
                        continue
                    seen.add(nxt.name)
                    first_hop[nxt.name] = link if node is source else first_hop[node.name]
                    frontier.append(nxt)
            source.routes.update(first_hop)

    def run(self, until: float) -> None:
        """Run the simulation up to ``until`` (virtual seconds)."""
        self.sim.run(until)


def link_spec(rate_bps: float, delay: float, limit: int) -> NetemSpec:
    """The spec of a wired link: ``rate`` bits/s, ``delay`` s of propagation, DropTail ``limit``."""
    from tdtp.netem import DelaySpec  # noqa: PLC0415 - keep the public import list short

    return NetemSpec(
        delay=DelaySpec(delay) if delay else None, rate=RateSpec(rate_bps), limit=limit
    )


def describe(links: Iterable[Link]) -> list[dict[str, Any]]:
    """JSON-ready statistics of some links."""
    return [
        {"link": link.name, "rate_bps": link.rate_bps, "delay": link.delay}
        | dataclasses.asdict(link.stats)
        for link in links
    ]
