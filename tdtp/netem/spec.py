"""What one direction of an emulated link does to datagrams, in tc-netem's terms.

Every class here is a frozen, validated dataclass that mirrors one tc-netem option (``tc-netem(8)``,
kernel ``net/sched/sch_netem.c``). Units are SI and fractions, never tc's scaled integers:

* times are **seconds** (``0.02`` for ``20ms``),
* probabilities and correlations are **fractions** in [0, 1] (``0.01`` for ``1%``),
* rates are **bits per second** (``1e6`` for ``1mbit``; note that tc's ``bps`` unit means *bytes* per
  second),
* sizes and overheads are **bytes**.

``str(spec)`` renders netem syntax and :func:`~tdtp.netem.parser.parse_netem` reads it back: ``parse_netem(str(spec))
== spec`` holds exactly for every valid spec (numbers are rendered through :mod:`decimal`, so no float
rounding creeps in).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import Context, Decimal
from typing import Final, Literal, TypeAlias, get_args

from tdtp.errors import InvalidArgumentError
from tdtp.netem.trace_file import Trace

__all__ = [
    "DEFAULT_LIMIT",
    "DISTRIBUTIONS",
    "CorruptSpec",
    "DelaySpec",
    "Distribution",
    "DuplicateSpec",
    "GilbertElliottLoss",
    "LossModel",
    "NetemSpec",
    "RandomLoss",
    "RateSpec",
    "ReorderSpec",
    "StateLoss",
    "TraceSpec",
]

Distribution: TypeAlias = Literal["uniform", "normal", "pareto", "paretonormal"]
"""Shape of the delay jitter. ``uniform`` is netem's default (no table loaded)."""

DISTRIBUTIONS: Final[tuple[str, ...]] = get_args(Distribution)

DEFAULT_LIMIT: Final = 1000
"""tc's default ``limit``: packets the queue may hold."""

MAX_LIMIT: Final = 2**32 - 1
MAX_LIMIT_BYTES: Final = 2**63 - 1
MAX_SEED: Final = 2**64 - 1
_S32_MIN: Final = -(2**31)
_S32_MAX: Final = 2**31 - 1
_U32_MAX: Final = 2**32 - 1

EXACT: Final = Context(prec=1000)
"""Decimal context wide enough that the conversions between netem text and floats here are exact."""


# -- validation helpers ------------------------------------------------------------------------------


def _is_real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _check_fraction(owner: str, name: str, value: float) -> None:
    if not (_is_real(value) and 0.0 <= value <= 1.0):
        raise InvalidArgumentError(
            f"{owner}.{name} must be a fraction between 0 and 1 (0.01 for 1 %), got {value!r}"
        )


def _check_time(owner: str, name: str, value: float) -> None:
    if not (_is_real(value) and math.isfinite(value) and value >= 0.0):
        raise InvalidArgumentError(
            f"{owner}.{name} must be a finite, non-negative number of seconds (0.02 for 20 ms), "
            f"got {value!r}"
        )


def _check_int(owner: str, name: str, value: int, low: int, high: int, hint: str) -> None:
    if not (isinstance(value, int) and not isinstance(value, bool) and low <= value <= high):
        raise InvalidArgumentError(f"{owner}.{name} must be a whole number {hint}, got {value!r}")


# -- rendering helpers (exact: parse(render(x)) == x) --------------------------------------------------


def exact_decimal(value: float) -> Decimal:
    """The shortest decimal that reads back as ``value`` (``repr``), as an exact :class:`Decimal`."""
    if value == 0:
        return Decimal(0)  # also maps -0.0 to 0
    return Decimal(repr(float(value)))


def _plain(value: Decimal) -> str:
    """``value`` in positional notation without trailing zeros (``100``, ``0.5``, never ``1E+2``)."""
    text = format(value.normalize(EXACT), "f")
    return "0" if text in ("-0", "") else text


def format_percent(fraction: float) -> str:
    """``0.01`` -> ``1%``."""
    return _plain(EXACT.multiply(exact_decimal(fraction), Decimal(100))) + "%"


def format_time(seconds: float) -> str:
    """``0.02`` -> ``20ms``; seconds, milliseconds or microseconds, whichever reads best."""
    if seconds >= 1:
        unit, scale = "s", 1
    elif seconds >= 0.001 or seconds == 0:
        unit, scale = "ms", 1000
    else:
        unit, scale = "us", 1_000_000
    return _plain(EXACT.multiply(exact_decimal(seconds), Decimal(scale))) + unit


_RATE_UNITS: Final = (
    ("tbit", 10**12),
    ("gbit", 10**9),
    ("mbit", 10**6),
    ("kbit", 10**3),
)


def format_rate(bits_per_second: float) -> str:
    """``1e6`` -> ``1mbit``: the largest SI bit unit the value reaches."""
    for unit, scale in _RATE_UNITS:
        if bits_per_second >= scale:
            return _plain(EXACT.divide(exact_decimal(bits_per_second), Decimal(scale))) + unit
    return _plain(exact_decimal(bits_per_second)) + "bit"


def complement(fraction: float) -> float:
    """``1 - fraction`` computed the way the parser computes it (exactly, then rounded once)."""
    return float(EXACT.subtract(Decimal(1), exact_decimal(fraction)))


def _format_complement(fraction: float) -> str:
    """``1 - fraction`` as a percentage that reads back (via :func:`complement`) as ``fraction``."""
    one_minus = EXACT.subtract(Decimal(1), exact_decimal(fraction))
    return _plain(EXACT.multiply(one_minus, Decimal(100))) + "%"


# -- delay ----------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class DelaySpec:
    """``delay TIME [JITTER [CORRELATION]] [distribution NAME]``.

    Each packet is held ``delay + jitter * X`` seconds, X drawn from ``distribution``:

    * ``uniform`` (netem's default): X uniform in [-1, 1), so the delay is uniform in
      [delay - jitter, delay + jitter).
    * ``normal``: X standard normal (mean 0, standard deviation 1, so ``jitter`` is the standard
      deviation), clipped at +/-4 like netem's 16-bit table.
    * ``pareto``: X = 4/3 * (P - 1.5) with P Pareto of shape 3 and scale 1 (NISTnet's table that netem
      ships): a floor of -2/3 and a long right tail clipped at +4 like the table, which leaves a mean
      of -0.033 and a standard deviation of 0.82 (0 and 1.15 without the clip).
    * ``paretonormal``: 0.25 * normal + 0.75 * pareto, both read at the *same* quantile (netem's table is
      the sum of the two quantile functions, not a mixture): mean -0.025, standard deviation 0.83.

    ``correlation`` makes successive draws depend on each other with netem's approximation (see
    :class:`~tdtp.netem.link.NetemLink`). A packet's delay can come out negative (jitter larger than
    the delay): it then leaves at once, as in netem.
    """

    delay: float
    """Mean delay in seconds (``latency``/``delay`` in tc)."""
    jitter: float = 0.0
    """Spread in seconds: half-width for ``uniform``, scale (standard deviation) for the tables."""
    correlation: float = 0.0
    """Weight of the previous random draw in the next one, a fraction; needs a jitter."""
    distribution: Distribution = "uniform"

    def __post_init__(self) -> None:
        _check_time("DelaySpec", "delay", self.delay)
        _check_time("DelaySpec", "jitter", self.jitter)
        _check_fraction("DelaySpec", "correlation", self.correlation)
        if self.distribution not in DISTRIBUTIONS:
            raise InvalidArgumentError(
                f"DelaySpec.distribution must be one of {', '.join(DISTRIBUTIONS)}, "
                f"got {self.distribution!r}"
            )
        if self.correlation and not self.jitter:
            raise InvalidArgumentError(
                "DelaySpec.correlation correlates the jitter, so it needs one: "
                "give a jitter too, e.g. 'delay 20ms 5ms 25%'"
            )
        if self.distribution != "uniform" and not (self.delay and self.jitter):
            raise InvalidArgumentError(
                f"distribution {self.distribution} needs both a delay and a jitter (tc refuses it "
                f"otherwise): e.g. 'delay 20ms 5ms distribution {self.distribution}'"
            )

    def __str__(self) -> str:
        parts = ["delay", format_time(self.delay)]
        if self.jitter:
            parts.append(format_time(self.jitter))
            if self.correlation:
                parts.append(format_percent(self.correlation))
        if self.distribution != "uniform":
            parts += ["distribution", self.distribution]
        return " ".join(parts)


# -- loss models ----------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RandomLoss:
    """``loss [random] PERCENT [CORRELATION]``: each packet is lost with probability ``p``.

    With a ``correlation``, netem mixes the previous uniform draw into the next one. This is an
    approximation, not a true correlation, and it also moves the effective loss rate away from ``p``
    (the mixed draw is no longer uniform): the reason ``tc-netem(8)`` calls it deprecated. Prefer
    :class:`GilbertElliottLoss` or :class:`StateLoss` for bursty loss.
    """

    p: float
    correlation: float = 0.0

    def __post_init__(self) -> None:
        _check_fraction("RandomLoss", "p", self.p)
        _check_fraction("RandomLoss", "correlation", self.correlation)

    def __str__(self) -> str:
        text = f"loss {format_percent(self.p)}"
        return f"{text} {format_percent(self.correlation)}" if self.correlation else text


@dataclass(frozen=True, slots=True)
class StateLoss:
    """``loss state P13 [P31 [P32 [P23 [P14]]]]``: netem's 4-state Markov loss model (the GI model of
    Salsano et al.).

    States: 1 = packets received within a gap period, 2 = received within a burst, 3 = lost within a
    burst, 4 = isolated loss. A packet is lost when the chain moves *into* state 3 or 4 (or stays in 3).
    ``pXY`` is the probability of moving from state X to state Y at a packet; state 4 always returns to 1.
    tc's defaults for omitted values are ``p31 = 1 - p13``, ``p32 = 0``, ``p23 = 1``, ``p14 = 0`` (with
    only ``p13`` the model is Bernoulli loss with rate ``p13``); here ``p31`` must be given, the parser
    fills it in.
    """

    p13: float
    p31: float
    p32: float = 0.0
    p23: float = 1.0
    p14: float = 0.0

    def __post_init__(self) -> None:
        for name in ("p13", "p31", "p32", "p23", "p14"):
            _check_fraction("StateLoss", name, getattr(self, name))
        if self.p13 + self.p14 > 1.0:
            raise InvalidArgumentError(
                "StateLoss: p13 + p14 is the chance of leaving state 1 and cannot exceed 1 "
                f"(got {self.p13!r} + {self.p14!r}); lower one of them"
            )
        if self.p31 + self.p32 > 1.0:
            raise InvalidArgumentError(
                "StateLoss: p31 + p32 is the chance of leaving state 3 and cannot exceed 1 "
                f"(got {self.p31!r} + {self.p32!r}); lower one of them"
            )

    def __str__(self) -> str:
        values = [self.p13, self.p31, self.p32, self.p23, self.p14]
        defaults = [None, complement(self.p13), 0.0, 1.0, 0.0]
        while len(values) > 1 and values[-1] == defaults[len(values) - 1]:
            values.pop()
        return "loss state " + " ".join(format_percent(v) for v in values)


@dataclass(frozen=True, slots=True)
class GilbertElliottLoss:
    """``loss gemodel P [R [1-H [1-K]]]``: the Gilbert-Elliott two-state loss model.

    A good state G and a bad state B; at each packet the chain moves G -> B with probability ``p`` and
    B -> G with probability ``r``. The packet is lost with probability ``1 - k`` if the chain was in G
    and ``1 - h`` if it was in B (the state before the move, as in the kernel).

    **Argument meaning.** ``h`` and ``k`` here are the model's own parameters, the probabilities that a
    packet *gets through* in the bad and in the good state. netem's command line takes their
    complements, the *loss* probabilities: ``loss gemodel 1% 30% 70% 0.1%`` means p = 1 %, r = 30 %,
    1-h = 70 % (so ``h = 0.3``) and 1-k = 0.1 % (so ``k = 0.999``). The parser and ``str()`` convert.
    tc's defaults for omitted values are ``r = 1 - p``, ``1-h = 100 %`` (``h = 0``) and ``1-k = 0``
    (``k = 1``), which make it Bernoulli loss with rate ``p``; here ``r`` must be given, the parser
    fills it in.
    """

    p: float
    """Probability of moving from the good to the bad state at a packet."""
    r: float
    """Probability of moving from the bad to the good state at a packet."""
    h: float = 0.0
    """Probability that a packet gets through in the bad state (netem's argument is ``1-h``)."""
    k: float = 1.0
    """Probability that a packet gets through in the good state (netem's argument is ``1-k``)."""

    def __post_init__(self) -> None:
        for name in ("p", "r", "h", "k"):
            _check_fraction("GilbertElliottLoss", name, getattr(self, name))

    @property
    def loss_in_bad(self) -> float:
        """``1 - h``: loss probability in the bad state (netem's third argument)."""
        return 1.0 - self.h

    @property
    def loss_in_good(self) -> float:
        """``1 - k``: loss probability in the good state (netem's fourth argument)."""
        return 1.0 - self.k

    def __str__(self) -> str:
        parts = [format_percent(self.p), format_percent(self.r)]
        parts += [_format_complement(self.h), _format_complement(self.k)]
        # Drop trailing arguments equal to tc's defaults: 1-k = 0, then 1-h = 1, then r = 1 - p.
        if self.k == 1.0:
            parts.pop()
            if self.h == 0.0:
                parts.pop()
                if self.r == complement(self.p):
                    parts.pop()
        return "loss gemodel " + " ".join(parts)


LossModel: TypeAlias = RandomLoss | StateLoss | GilbertElliottLoss
"""Any of netem's three loss models."""


# -- duplicate, corrupt, reorder ------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class DuplicateSpec:
    """``duplicate PERCENT [CORRELATION]``: a packet is sent twice with probability ``p``.

    The copy goes through loss, corruption, the queue limit, reordering and delay on its own (netem
    re-enqueues it), but is never duplicated again.
    """

    p: float
    correlation: float = 0.0

    def __post_init__(self) -> None:
        _check_fraction("DuplicateSpec", "p", self.p)
        _check_fraction("DuplicateSpec", "correlation", self.correlation)

    def __str__(self) -> str:
        text = f"duplicate {format_percent(self.p)}"
        return f"{text} {format_percent(self.correlation)}" if self.correlation else text


@dataclass(frozen=True, slots=True)
class CorruptSpec:
    """``corrupt PERCENT [CORRELATION]``: one random bit of the packet is flipped with probability ``p``."""

    p: float
    correlation: float = 0.0

    def __post_init__(self) -> None:
        _check_fraction("CorruptSpec", "p", self.p)
        _check_fraction("CorruptSpec", "correlation", self.correlation)

    def __str__(self) -> str:
        text = f"corrupt {format_percent(self.p)}"
        return f"{text} {format_percent(self.correlation)}" if self.correlation else text


@dataclass(frozen=True, slots=True)
class ReorderSpec:
    """``reorder PERCENT [CORRELATION] [gap DISTANCE]``: some packets skip the delay.

    After ``gap - 1`` delayed packets, each packet is sent at once (overtaking the delayed ones) with
    probability ``p``; once one is, the count restarts. ``gap = 1`` (tc's default) makes every packet a
    candidate; ``reorder 100% gap 5`` sends every 5th packet at once. Needs a delay
    (:class:`NetemSpec` checks), as in tc.
    """

    p: float
    correlation: float = 0.0
    gap: int = 1

    def __post_init__(self) -> None:
        _check_fraction("ReorderSpec", "p", self.p)
        _check_fraction("ReorderSpec", "correlation", self.correlation)
        _check_int("ReorderSpec", "gap", self.gap, 1, _U32_MAX, "of packets, at least 1")

    def __str__(self) -> str:
        parts = ["reorder", format_percent(self.p)]
        if self.correlation:
            parts.append(format_percent(self.correlation))
        if self.gap != 1:
            parts += ["gap", str(self.gap)]
        return " ".join(parts)


# -- rate -----------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RateSpec:
    """``rate RATE [PACKETOVERHEAD [CELLSIZE [CELLOVERHEAD]]]``: a serialising link of ``rate_bps``.

    A packet of ``n`` bytes occupies the link for :meth:`transmit_time` seconds: ``n + packet_overhead``
    bytes, rounded up to whole cells of ``cell_size`` bytes each carrying ``cell_overhead`` extra bytes
    when ``cell_size`` is set (ATM: 48 and 5), at ``rate_bps``. Packets leave one after another:
    ``send_time = max(now + delay, previous send_time) + transmit_time``.

    ``n`` is the datagram handed to the link (the UDP payload); add the headers the real wire would carry
    as ``packet_overhead`` (28 for IPv4 + UDP, 42 with Ethernet) to emulate a wire rate.
    """

    rate_bps: float
    """Bits per second (``1mbit`` = 1e6). Not tc's ``bps`` unit, which is bytes per second."""
    packet_overhead: int = 0
    """Bytes added to every packet; may be negative (e.g. -14 to strip an Ethernet header)."""
    cell_size: int = 0
    """Cell payload size in bytes, 0 for no cells."""
    cell_overhead: int = 0
    """Bytes added to every cell (needs ``cell_size``); may be negative."""

    def __post_init__(self) -> None:
        if not (_is_real(self.rate_bps) and math.isfinite(self.rate_bps) and self.rate_bps > 0):
            raise InvalidArgumentError(
                "RateSpec.rate_bps must be a positive, finite number of bits per second "
                f"(1e6 for 1mbit), got {self.rate_bps!r}"
            )
        _check_int(
            "RateSpec", "packet_overhead", self.packet_overhead, _S32_MIN, _S32_MAX, "of bytes"
        )
        _check_int("RateSpec", "cell_size", self.cell_size, 0, _U32_MAX, "of bytes, 0 for no cells")
        _check_int("RateSpec", "cell_overhead", self.cell_overhead, _S32_MIN, _S32_MAX, "of bytes")
        if self.cell_overhead and not self.cell_size:
            raise InvalidArgumentError(
                "RateSpec.cell_overhead only applies to cells: set cell_size too "
                "(e.g. 'rate 2mbit 0 48 5' for ATM)"
            )

    def wire_bytes(self, size: int) -> int:
        """Bytes a ``size``-byte datagram occupies on the emulated link (never negative)."""
        total = size + self.packet_overhead
        if self.cell_size:
            cells = -(-total // self.cell_size)  # ceil; the kernel adds a cell for a remainder
            total = cells * (self.cell_size + self.cell_overhead)
        return max(total, 0)

    def transmit_time(self, size: int) -> float:
        """Seconds the link is busy sending a ``size``-byte datagram."""
        return self.wire_bytes(size) * 8 / self.rate_bps

    def __str__(self) -> str:
        parts = ["rate", format_rate(self.rate_bps)]
        positional = [self.packet_overhead, self.cell_size, self.cell_overhead]
        while positional and positional[-1] == 0:
            positional.pop()
        parts += [str(value) for value in positional]
        return " ".join(parts)


# -- trace ------------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TraceSpec:
    """``trace FILE [offset TIME] [overhead N]`` (a tdtp extension): a link whose capacity follows a
    recorded trace in Mahimahi's format (see :mod:`tdtp.netem.trace_file` and
    :mod:`tdtp.netem.trace_queue`).

    ``offset`` starts the trace that far in (it still loops at its end); ``overhead`` bytes are added
    to every datagram when counting the trace's 1500-byte opportunities and the queue's
    ``limit-bytes`` (28 for the IPv4 + UDP headers a real link would carry besides the payload).
    """

    trace: Trace
    """The opportunities, read from the file by :func:`~tdtp.netem.trace_file.load_trace`."""
    offset: float = 0.0
    """Seconds into the trace at which the link starts."""
    overhead: int = 0
    """Bytes added to every datagram's size; may be negative (never below 0 in total)."""

    def __post_init__(self) -> None:
        if not isinstance(self.trace, Trace):
            raise InvalidArgumentError(
                "TraceSpec.trace must be a Trace: load one with tdtp.netem.load_trace(path), "
                f"got {self.trace!r}"
            )
        _check_time("TraceSpec", "offset", self.offset)
        _check_int("TraceSpec", "overhead", self.overhead, _S32_MIN, _S32_MAX, "of bytes")

    @property
    def path(self) -> str:
        """The trace file's path, as given (what ``str(spec)`` writes back)."""
        return self.trace.path

    def __str__(self) -> str:
        parts = ["trace", self.trace.path]
        if self.offset:
            parts += ["offset", format_time(self.offset)]
        if self.overhead:
            parts += ["overhead", str(self.overhead)]
        return " ".join(parts)


# -- the whole direction --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class NetemSpec:
    """Everything netem does to one direction. The empty spec impairs nothing.

    Build one directly, or from netem syntax with :meth:`parse` / :func:`~tdtp.netem.parse_netem`;
    ``str(spec)`` gives the netem syntax back.
    """

    delay: DelaySpec | None = None
    loss: LossModel | None = None
    duplicate: DuplicateSpec | None = None
    corrupt: CorruptSpec | None = None
    reorder: ReorderSpec | None = None
    rate: RateSpec | None = None
    limit: int = DEFAULT_LIMIT
    """Packets the queue may hold; a packet arriving when ``limit`` are held is dropped (DropTail)."""
    seed: int | None = None
    """Seed of the random generator (netem's ``seed``); ``None`` for a fresh one per link."""
    trace: TraceSpec | None = None
    """A recorded capacity instead of a ``rate`` (a tdtp extension): the queue and ``delay`` then
    follow Mahimahi's link (docs/NETEM.md, "Recorded traces")."""
    limit_bytes: int | None = None
    """Bytes the queue may hold instead of packets (a tdtp extension); ``limit`` must then be left
    at its default, which is not used."""

    def __post_init__(self) -> None:
        parts: tuple[tuple[str, object, type], ...] = (
            ("delay", self.delay, DelaySpec),
            ("duplicate", self.duplicate, DuplicateSpec),
            ("corrupt", self.corrupt, CorruptSpec),
            ("reorder", self.reorder, ReorderSpec),
            ("rate", self.rate, RateSpec),
            ("trace", self.trace, TraceSpec),
        )
        for name, value, kind in parts:
            if value is not None and not isinstance(value, kind):
                raise InvalidArgumentError(
                    f"NetemSpec.{name} must be a {kind.__name__} or None, got {value!r}"
                )
        if self.loss is not None and not isinstance(
            self.loss, RandomLoss | StateLoss | GilbertElliottLoss
        ):
            raise InvalidArgumentError(
                "NetemSpec.loss must be a RandomLoss, StateLoss or GilbertElliottLoss or None, "
                f"got {self.loss!r}"
            )
        _check_int("NetemSpec", "limit", self.limit, 0, MAX_LIMIT, "of packets")
        if self.limit_bytes is not None:
            _check_int("NetemSpec", "limit_bytes", self.limit_bytes, 0, MAX_LIMIT_BYTES, "of bytes")
            if self.limit != DEFAULT_LIMIT:
                raise InvalidArgumentError(
                    "give the queue's size in packets (limit) or in bytes (limit-bytes), not both"
                )
        if self.trace is not None and self.rate is not None:
            raise InvalidArgumentError(
                "a trace and a rate both set the link's capacity: give one of them "
                "(the trace's capacity is its recorded one)"
            )
        if self.seed is not None:
            _check_int("NetemSpec", "seed", self.seed, 0, MAX_SEED, "from 0 to 2**64 - 1")
        if (
            self.reorder is not None
            and self.reorder.p > 0
            and not (self.delay and self.delay.delay)
        ):
            raise InvalidArgumentError(
                "reordering needs a delay: netem sends a reordered packet at once and delays the "
                "others, so add one, e.g. 'delay 10ms reorder 25%'"
            )

    def __str__(self) -> str:
        parts = [
            str(part)
            for part in (
                self.delay,
                self.loss,
                self.duplicate,
                self.corrupt,
                self.reorder,
                self.rate,
                self.trace,
            )
            if part is not None
        ]
        if self.limit_bytes is not None:
            parts.append(f"limit-bytes {self.limit_bytes}")
        elif self.limit != DEFAULT_LIMIT or not parts:
            parts.append(f"limit {self.limit}")
        if self.seed is not None:
            parts.append(f"seed {self.seed}")
        return " ".join(parts)
