"""A parser for tc-netem's option syntax: ``parse_netem("delay 20ms 5ms loss 1% rate 1mbit limit 15")``.

It accepts what ``tc qdisc ... netem`` accepts (iproute2 ``tc/q_netem.c``), with tc's units:

* **times**: ``s``/``sec``/``secs``, ``ms``/``msec``/``msecs``, ``us``/``usec``/``usecs`` and
  ``ns``/``nsec``/``nsecs``, case-insensitive. **A time needs its unit** (only ``0`` may stand bare):
  ``tc(8)`` reads a bare number as microseconds, and an iproute2 patch of 2024 ("netem: use 64 bit value
  for latency and jitter") as nanoseconds, while a person who writes ``delay 20`` nearly always means
  milliseconds. A bare time is refused with a message that says so, rather than read in silence.
* **percentages**: ``1%`` or a bare ``1``, both one percent. tc reads a bare number as a percentage too,
  not as a fraction: ``loss 0.5`` is 0.5 %, not 50 %.
* **rates**: ``bit``, ``kbit``, ``mbit``, ``gbit``, ``tbit`` (SI, bits per second), the IEC ``kibit``,
  ``mibit``, ``gibit``, ``tibit``, and the byte units ``bps``, ``kbps``, ``mbps``, ``gbps``, ``tbps``,
  ``kibps``... which in tc mean **bytes** per second; case-insensitive; a bare number is bits per
  second. tc's percentage-of-device rates (``rate 10%``) have no device here and are refused.
* **counts and overheads** (``limit``, ``gap``, overheads, cell size, ``seed``): whole numbers.

Options may come in any order; ``latency`` is a synonym of ``delay`` and ``drop`` of ``loss``; a leading
``netem`` word is skipped, so ``tc`` command tails can be pasted. As extensions, ``rate`` also takes the
keyword forms ``overhead N``, ``cellsize N`` and ``celloverhead N``. ``slot`` (delivery in slots) and
``ecn`` (marking instead of dropping) are not emulated and are refused with a message saying so.

Errors raise :class:`NetemSyntaxError`, a :class:`ValueError` whose message names the offending token,
its position and what was expected.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from decimal import Decimal
from typing import Final, cast

from tdtp.errors import ArgumentTypeError, TdtpError
from tdtp.netem.spec import (
    DISTRIBUTIONS,
    EXACT,
    MAX_LIMIT,
    MAX_LIMIT_BYTES,
    MAX_SEED,
    CorruptSpec,
    DelaySpec,
    Distribution,
    DuplicateSpec,
    GilbertElliottLoss,
    LossModel,
    NetemSpec,
    RandomLoss,
    RateSpec,
    ReorderSpec,
    StateLoss,
    TraceSpec,
)
from tdtp.netem.trace_file import load_trace

__all__ = ["NetemSyntaxError", "parse_netem"]


def _q(token: str) -> str:
    """A token quoted for a message, shortened if it is very long."""
    return repr(token if len(token) <= 40 else token[:37] + "...")


class NetemSyntaxError(TdtpError, ValueError):
    """netem text that does not parse. The message names the token, its position and the fix."""

    def __init__(self, message: str, *, token: str | None, index: int) -> None:
        super().__init__(message)
        self.token = token
        """The offending token, or ``None`` when one is missing at the end of the text."""
        self.index = index
        """1-based position of the token among the whitespace-separated words (one past the end when
        a value is missing at the end)."""


_NUMBER: Final = r"(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?"
_WITH_SUFFIX: Final = re.compile(rf"({_NUMBER})([A-Za-z%]*)")
_UNSIGNED: Final = re.compile(r"[0-9]+")
_SIGNED: Final = re.compile(r"[-+]?[0-9]+")

_TIME_UNITS: Final[dict[str, Decimal]] = {
    "": Decimal("1e-6"),  # tc(8): microseconds; refused by _Parser.time() unless it is zero
    **dict.fromkeys(("s", "sec", "secs"), Decimal(1)),
    **dict.fromkeys(("ms", "msec", "msecs"), Decimal("1e-3")),
    **dict.fromkeys(("us", "usec", "usecs"), Decimal("1e-6")),
    **dict.fromkeys(("ns", "nsec", "nsecs"), Decimal("1e-9")),
}

_RATE_UNITS: Final[dict[str, Decimal]] = {
    "": Decimal(1),  # a bare rate is bits per second
    "bit": Decimal(1),
    "kbit": Decimal(10**3),
    "mbit": Decimal(10**6),
    "gbit": Decimal(10**9),
    "tbit": Decimal(10**12),
    "kibit": Decimal(2**10),
    "mibit": Decimal(2**20),
    "gibit": Decimal(2**30),
    "tibit": Decimal(2**40),
    # tc's byte units: "bps" is BYTES per second.
    "bps": Decimal(8),
    "kbps": Decimal(8 * 10**3),
    "mbps": Decimal(8 * 10**6),
    "gbps": Decimal(8 * 10**9),
    "tbps": Decimal(8 * 10**12),
    "kibps": Decimal(8 * 2**10),
    "mibps": Decimal(8 * 2**20),
    "gibps": Decimal(8 * 2**30),
    "tibps": Decimal(8 * 2**40),
}

_KEYWORDS: Final = (
    "delay",
    "distribution",
    "loss",
    "duplicate",
    "corrupt",
    "reorder",
    "gap",
    "rate",
    "trace",
    "limit",
    "limit-bytes",
    "seed",
)
_ALIASES: Final = {"latency": "delay", "drop": "loss"}

_TIME_HINT: Final = "expected a number with a unit like 20ms"
_PERCENT_HINT: Final = "expected a percentage like 1% (a bare number is a percentage too, as in tc)"
_RATE_HINT: Final = (
    "expected a rate like 1mbit, 500kbit or 2mibit (tc's bps/kbps/mbps units are BYTES per second)"
)


@dataclass
class _Draft:
    """Options as read, before the cross-checks and the final :class:`NetemSpec`."""

    seen: dict[str, int] = field(default_factory=dict)
    """Canonical keyword -> 0-based token index where it appeared."""
    delay: tuple[Decimal, Decimal, Decimal] | None = None
    distribution: Distribution = "uniform"
    loss: LossModel | None = None
    duplicate: DuplicateSpec | None = None
    corrupt: CorruptSpec | None = None
    reorder: tuple[float, float] | None = None
    gap: int = 0
    rate: RateSpec | None = None
    trace: TraceSpec | None = None
    limit: int = 1000
    limit_bytes: int | None = None
    seed: int | None = None


class _Parser:
    def __init__(self, text: str) -> None:
        self.tokens = text.split()
        self.pos = 0
        if self.tokens and self.tokens[0].lower() == "netem":
            self.pos = 1

    # -- positions and errors ----------------------------------------------------------------------

    def where(self, index: int) -> str:
        if index >= len(self.tokens):
            last = f" (after {_q(self.tokens[-1])})" if self.tokens else ""
            return f"at the end{last}"
        before = f"after {_q(self.tokens[index - 1])}" if index > 0 else "at the start"
        return f"at token {index + 1} ({before})"

    def fail(self, problem: str, index: int, hint: str) -> NetemSyntaxError:
        token = self.tokens[index] if index < len(self.tokens) else None
        return NetemSyntaxError(
            f"{problem} {self.where(index)}: {hint}", token=token, index=index + 1
        )

    def take(self, what: str, hint: str) -> tuple[str, int]:
        """The next token, or an error saying that ``what`` is missing."""
        if self.pos >= len(self.tokens):
            raise self.fail(f"missing {what}", self.pos, hint)
        index = self.pos
        self.pos += 1
        return self.tokens[index], index

    def next_is_number(self, *, signed: bool = False) -> bool:
        """tc's NEXT_IS_NUMBER: optional positional values start with a digit (or a sign)."""
        if self.pos >= len(self.tokens):
            return False
        first = self.tokens[self.pos][0]
        return first.isdigit() or first == "." or (signed and first in "+-")

    # -- values --------------------------------------------------------------------------------------

    def value_with_unit(
        self, what: str, hint: str, units: dict[str, Decimal]
    ) -> tuple[Decimal, int]:
        token, index = self.take(what, hint)
        match = _WITH_SUFFIX.fullmatch(token)
        if match is None or match.group(2).lower() not in units:
            raise self.fail(f"bad {what} {_q(token)}", index, hint)
        try:
            value = EXACT.multiply(Decimal(match.group(1)), units[match.group(2).lower()])
            if not math.isfinite(float(value)):
                raise OverflowError
        except (ArithmeticError, ValueError):  # decimal overflow, or beyond a float
            raise self.fail(
                f"bad {what} {_q(token)}", index, "the number is out of range"
            ) from None
        return value, index

    def time(self, what: str = "time") -> Decimal:
        """Seconds, exact. A bare number other than zero is refused: its unit is ambiguous."""
        index = self.pos
        seconds, _ = self.value_with_unit(what, _TIME_HINT, _TIME_UNITS)
        token = self.tokens[index]
        match = _WITH_SUFFIX.fullmatch(token)
        if match is not None and not match.group(2) and seconds != 0:
            raise self.fail(
                f"{what} {_q(token)} has no unit",
                index,
                f"write {token}ms for milliseconds or {token}us for microseconds (tc reads a bare "
                "time as microseconds, newer iproute2 as nanoseconds)",
            )
        return seconds

    def fraction(self, what: str = "percentage") -> Decimal:
        """A percentage as an exact fraction in [0, 1]."""
        token, index = self.take(what, _PERCENT_HINT)
        match = _WITH_SUFFIX.fullmatch(token)
        if match is None or match.group(2) not in ("", "%"):
            raise self.fail(f"bad {what} {_q(token)}", index, _PERCENT_HINT)
        try:
            value = EXACT.divide(Decimal(match.group(1)), Decimal(100))
        except ArithmeticError:  # decimal overflow: far beyond 100 % anyway
            value = Decimal(2)
        if value > 1:
            raise self.fail(f"bad {what} {_q(token)}", index, "a percentage cannot exceed 100%")
        return value

    def optional_fraction(self, what: str) -> Decimal | None:
        return self.fraction(what) if self.next_is_number() else None

    def rate_value(self) -> float:
        token = self.tokens[self.pos] if self.pos < len(self.tokens) else ""
        if token.endswith("%"):
            raise self.fail(
                f"unsupported rate {_q(token)}",
                self.pos,
                "rates relative to a device's speed need a device; give an absolute rate like 10mbit",
            )
        bits, index = self.value_with_unit("rate", _RATE_HINT, _RATE_UNITS)
        if float(bits) <= 0:
            raise self.fail(
                f"bad rate {_q(self.tokens[index])}", index, "a rate must be above zero"
            )
        return float(bits)

    def integer(self, what: str, low: int, high: int, *, signed: bool = False) -> int:
        hint = f"expected a whole number from {low} to {high}"
        token, index = self.take(what, hint)
        if (_SIGNED if signed else _UNSIGNED).fullmatch(token) is None:
            raise self.fail(f"bad {what} {_q(token)}", index, hint)
        if len(token.lstrip("+-").lstrip("0")) > len(str(max(abs(low), high))):
            raise self.fail(f"bad {what} {_q(token)}", index, hint)  # before int() of a huge string
        value = int(token)
        if not low <= value <= high:
            raise self.fail(f"bad {what} {_q(token)}", index, hint)
        return value

    # -- options --------------------------------------------------------------------------------------

    def parse(self) -> NetemSpec:
        draft = _Draft()
        while self.pos < len(self.tokens):
            token, index = self.tokens[self.pos], self.pos
            self.pos += 1
            keyword = _ALIASES.get(token.lower(), token.lower())
            if keyword in ("slot", "ecn"):
                raise self.fail(f"unsupported option {_q(token)}", index, _UNSUPPORTED[keyword])
            if keyword not in _KEYWORDS:
                looks_like_value = token[0].isdigit() or token[0] in ".-+"
                problem = (
                    f"unexpected value {_q(token)}"
                    if looks_like_value
                    else f"unknown option {_q(token)}"
                )
                raise self.fail(problem, index, f"expected one of {', '.join(_KEYWORDS)}")
            if keyword in draft.seen:
                first = draft.seen[keyword]
                raise self.fail(
                    f"{_q(token)} given twice",
                    index,
                    f"it already appeared at token {first + 1}; give each option once",
                )
            draft.seen[keyword] = index
            getattr(self, f"opt_{keyword.replace('-', '_')}")(draft, index)
        return self.finish(draft)

    def opt_delay(self, draft: _Draft, index: int) -> None:
        delay = self.time("time")
        jitter = correlation = Decimal(0)
        if self.next_is_number():
            jitter = self.time("jitter")
            if self.next_is_number():
                correlation = self.fraction("delay correlation")
        draft.delay = (delay, jitter, correlation)

    def opt_distribution(self, draft: _Draft, index: int) -> None:
        hint = f"expected one of {', '.join(DISTRIBUTIONS)}"
        token, at = self.take("distribution name", hint)
        if token.lower() not in DISTRIBUTIONS:
            raise self.fail(
                f"unknown distribution {_q(token)}",
                at,
                hint + " (custom .dist tables are not supported)",
            )
        draft.distribution = cast(Distribution, token.lower())  # checked just above

    def opt_loss(self, draft: _Draft, index: int) -> None:
        hint = "expected a percentage, or a model: 'random P', 'state P13 ...', 'gemodel P ...'"
        if self.pos >= len(self.tokens):
            raise self.fail("missing loss", self.pos, hint)
        model = self.tokens[self.pos].lower()
        if self.next_is_number():  # the old syntax: "loss 1%" is "loss random 1%"
            model = "random"
        elif model in ("random", "state", "gemodel"):
            self.pos += 1
        else:
            raise self.fail(f"unknown loss model {_q(self.tokens[self.pos])}", self.pos, hint)
        try:
            if model == "random":
                p = self.fraction("loss percentage")
                corr = self.optional_fraction("loss correlation") or Decimal(0)
                draft.loss = RandomLoss(float(p), float(corr))
            elif model == "state":
                draft.loss = self.state_model()
            else:
                draft.loss = self.gemodel()
        except NetemSyntaxError:
            raise
        except ValueError as error:
            raise self.fail("bad loss model", index, str(error)) from None

    def state_model(self) -> StateLoss:
        p13 = self.fraction("loss state p13")
        # tc's defaults for the omitted ones: p31 = 1 - p13, p32 = 0, p23 = 1, p14 = 0.
        values = [p13, EXACT.subtract(Decimal(1), p13), Decimal(0), Decimal(1), Decimal(0)]
        for slot, name in enumerate(("p31", "p32", "p23", "p14"), start=1):
            if not self.next_is_number():
                break
            values[slot] = self.fraction(f"loss state {name}")
        return StateLoss(*(float(v) for v in values))

    def gemodel(self) -> GilbertElliottLoss:
        p = self.fraction("loss gemodel p")
        r = EXACT.subtract(Decimal(1), p)  # tc's default
        h = Decimal(0)  # "1-h" defaults to 100 %: every packet in the bad state is lost
        k = Decimal(1)  # "1-k" defaults to 0: no loss in the good state
        if self.next_is_number():
            r = self.fraction("loss gemodel r")
            if self.next_is_number():
                h = EXACT.subtract(Decimal(1), self.fraction("loss gemodel 1-h"))
                if self.next_is_number():
                    k = EXACT.subtract(Decimal(1), self.fraction("loss gemodel 1-k"))
        return GilbertElliottLoss(float(p), float(r), float(h), float(k))

    def opt_duplicate(self, draft: _Draft, index: int) -> None:
        p = self.fraction("duplicate percentage")
        corr = self.optional_fraction("duplicate correlation") or Decimal(0)
        draft.duplicate = DuplicateSpec(float(p), float(corr))

    def opt_corrupt(self, draft: _Draft, index: int) -> None:
        p = self.fraction("corrupt percentage")
        corr = self.optional_fraction("corrupt correlation") or Decimal(0)
        draft.corrupt = CorruptSpec(float(p), float(corr))

    def opt_reorder(self, draft: _Draft, index: int) -> None:
        p = self.fraction("reorder percentage")
        corr = self.optional_fraction("reorder correlation") or Decimal(0)
        draft.reorder = (float(p), float(corr))

    def opt_gap(self, draft: _Draft, index: int) -> None:
        draft.gap = self.integer("gap", 0, 2**32 - 1)

    def opt_rate(self, draft: _Draft, index: int) -> None:
        rate = self.rate_value()
        extra = [0, 0, 0]  # packet overhead, cell size, cell overhead
        # tc's positional form: rate R [PACKETOVERHEAD [CELLSIZE [CELLOVERHEAD]]]
        names = ("packet overhead", "cell size", "cell overhead")
        for slot, name in enumerate(names):
            # tc takes a cell size only if it starts with a digit; a '-' here gets a clearer error.
            if not self.next_is_number(signed=True):
                break
            signed = slot != 1
            extra[slot] = self.integer(name, -(2**31) if signed else 0, 2**31 - 1, signed=True)
        # Keyword forms (an extension): overhead N, cellsize N, celloverhead N.
        keywords = {"overhead": 0, "cellsize": 1, "celloverhead": 2}
        while self.pos < len(self.tokens) and self.tokens[self.pos].lower() in keywords:
            slot = keywords[self.tokens[self.pos].lower()]
            self.pos += 1
            low = 0 if slot == 1 else -(2**31)
            extra[slot] = self.integer(names[slot], low, 2**31 - 1, signed=True)
        try:
            draft.rate = RateSpec(rate, *extra)
        except ValueError as error:
            raise self.fail("bad rate", index, str(error)) from None

    def opt_trace(self, draft: _Draft, index: int) -> None:
        path, at = self.take("trace file", "expected the path of a Mahimahi trace file")
        try:
            trace = load_trace(path)
        except ValueError as error:  # TraceFileError, or a path netem syntax cannot carry
            raise self.fail(f"bad trace {_q(path)}", at, str(error)) from None
        offset, overhead = Decimal(0), 0
        seen: set[str] = set()
        while self.pos < len(self.tokens) and self.tokens[self.pos].lower() in (
            "offset",
            "overhead",
        ):
            word, at = self.tokens[self.pos].lower(), self.pos
            if word in seen:
                raise self.fail(f"trace {word} given twice", at, f"give the trace's {word} once")
            seen.add(word)
            self.pos += 1
            if word == "offset":
                offset = self.time("trace offset")
            else:
                overhead = self.integer("trace overhead", -(2**31), 2**31 - 1, signed=True)
        draft.trace = TraceSpec(trace, float(offset), overhead)

    def opt_limit(self, draft: _Draft, index: int) -> None:
        draft.limit = self.integer("limit", 0, MAX_LIMIT)

    def opt_limit_bytes(self, draft: _Draft, index: int) -> None:
        draft.limit_bytes = self.integer("limit-bytes", 0, MAX_LIMIT_BYTES)

    def opt_seed(self, draft: _Draft, index: int) -> None:
        draft.seed = self.integer("seed", 0, MAX_SEED)

    # -- cross-checks (tc's own, after reading every option) ------------------------------------------

    def finish(self, draft: _Draft) -> NetemSpec:
        delay_spec: DelaySpec | None = None
        if draft.delay is not None:
            delay, jitter, correlation = draft.delay
            if draft.distribution != "uniform" and not (delay and jitter):
                at = draft.seen["distribution"]
                raise self.fail(
                    f"distribution {draft.distribution!r}",
                    at,
                    "a distribution needs a delay and a jitter (tc refuses it too): "
                    f"e.g. 'delay 20ms 5ms distribution {draft.distribution}'",
                )
            try:
                delay_spec = DelaySpec(
                    float(delay), float(jitter), float(correlation), draft.distribution
                )
            except ValueError as error:  # e.g. a correlation with a zero jitter
                raise self.fail("bad delay", draft.seen["delay"], str(error)) from None
        elif "distribution" in draft.seen:
            raise self.fail(
                f"distribution {draft.distribution!r}",
                draft.seen["distribution"],
                "a distribution shapes the jitter of a delay: "
                f"add one, e.g. 'delay 20ms 5ms distribution {draft.distribution}'",
            )
        reorder_spec: ReorderSpec | None = None
        if draft.reorder is not None:
            p, corr = draft.reorder
            if p > 0 and not (delay_spec and delay_spec.delay):
                raise self.fail(
                    "reorder",
                    draft.seen["reorder"],
                    "reordering needs a delay (netem sends a reordered packet at once and delays "
                    "the others): add one, e.g. 'delay 10ms reorder 25%'",
                )
            reorder_spec = ReorderSpec(p, corr, max(draft.gap, 1))  # tc: no gap means gap 1
        elif "gap" in draft.seen:
            raise self.fail(
                "gap",
                draft.seen["gap"],
                "gap is part of reordering: give a reorder probability, e.g. 'reorder 100% gap 5'",
            )
        if "limit" in draft.seen and "limit-bytes" in draft.seen:
            raise self.fail(
                "'limit-bytes'",
                draft.seen["limit-bytes"],
                "the queue's size is in packets (limit) or in bytes (limit-bytes): give one",
            )
        if draft.trace is not None and draft.rate is not None:
            raise self.fail(
                "'trace'",
                draft.seen["trace"],
                "a trace and a rate both set the link's capacity: give one of them",
            )
        try:
            return NetemSpec(
                delay=delay_spec,
                loss=draft.loss,
                duplicate=draft.duplicate,
                corrupt=draft.corrupt,
                reorder=reorder_spec,
                rate=draft.rate,
                limit=draft.limit,
                seed=draft.seed,
                trace=draft.trace,
                limit_bytes=draft.limit_bytes,
            )
        except ValueError as error:  # not expected after the checks above; still name a place
            raise self.fail("invalid options", 0, str(error)) from None


_UNSUPPORTED: Final = {
    "slot": "slotted delivery is not emulated by tdtp's netem; remove the slot option "
    "(delay, jitter and rate are)",
    "ecn": "ECN marking is not emulated: the link carries UDP payloads without IP headers to mark; "
    "remove 'ecn' to drop packets instead",
}


def parse_netem(text: str) -> NetemSpec:
    """Parse tc-netem options into a :class:`~tdtp.netem.spec.NetemSpec`.

    >>> str(parse_netem("delay 20ms 5ms 25% distribution normal loss 1% rate 1mbit limit 15"))
    'delay 20ms 5ms 25% distribution normal loss 1% rate 1mbit limit 15'

    Raises :class:`NetemSyntaxError` naming the bad token, e.g. ``bad time '20xs' at token 2 (after
    'delay'): expected a number with a unit like 20ms``.
    """
    if not isinstance(text, str):
        raise ArgumentTypeError(
            f"parse_netem takes a str of netem options, got {type(text).__name__}"
        )
    return _Parser(text).parse()


def _deprecated_spec_parse(cls: type[NetemSpec], text: str) -> NetemSpec:
    warnings.warn(
        "NetemSpec.parse() is deprecated and goes away in tdtp 0.3.0; call "
        "tdtp.netem.parse_netem() instead",
        DeprecationWarning,
        stacklevel=2,
    )
    return parse_netem(text)


# NetemSpec.parse() read netem syntax up to 0.1.0 by importing this module from spec.py, a circle: the
# parser builds specs, specs know nothing of the parser. The old spelling stays for one release,
# attached from this side.
NetemSpec.parse = classmethod(_deprecated_spec_parse)  # type: ignore[attr-defined]
