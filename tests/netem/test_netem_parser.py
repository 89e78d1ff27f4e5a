"""netem syntax: the documented forms parse to the expected spec, bad ones name the token, and
``parse(str(spec)) == spec`` for every spec."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tdtp.netem import (
    CorruptSpec,
    DelaySpec,
    Distribution,
    DuplicateSpec,
    GilbertElliottLoss,
    NetemSpec,
    NetemSyntaxError,
    RandomLoss,
    RateSpec,
    ReorderSpec,
    StateLoss,
    parse_netem,
)

MS = 1e-3

ACCEPTED: list[tuple[str, NetemSpec]] = [
    ("", NetemSpec()),
    ("delay 20ms", NetemSpec(delay=DelaySpec(0.02))),
    ("latency 100ms", NetemSpec(delay=DelaySpec(0.1))),
    ("netem delay 20ms", NetemSpec(delay=DelaySpec(0.02))),  # a pasted tc tail
    ("delay 20ms 5ms", NetemSpec(delay=DelaySpec(0.02, 0.005))),
    ("delay 20ms 5ms 25%", NetemSpec(delay=DelaySpec(0.02, 0.005, 0.25))),
    ("delay 100ms 10ms 25", NetemSpec(delay=DelaySpec(0.1, 0.01, 0.25))),  # bare percent
    # every time unit tc knows, case-insensitively (a bare time other than 0 is refused, below)
    ("delay 1s", NetemSpec(delay=DelaySpec(1.0))),
    ("delay 1.5sec", NetemSpec(delay=DelaySpec(1.5))),
    ("delay 2secs", NetemSpec(delay=DelaySpec(2.0))),
    ("delay 2msec", NetemSpec(delay=DelaySpec(0.002))),
    ("delay 2msecs", NetemSpec(delay=DelaySpec(0.002))),
    ("delay 20MS", NetemSpec(delay=DelaySpec(0.02))),
    ("delay 500us", NetemSpec(delay=DelaySpec(0.0005))),
    ("delay 500usec", NetemSpec(delay=DelaySpec(0.0005))),
    ("delay 500usecs", NetemSpec(delay=DelaySpec(0.0005))),
    ("delay 1500ns", NetemSpec(delay=DelaySpec(1.5e-6))),
    ("delay 0 5ms", NetemSpec(delay=DelaySpec(0.0, 0.005))),  # zero needs no unit
    ("delay .5ms", NetemSpec(delay=DelaySpec(0.0005))),
    ("delay 1e1ms", NetemSpec(delay=DelaySpec(0.01))),
    ("delay 0 5ms", NetemSpec(delay=DelaySpec(0.0, 0.005))),
    # distributions, in any position (tc reads options in any order)
    (
        "delay 10ms 2ms distribution normal",
        NetemSpec(delay=DelaySpec(0.01, 0.002, distribution="normal")),
    ),
    (
        "distribution pareto delay 10ms 2ms",
        NetemSpec(delay=DelaySpec(0.01, 0.002, distribution="pareto")),
    ),
    (
        "delay 10ms 2ms 10% distribution paretonormal",
        NetemSpec(delay=DelaySpec(0.01, 0.002, 0.1, "paretonormal")),
    ),
    ("delay 10ms 2ms distribution uniform", NetemSpec(delay=DelaySpec(0.01, 0.002))),
    # loss
    ("loss 1%", NetemSpec(loss=RandomLoss(0.01))),
    ("loss 1", NetemSpec(loss=RandomLoss(0.01))),  # tc: a bare number is a percentage
    ("loss 0.5", NetemSpec(loss=RandomLoss(0.005))),
    ("loss 0.1% 25%", NetemSpec(loss=RandomLoss(0.001, 0.25))),
    ("loss random 2%", NetemSpec(loss=RandomLoss(0.02))),
    ("loss random 2% 50%", NetemSpec(loss=RandomLoss(0.02, 0.5))),
    ("drop 3%", NetemSpec(loss=RandomLoss(0.03))),
    ("loss 100%", NetemSpec(loss=RandomLoss(1.0))),
    ("loss state 1%", NetemSpec(loss=StateLoss(0.01, 0.99, 0.0, 1.0, 0.0))),
    ("loss state 1% 30%", NetemSpec(loss=StateLoss(0.01, 0.3))),
    ("loss state 1% 30% 10% 40% 2%", NetemSpec(loss=StateLoss(0.01, 0.3, 0.1, 0.4, 0.02))),
    ("loss gemodel 1%", NetemSpec(loss=GilbertElliottLoss(0.01, 0.99, h=0.0, k=1.0))),
    ("loss gemodel 1% 10%", NetemSpec(loss=GilbertElliottLoss(0.01, 0.1))),
    # netem's third and fourth arguments are 1-h and 1-k: loss probabilities
    ("loss gemodel 1% 10% 70%", NetemSpec(loss=GilbertElliottLoss(0.01, 0.1, h=0.3))),
    (
        "loss gemodel 1% 10% 70% 0.1%",
        NetemSpec(loss=GilbertElliottLoss(0.01, 0.1, h=0.3, k=0.999)),
    ),
    # duplicate, corrupt, reorder
    ("duplicate 1%", NetemSpec(duplicate=DuplicateSpec(0.01))),
    ("duplicate 1% 25%", NetemSpec(duplicate=DuplicateSpec(0.01, 0.25))),
    ("corrupt 0.1%", NetemSpec(corrupt=CorruptSpec(0.001))),
    ("corrupt 5% 10%", NetemSpec(corrupt=CorruptSpec(0.05, 0.1))),
    (
        "delay 10ms reorder 25% 50%",
        NetemSpec(delay=DelaySpec(0.01), reorder=ReorderSpec(0.25, 0.5, gap=1)),
    ),
    (
        "delay 10ms reorder 25% 50% gap 5",
        NetemSpec(delay=DelaySpec(0.01), reorder=ReorderSpec(0.25, 0.5, gap=5)),
    ),
    (
        "gap 5 delay 10ms reorder 100%",
        NetemSpec(delay=DelaySpec(0.01), reorder=ReorderSpec(1.0, gap=5)),
    ),
    ("delay 10ms reorder 5% gap 0", NetemSpec(delay=DelaySpec(0.01), reorder=ReorderSpec(0.05))),
    # rate: SI and IEC bit units, tc's byte units (bps = BYTES/s), positional and keyword overheads
    ("rate 1mbit", NetemSpec(rate=RateSpec(1e6))),
    ("rate 1000", NetemSpec(rate=RateSpec(1000.0))),
    ("rate 64bit", NetemSpec(rate=RateSpec(64.0))),
    ("rate 500kbit", NetemSpec(rate=RateSpec(5e5))),
    ("rate 1.5Mbit", NetemSpec(rate=RateSpec(1.5e6))),
    ("rate 10gbit", NetemSpec(rate=RateSpec(1e10))),
    ("rate 1tbit", NetemSpec(rate=RateSpec(1e12))),
    ("rate 1kibit", NetemSpec(rate=RateSpec(1024.0))),
    ("rate 2mibit", NetemSpec(rate=RateSpec(2 * 2**20))),
    ("rate 1gibit", NetemSpec(rate=RateSpec(2.0**30))),
    ("rate 1tibit", NetemSpec(rate=RateSpec(2.0**40))),
    ("rate 100bps", NetemSpec(rate=RateSpec(800.0))),
    ("rate 100kbps", NetemSpec(rate=RateSpec(800e3))),
    ("rate 1mbps", NetemSpec(rate=RateSpec(8e6))),
    ("rate 1gbps", NetemSpec(rate=RateSpec(8e9))),
    ("rate 1tbps", NetemSpec(rate=RateSpec(8e12))),
    ("rate 1kibps", NetemSpec(rate=RateSpec(8 * 1024.0))),
    ("rate 1MiBps", NetemSpec(rate=RateSpec(8.0 * 2**20))),
    ("rate 100kbit 20", NetemSpec(rate=RateSpec(1e5, 20))),
    ("rate 100kbit -14", NetemSpec(rate=RateSpec(1e5, -14))),
    ("rate 5kbit 20 100 5", NetemSpec(rate=RateSpec(5e3, 20, 100, 5))),  # tc-netem(8)'s example
    ("rate 1mbit overhead 28", NetemSpec(rate=RateSpec(1e6, 28))),
    ("rate 2mbit cellsize 48 celloverhead 5", NetemSpec(rate=RateSpec(2e6, 0, 48, 5))),
    # limit and seed
    ("limit 15", NetemSpec(limit=15)),
    ("limit 0", NetemSpec(limit=0)),
    ("seed 42", NetemSpec(seed=42)),
    ("seed 18446744073709551615", NetemSpec(seed=2**64 - 1)),
    # the example, and a kitchen sink
    (
        "delay 20ms 5ms 25% distribution normal loss 1% rate 1mbit limit 15",
        NetemSpec(
            delay=DelaySpec(0.02, 0.005, 0.25, "normal"),
            loss=RandomLoss(0.01),
            rate=RateSpec(1e6),
            limit=15,
        ),
    ),
    (
        "limit 50 delay 30ms 10ms duplicate 1% corrupt 0.1% reorder 10% gap 3 "
        "loss gemodel 2% 20% rate 10mbit 42 seed 7",
        NetemSpec(
            delay=DelaySpec(0.03, 0.01),
            loss=GilbertElliottLoss(0.02, 0.2),
            duplicate=DuplicateSpec(0.01),
            corrupt=CorruptSpec(0.001),
            reorder=ReorderSpec(0.1, gap=3),
            rate=RateSpec(1e7, 42),
            limit=50,
            seed=7,
        ),
    ),
]


@pytest.mark.parametrize(("text", "expected"), ACCEPTED, ids=[t or "<empty>" for t, _ in ACCEPTED])
def test_accepts_netem_forms(text: str, expected: NetemSpec) -> None:
    spec = parse_netem(text)
    assert spec == expected
    with pytest.warns(DeprecationWarning, match="parse_netem"):
        assert NetemSpec.parse(text) == expected  # type: ignore[attr-defined]
    assert parse_netem(str(spec)) == spec  # and renders back


RENDERED = [
    ("delay 20ms 5ms 25% distribution normal loss 1% rate 1mbit limit 15", None),
    ("delay 0.5ms", "delay 500us"),
    ("delay 1500ms", "delay 1.5s"),
    ("delay 250000ns", "delay 250us"),
    ("loss 1", "loss 1%"),
    ("loss random 1% 25%", "loss 1% 25%"),
    ("loss state 1%", "loss state 1%"),
    ("loss state 1% 99% 0% 100% 0%", "loss state 1%"),
    ("loss state 1% 30% 0 100% 2%", "loss state 1% 30% 0% 100% 2%"),
    ("loss gemodel 1% 99% 100% 0%", "loss gemodel 1%"),
    ("loss gemodel 1% 10% 70% 0.1%", None),
    ("rate 100bps", "rate 800bit"),
    ("rate 1mibit", "rate 1.048576mbit"),
    ("rate 5kbit 20 100 5", None),
    ("rate 1mbit overhead 28", "rate 1mbit 28"),
    ("delay 10ms reorder 25% 50% gap 5", None),
    ("seed 3 limit 1000", "limit 1000 seed 3"),
    ("", "limit 1000"),
]


@pytest.mark.parametrize(("text", "rendered"), RENDERED)
def test_renders_canonical_netem(text: str, rendered: str | None) -> None:
    assert str(parse_netem(text)) == (rendered if rendered is not None else text)


REJECTED: list[tuple[str, str, int | None, str]] = [
    # text, offending token, its 1-based position (None: missing at the end), words in the message
    ("delay 20xs", "20xs", 2, "bad time '20xs' at token 2 (after 'delay'): expected a number"),
    ("delay", "", None, "missing time at the end (after 'delay')"),
    ("delay 20", "20", 2, "time '20' has no unit at token 2 (after 'delay'): write 20ms"),
    ("delay 20ms 5", "5", 3, "jitter '5' has no unit"),
    ("delay -5ms", "-5ms", 2, "bad time '-5ms'"),
    ("delay 10ms 5xs", "5xs", 3, "bad jitter '5xs' at token 3 (after '10ms')"),
    ("delay 10ms 5ms 150%", "150%", 4, "cannot exceed 100%"),
    ("delay 10ms 5ms 25% 30%", "30%", 5, "unexpected value '30%'"),
    ("delay 10ms 0ms 25%", "delay", 1, "correlation correlates the jitter"),
    ("delay 1e400s", "1e400s", 2, "out of range"),
    ("delay 10ms delay 20ms", "delay", 3, "'delay' given twice"),
    ("latency 10ms delay 20ms", "delay", 3, "already appeared at token 1"),
    ("loss", "", None, "missing loss at the end"),
    ("loss 150%", "150%", 2, "bad loss percentage '150%'"),
    ("loss 1%%", "1%%", 2, "bad loss percentage '1%%'"),
    ("loss 1x", "1x", 2, "expected a percentage"),
    ("loss bursty 1%", "bursty", 2, "unknown loss model 'bursty'"),
    ("loss random", "", None, "missing loss percentage at the end (after 'random')"),
    ("loss 1% drop 2%", "drop", 3, "given twice"),
    ("loss state 60% 50% 60%", "loss", 1, "p31 + p32"),
    ("loss state 60% 50% 0% 100% 50%", "loss", 1, "p13 + p14"),
    ("loss gemodel 1% 200%", "200%", 4, "cannot exceed 100%"),
    ("duplicate", "", None, "missing duplicate percentage"),
    ("corrupt lots", "lots", 2, "bad corrupt percentage 'lots'"),
    ("reorder 25%", "reorder", 1, "reordering needs a delay"),
    ("rate 1mbit reorder 25%", "reorder", 3, "needs a delay"),
    ("delay 0 5ms reorder 25%", "reorder", 4, "needs a delay"),
    ("delay 10ms gap 5", "gap", 3, "gap is part of reordering"),
    ("delay 10ms reorder 5% gap x", "x", 6, "bad gap 'x'"),
    ("distribution normal", "distribution", 1, "shapes the jitter of a delay"),
    ("delay 10ms distribution normal", "distribution", 3, "needs a delay and a jitter"),
    ("delay 10ms 1ms distribution weird", "weird", 5, "unknown distribution 'weird'"),
    ("rate", "", None, "missing rate"),
    ("rate 1mbiit", "1mbiit", 2, "bad rate '1mbiit'"),
    ("rate 0kbit", "0kbit", 2, "a rate must be above zero"),
    ("rate 10%", "10%", 2, "need a device"),
    ("rate 1mbit 20 -48", "-48", 4, "bad cell size '-48'"),
    ("rate 1mbit 0 0 5", "rate", 1, "cell_overhead only applies to cells"),
    ("rate 1mbit overhead x", "x", 4, "bad packet overhead 'x'"),
    ("limit", "", None, "missing limit"),
    ("limit -1", "-1", 2, "bad limit '-1'"),
    ("limit 1.5", "1.5", 2, "expected a whole number"),
    ("limit 4294967296", "4294967296", 2, "bad limit"),
    ("seed x", "x", 2, "bad seed 'x'"),
    ("seed 18446744073709551616", "18446744073709551616", 2, "bad seed"),
    ("slot 10ms", "slot", 1, "unsupported option 'slot'"),
    ("loss 1% ecn", "ecn", 3, "unsupported option 'ecn'"),
    ("foo 1", "foo", 1, "unknown option 'foo' at token 1 (at the start)"),
    ("delay 10ms bar", "bar", 3, "unknown option 'bar' at token 3 (after '10ms')"),
]


@pytest.mark.parametrize(
    ("text", "token", "index", "words"), REJECTED, ids=[r[0] for r in REJECTED]
)
def test_rejects_with_the_token_named(text: str, token: str, index: int | None, words: str) -> None:
    with pytest.raises(NetemSyntaxError) as caught:
        parse_netem(text)
    error = caught.value
    assert isinstance(error, ValueError)
    assert words in str(error)
    if index is None:
        assert error.token is None
        assert error.index == len(text.split()) + 1
    else:
        assert error.token == token
        assert error.index == index
        assert f"'{token}'" in str(error) or f"token {index}" in str(error)
    assert ": " in str(error)  # every message ends with what to do


def test_error_message_matches_the_documented_example() -> None:
    with pytest.raises(NetemSyntaxError) as caught:
        parse_netem("delay 20xs")
    assert str(caught.value) == (
        "bad time '20xs' at token 2 (after 'delay'): expected a number with a unit like 20ms"
    )


def test_parse_takes_only_text() -> None:
    with pytest.raises(TypeError, match="str of netem options"):
        parse_netem(b"delay 20ms")  # type: ignore[arg-type]


# -- the dataclasses validate themselves -------------------------------------------------------------


@pytest.mark.parametrize(
    ("build", "words"),
    [
        (lambda: DelaySpec(-0.01), "non-negative number of seconds"),
        (lambda: DelaySpec(float("inf")), "finite"),
        (lambda: DelaySpec(0.01, 0.0, 0.5), "correlation correlates the jitter"),
        (lambda: DelaySpec(0.01, distribution="normal"), "needs both a delay and a jitter"),
        (lambda: DelaySpec(0.01, 0.001, distribution="gamma"), "must be one of"),  # type: ignore[arg-type]
        (lambda: RandomLoss(1.5), "fraction between 0 and 1"),
        (lambda: RandomLoss(float("nan")), "fraction between 0 and 1"),
        (lambda: StateLoss(0.7, 0.5, 0.6), "p31 + p32"),
        (lambda: GilbertElliottLoss(0.1, -0.1), "fraction"),
        (lambda: ReorderSpec(0.1, gap=0), "at least 1"),
        (lambda: RateSpec(0.0), "positive"),
        (lambda: RateSpec(1e6, cell_overhead=5), "set cell_size too"),
        (lambda: RateSpec(1e6, cell_size=-1), "cell_size"),
        (lambda: NetemSpec(limit=-1), "limit"),
        (lambda: NetemSpec(seed=2**64), "seed"),
        (lambda: NetemSpec(reorder=ReorderSpec(0.1)), "reordering needs a delay"),
        (lambda: NetemSpec(loss=DuplicateSpec(0.1)), "NetemSpec.loss must be"),  # type: ignore[arg-type]
        (lambda: NetemSpec(delay=RandomLoss(0.1)), "NetemSpec.delay must be"),  # type: ignore[arg-type]
    ],
)
def test_specs_validate_with_a_helpful_message(build: object, words: str) -> None:
    with pytest.raises(ValueError, match=words.replace("+", r"\+").replace("(", r"\(")):
        build()  # type: ignore[operator]


def test_gilbert_elliott_exposes_netem_loss_arguments() -> None:
    model = GilbertElliottLoss(0.01, 0.1, h=0.3, k=0.999)
    assert model.loss_in_bad == pytest.approx(0.7)
    assert model.loss_in_good == pytest.approx(0.001)


# -- round trip for every spec ----------------------------------------------------------------------

fractions = st.floats(min_value=0.0, max_value=1.0)
nonzero_fractions = st.floats(min_value=0.0, max_value=1.0, exclude_min=True)
times = st.floats(min_value=0.0, max_value=3600.0)
positive_times = st.floats(min_value=1e-9, max_value=3600.0)


@st.composite
def delays(draw: st.DrawFn) -> DelaySpec:
    delay = draw(positive_times)
    jitter = draw(st.one_of(st.just(0.0), positive_times))
    correlation = draw(fractions) if jitter else 0.0
    distribution: Distribution = draw(
        st.sampled_from(["uniform", "normal", "pareto", "paretonormal"])
    )
    return DelaySpec(delay, jitter, correlation, distribution if jitter else "uniform")


@st.composite
def state_losses(draw: st.DrawFn) -> StateLoss:
    p13 = draw(fractions)
    p14 = draw(st.floats(0.0, 1.0 - p13))
    p31 = draw(fractions)
    p32 = draw(st.floats(0.0, 1.0 - p31))
    return StateLoss(p13, p31, p32, draw(fractions), p14)


losses = st.one_of(
    st.builds(RandomLoss, fractions, fractions),
    state_losses(),
    st.builds(GilbertElliottLoss, fractions, fractions, fractions, fractions),
)
rates = st.builds(
    RateSpec,
    st.floats(min_value=1e-3, max_value=1e14),
    st.integers(-(2**31), 2**31 - 1),
    st.integers(0, 2**31 - 1),
    st.just(0),
) | st.builds(
    RateSpec,
    st.floats(min_value=1e-3, max_value=1e14),
    st.integers(-100, 100),
    st.integers(1, 100),
    st.integers(-100, 100),
)


@st.composite
def specs(draw: st.DrawFn) -> NetemSpec:
    delay = draw(st.none() | delays())
    reorder = None
    if delay is not None and draw(st.booleans()):
        reorder = ReorderSpec(draw(fractions), draw(fractions), draw(st.integers(1, 2**32 - 1)))
    return NetemSpec(
        delay=delay,
        loss=draw(st.none() | losses),
        duplicate=draw(st.none() | st.builds(DuplicateSpec, fractions, fractions)),
        corrupt=draw(st.none() | st.builds(CorruptSpec, fractions, fractions)),
        reorder=reorder,
        rate=draw(st.none() | rates),
        limit=draw(st.integers(0, 2**32 - 1)),
        seed=draw(st.none() | st.integers(0, 2**64 - 1)),
    )


@given(specs())
def test_round_trip_is_exact(spec: NetemSpec) -> None:
    assert parse_netem(str(spec)) == spec


@given(st.floats(min_value=0.0, max_value=1.0), st.floats(min_value=0.0, max_value=1.0))
def test_round_trip_of_gemodel_complements_is_exact(h: float, k: float) -> None:
    spec = NetemSpec(loss=GilbertElliottLoss(0.05, 0.3, h, k))
    assert parse_netem(str(spec)) == spec


VOCABULARY = " ".join(
    [
        "delay latency distribution loss drop random state gemodel duplicate corrupt reorder gap",
        "rate overhead cellsize celloverhead limit seed slot ecn netem normal pareto uniform",
        "0 1 5 -3 +2 .5 1e3 1e999 20ms 5ms 0ms 1s 250 1% 25% 100% 150% 0.5% 1mbit 100kbps 2mibit",
        "x % ms 10%% 1e-400bit -5ms 99999999999999999999999",
    ]
).split()


@given(st.lists(st.sampled_from(VOCABULARY), max_size=12))
def test_any_text_parses_or_raises_netem_syntax_error(words: list[str]) -> None:
    text = " ".join(words)
    try:
        spec = parse_netem(text)
    except NetemSyntaxError as error:
        assert 1 <= error.index <= len(words) + 1
        assert error.token is None or error.token in words
    else:
        assert parse_netem(str(spec)) == spec
