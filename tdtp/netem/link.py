"""A sans-IO model of one direction of a tc-netem link.

:class:`NetemLink` takes datagrams with :meth:`~NetemLink.send` and gives them back, impaired, from
:meth:`~NetemLink.deliver` once their delivery time has come. It never reads a clock or touches a
socket: every call takes ``now`` (seconds, any monotonic origin), and :meth:`~NetemLink.next_delivery`
says when to call again. Its decisions depend only on the spec, the seed and the sequence of calls, so a
seeded run replays exactly.

Order of operations per datagram, as in the kernel's ``netem_enqueue``:

1. **duplicate** decision (a copy is made, to be enqueued on its own, never duplicated again);
2. **loss** decision (random, 4-state or Gilbert-Elliott). Loss removes one of the copies: a packet that
   is both duplicated and lost goes on once;
3. **corrupt**: one random bit of the packet flipped (the copy was taken before, so it is unharmed by
   this decision but gets its own);
4. **queue limit** (DropTail): if ``limit`` packets are already held, the packet (and its copy) is
   dropped; the copy, if any, is now enqueued through steps 2 to 6;
5. **reorder** decision: after ``gap - 1`` delayed packets, a packet is sent at once (no delay, no rate)
   with the reorder probability, and the count restarts;
6. **delay + rate**: ``send_time = now + delay`` where delay = ``delay + jitter * X`` from the
   distribution; with a rate, ``send_time = max(now + delay, last_send_time) + transmit_time`` where
   ``last_send_time`` is that of the last packet still held;
7. a FIFO ordered by send time (equal times keep arrival order), so jitter larger than the spacing of
   packets reorders them when no rate is set, as in netem.

With a ``trace`` (a tdtp extension) the rate's place is taken by a recorded capacity: after steps 1 to 3
the datagram joins the trace's DropTail queue (:class:`~tdtp.netem.trace_queue.TraceQueue`: ``limit``
or ``limit-bytes`` count the datagrams waiting there, not those being delayed), and steps 5 and 6 run
from the moment it leaves, so the ``delay`` is propagation after the bottleneck.

Randomness comes from one :class:`random.Random` owned by the link, drawn in the kernel's order.
Correlated values use netem's approximation ``next = (1 - corr) * uniform + corr * last``: a weighted
mix of uniform draws, not a true correlation (it also narrows the spread of the draws, which is why a
correlated ``loss`` does not lose exactly ``P``).
"""

from __future__ import annotations

import heapq
import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from statistics import NormalDist
from typing import Final

from tdtp.errors import ArgumentTypeError, InvalidArgumentError
from tdtp.netem.spec import (
    MAX_SEED,
    Distribution,
    GilbertElliottLoss,
    NetemSpec,
    RandomLoss,
    StateLoss,
)
from tdtp.netem.trace_queue import TraceQueue

__all__ = ["NetemLink", "NetemStats"]

_TABLE_MAX: Final = 32767 / 8192
"""netem's distribution tables are int16 scaled by NETEM_DIST_SCALE (8192): values stop at ~+/-4."""

_STANDARD_NORMAL: Final = NormalDist()


# -- distributions: the analytic form of netem's tables, as quantile functions of a uniform draw --------


def _uniform(v: float) -> float:
    """netem without a table: uniform in [-1, 1)."""
    return 2.0 * v - 1.0


def _normal(v: float) -> float:
    """Standard normal quantile (iproute2 ``normal.c`` tabulates the same), clipped like the table."""
    if v <= 0.0:
        return -_TABLE_MAX
    return max(-_TABLE_MAX, min(_TABLE_MAX, _STANDARD_NORMAL.inv_cdf(v)))


def _pareto(v: float) -> float:
    """iproute2 ``pareto.c``: 4/3 * (P - 1.5) with P = (1 - v) ** (-1/3), Pareto of shape 3, scale 1.

    Its mean is 0 and its floor -2/3; the table's int16 range clips the tail at ~+4.
    """
    return min(_TABLE_MAX, (4.0 / 3.0) * (math.pow(1.0 - v, -1.0 / 3.0) - 1.5))


def _paretonormal(v: float) -> float:
    """iproute2 ``paretonormal.c``: 0.25 * normal + 0.75 * pareto at the same quantile ``v``."""
    return 0.25 * _normal(v) + 0.75 * _pareto(v)


_QUANTILES: Final[dict[Distribution, Callable[[float], float]]] = {
    "uniform": _uniform,
    "normal": _normal,
    "pareto": _pareto,
    "paretonormal": _paretonormal,
}


class _CorrelatedUniform:
    """netem's ``get_crandom``: uniform draws in [0, 1) mixed with the previous one.

    ``next = (1 - corr) * uniform + corr * last``. This is netem's approximation of a correlated
    sequence (lag-1 autocorrelation ``corr``), not a correlated uniform: the mix is no longer uniform.
    Without correlation the draws are plain uniform and no state is kept.
    """

    __slots__ = ("_corr", "_last", "_random")

    def __init__(self, rng: random.Random, correlation: float) -> None:
        self._random = rng.random
        self._corr = correlation
        self._last = rng.random() if correlation else 0.0

    def __call__(self) -> float:
        value = self._random()
        if not self._corr:
            return value
        value = (1.0 - self._corr) * value + self._corr * self._last
        self._last = value
        return value


# -- loss processes ---------------------------------------------------------------------------------------


class _RandomLossProcess:
    __slots__ = ("_draw", "_p")

    def __init__(self, model: RandomLoss, rng: random.Random) -> None:
        self._p = model.p
        self._draw = _CorrelatedUniform(rng, model.correlation)

    def __call__(self) -> bool:
        return bool(self._p) and self._draw() < self._p


class _StateLossProcess:
    """The kernel's ``loss_4state``: one uniform draw per packet compared with the transition
    probabilities out of the current state; lost when the new state is 3 or 4."""

    __slots__ = ("_m", "_random", "state")

    def __init__(self, model: StateLoss, rng: random.Random) -> None:
        self._m = model
        self._random = rng.random
        self.state = 1

    def __call__(self) -> bool:
        m, rnd = self._m, self._random()
        if self.state == 1:
            if rnd < m.p14:
                self.state = 4
                return True
            if rnd < m.p13 + m.p14:
                self.state = 3
                return True
            return False
        if self.state == 2:
            if rnd < m.p23:
                self.state = 3
                return True
            return False
        if self.state == 3:
            if rnd < m.p32:
                self.state = 2
                return False
            if rnd < m.p31 + m.p32:
                self.state = 1
                return False
            return True
        self.state = 1  # state 4: an isolated loss is always followed by a reception
        return False


class _GilbertElliottProcess:
    """The kernel's ``loss_gilb_ell``: a transition draw, then a loss draw with the loss probability of
    the state the packet found (before the transition)."""

    __slots__ = ("_m", "_random", "bad")

    def __init__(self, model: GilbertElliottLoss, rng: random.Random) -> None:
        self._m = model
        self._random = rng.random
        self.bad = False

    def __call__(self) -> bool:
        m, rnd = self._m, self._random
        if not self.bad:
            if rnd() < m.p:
                self.bad = True
            return rnd() < 1.0 - m.k
        if rnd() < m.r:
            self.bad = False
        return rnd() < 1.0 - m.h


def _loss_process(spec: NetemSpec, rng: random.Random) -> Callable[[], bool] | None:
    model = spec.loss
    if isinstance(model, RandomLoss):
        return _RandomLossProcess(model, rng) if model.p else None
    if isinstance(model, StateLoss):
        return _StateLossProcess(model, rng)
    if isinstance(model, GilbertElliottLoss):
        return _GilbertElliottProcess(model, rng)
    return None


# -- the link ------------------------------------------------------------------------------------------


@dataclass(slots=True)
class NetemStats:
    """What a link did, one counter per decision.

    Every datagram is accounted for: ``sent + duplicated == delivered + lost + queue_dropped + pending``.
    """

    sent: int = 0
    """Datagrams passed to :meth:`NetemLink.send`."""
    bytes_in: int = 0
    """Their bytes."""
    delivered: int = 0
    """Datagrams returned by :meth:`NetemLink.deliver` (copies included)."""
    bytes_out: int = 0
    """Their bytes."""
    lost: int = 0
    """Loss decisions that removed a packet or a copy."""
    queue_dropped: int = 0
    """Packets and copies dropped because ``limit`` packets were already held."""
    duplicated: int = 0
    """Duplicate decisions: each adds one datagram to account for."""
    corrupted: int = 0
    """Packets with one bit flipped."""
    reordered: int = 0
    """Packets sent at once by the reorder decision, ahead of delayed ones."""

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict, for a JSON summary."""
        return asdict(self)


class NetemLink:
    """One direction of an emulated netem link. Sans-IO: every call takes ``now``; nothing else moves.

    ``send(datagram, now, tag)`` enqueues a datagram; ``deliver(now)`` returns every ``(datagram, tag)``
    whose delivery time is at or before ``now``, in delivery order; ``next_delivery()`` is the earliest
    pending delivery time (call ``deliver`` then). The ``tag`` is carried along untouched, and copied
    with duplicates: put the destination address there, or anything else the caller needs at delivery.

    ``now`` must not go backwards between calls. The queue ``limit`` counts the datagrams still in
    flight at ``now``: ones whose delivery time has passed but that ``deliver`` has not collected yet do
    not count, as the kernel would already have sent them. So decisions do not depend on how often the
    caller polls; only memory does, so call ``deliver`` whenever ``next_delivery`` comes.

    ``seed`` overrides ``spec.seed``; with neither, a seed is drawn from the OS and kept in
    :attr:`seed`, so any run can be replayed.
    """

    def __init__(self, spec: NetemSpec, *, seed: int | None = None) -> None:
        if not isinstance(spec, NetemSpec):
            raise ArgumentTypeError(
                f"NetemLink needs a NetemSpec (parse_netem('delay 20ms') makes one), "
                f"got {type(spec).__name__}"
            )
        chosen = seed if seed is not None else spec.seed
        if chosen is None:
            chosen = random.SystemRandom().getrandbits(64)
        if not (
            isinstance(chosen, int) and not isinstance(chosen, bool) and 0 <= chosen <= MAX_SEED
        ):
            raise InvalidArgumentError(
                f"seed must be a whole number from 0 to 2**64 - 1, got {chosen!r}"
            )
        self.spec = spec
        self.seed: Final[int] = chosen
        """The seed in use: same seed, same spec and same calls give the same decisions."""
        self.stats: Final = NetemStats()
        self._rng = random.Random(chosen)
        self._configure(spec)

        self._now = -math.inf
        self._seq = 0
        self._counter = 0  # netem's q->counter: packets delayed since the last reordered one
        self._last_send_time = -math.inf  # send time of the latest rate-scheduled packet
        # heap by (send time, seq) of (send time, seq, datagram, tag, bytes counted by limit-bytes)
        self._in_flight: list[tuple[float, int, bytes, object, int]] = []
        self._in_flight_bytes = 0
        self._due: deque[tuple[float, bytes, object]] = deque()  # due, not yet collected

    def change(self, spec: NetemSpec) -> None:
        """Impair from now on with ``spec``, as ``tc qdisc change`` does: datagrams already on the
        link keep their delivery times, the statistics and the random sequence carry on. Switching
        to ``loss 100%`` and back is how to emulate an outage."""
        if not isinstance(spec, NetemSpec):
            raise ArgumentTypeError(f"change() needs a NetemSpec, got {type(spec).__name__}")
        self._configure(spec)
        self.spec = spec

    def _configure(self, spec: NetemSpec) -> None:
        rng = self._rng
        self._delay = spec.delay
        self._quantile = _QUANTILES[spec.delay.distribution] if spec.delay else _uniform
        self._delay_draw = _CorrelatedUniform(rng, spec.delay.correlation if spec.delay else 0.0)
        self._lose = _loss_process(spec, rng)
        dup, corrupt, reorder = spec.duplicate, spec.corrupt, spec.reorder
        self._dup_p = dup.p if dup else 0.0
        self._dup_draw = _CorrelatedUniform(rng, dup.correlation if dup else 0.0)
        self._corrupt_p = corrupt.p if corrupt else 0.0
        self._corrupt_draw = _CorrelatedUniform(rng, corrupt.correlation if corrupt else 0.0)
        self._reorder_p = reorder.p if reorder and reorder.p else 0.0
        self._gap = reorder.gap if self._reorder_p and reorder else 0
        self._reorder_draw = _CorrelatedUniform(rng, reorder.correlation if reorder else 0.0)
        self._rate = spec.rate
        self._limit = spec.limit
        self._limit_bytes = spec.limit_bytes
        old: TraceQueue | None = getattr(self, "_queue", None)
        trace = spec.trace
        if trace is None:
            self._queue = None
        elif old is not None and self.spec.trace == trace:
            old.limit, old.limit_bytes = spec.limit, spec.limit_bytes  # same trace: same clock
        else:
            self._queue = TraceQueue.of(
                spec, not_before=old.last_departure if old is not None else -math.inf
            )

    # -- the sans-IO interface ---------------------------------------------------------------------

    def send(
        self, datagram: bytes | bytearray | memoryview, now: float, tag: object = None
    ) -> None:
        """Put a datagram on the link at time ``now``; ``tag`` comes back with it from :meth:`deliver`.

        The datagram is copied to :class:`bytes` if it is another bytes-like object.
        """
        self._advance(now)
        data = datagram if type(datagram) is bytes else bytes(datagram)
        stats = self.stats
        stats.sent += 1
        stats.bytes_in += len(data)

        copies = 1
        if self._dup_p and self._dup_draw() < self._dup_p:
            copies += 1
            stats.duplicated += 1
        if self._lose is not None and self._lose():
            copies -= 1
            stats.lost += 1
        if not copies:
            return
        copy = data if copies > 1 else None  # taken before corruption, like the kernel's clone
        data = self._maybe_corrupt(data)
        if self._queue is None and self._full(len(data)):
            stats.queue_dropped += copies
            return
        if copy is not None:
            self._enqueue_copy(copy, now, tag)
        self._schedule(data, now, tag)

    def deliver(self, now: float) -> list[tuple[bytes, object]]:
        """Every ``(datagram, tag)`` due at or before ``now``, in delivery order."""
        self._advance(now)
        due = self._due
        out = [(data, tag) for _, data, tag in due]
        due.clear()
        self.stats.delivered += len(out)
        self.stats.bytes_out += sum(len(data) for data, _ in out)
        return out

    def next_delivery(self) -> float | None:
        """When the next datagram is due (possibly already past: then it is due now), or ``None``."""
        if self._due:
            return self._due[0][0]
        if self._in_flight:
            return self._in_flight[0][0]
        return None

    @property
    def pending(self) -> int:
        """Datagrams inside the link: in flight, or due and not yet collected by :meth:`deliver`."""
        return len(self._in_flight) + len(self._due)

    @property
    def trace_queue(self) -> TraceQueue | None:
        """With a ``trace``: its queue (``queued(now)`` gives the datagrams and bytes waiting)."""
        return self._queue

    @property
    def in_flight(self) -> int:
        """Datagrams not yet due at the latest ``now``: what the queue ``limit`` counts (without a
        trace; with one, ``limit`` counts the trace's queue).

        At most ``limit``, or ``limit + 1`` right after a duplicated packet: as in netem, the copy is
        checked against the limit and queued before the original, which then joins without a second
        check.
        """
        return len(self._in_flight)

    def __repr__(self) -> str:
        return f"NetemLink({str(self.spec)!r}, seed={self.seed}, pending={self.pending})"

    # -- internals ------------------------------------------------------------------------------------

    def _advance(self, now: float) -> None:
        if not math.isfinite(now):
            raise InvalidArgumentError(f"now must be a finite time in seconds, got {now!r}")
        if now < self._now:
            raise InvalidArgumentError(
                f"now went backwards ({now!r} after {self._now!r}): pass times from a monotonic clock"
            )
        self._now = now
        queue = self._queue
        if queue is not None and queue.origin is None:
            queue.origin = now  # the trace's clock starts with the first time the link sees
        heap, due = self._in_flight, self._due
        while heap and heap[0][0] <= now:
            send_time, _, data, tag, counted = heapq.heappop(heap)
            self._in_flight_bytes -= counted
            due.append((send_time, data, tag))

    def _maybe_corrupt(self, data: bytes) -> bytes:
        if not (self._corrupt_p and self._corrupt_draw() < self._corrupt_p) or not data:
            return data
        flipped = bytearray(data)
        flipped[self._rng.randrange(len(flipped))] ^= 1 << self._rng.randrange(8)
        self.stats.corrupted += 1
        return bytes(flipped)

    def _enqueue_copy(self, data: bytes, now: float, tag: object) -> None:
        """The duplicate, re-enqueued like a new packet that is not duplicated again."""
        if self._lose is not None and self._lose():
            self.stats.lost += 1
            return
        data = self._maybe_corrupt(data)
        if self._queue is None and self._full(len(data)):
            self.stats.queue_dropped += 1
            return
        self._schedule(data, now, tag)

    def _full(self, size: int) -> bool:
        """netem's limit: the datagrams (or bytes) in flight leave no room for one more."""
        if self._limit_bytes is None:
            return len(self._in_flight) >= self._limit
        return self._in_flight_bytes + self._wire_bytes(size) > self._limit_bytes

    def _wire_bytes(self, size: int) -> int:
        rate = self._rate
        return rate.wire_bytes(size) if rate is not None else size

    def _schedule(self, data: bytes, now: float, tag: object) -> None:
        """Trace queue (if any), reorder decision, then delay and rate; into the time-ordered FIFO."""
        start = now
        counted = 0  # bytes the netem limit counts (none behind a trace: its queue counts)
        if self._queue is not None:
            departure = self._queue.offer(now, len(data))
            if departure is None:
                self.stats.queue_dropped += 1
                return
            start = departure
        elif self._limit_bytes is not None:
            counted = self._wire_bytes(len(data))
        gap = self._gap
        if gap and self._counter >= gap - 1 and self._reorder_draw() < self._reorder_p:
            send_time = start  # sent at once, ahead of the delayed packets (and of the rate)
            self._counter = 0
            self.stats.reordered += 1
        else:
            send_time = start + self._sample_delay()
            rate = self._rate
            if rate is not None:
                if self._last_send_time > now:  # a packet is still held: queue behind it
                    send_time = max(send_time, self._last_send_time)
                send_time += rate.transmit_time(len(data))
                self._last_send_time = send_time
            self._counter += 1
        self._seq += 1
        heapq.heappush(self._in_flight, (send_time, self._seq, data, tag, counted))
        self._in_flight_bytes += counted
        if send_time <= now:  # due at once: leaves before anything still in flight
            self._advance(now)

    def _sample_delay(self) -> float:
        spec = self._delay
        if spec is None:
            return 0.0
        if not spec.jitter:
            return spec.delay  # netem's tabledist returns mu without drawing when sigma is 0
        return spec.delay + spec.jitter * self._quantile(self._delay_draw())
