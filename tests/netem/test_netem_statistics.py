"""Statistical properties of NetemLink, seeded, with bounds derived in each test.

Bounds are 5 standard errors of the statistic (a two-sided 5-sigma band: a correct implementation
fails one such check with probability ~6e-7), computed from the model's own variance where it is
known in closed form, and from the sample otherwise (said where it is). The seeds are fixed, so the
tests are deterministic; the bounds are what makes them meaningful rather than tuned to one seed.
"""

from __future__ import annotations

import itertools
import math
import random
from statistics import NormalDist, fmean, pstdev

from tdtp.netem import (
    DelaySpec,
    Distribution,
    GilbertElliottLoss,
    NetemLink,
    NetemSpec,
    RandomLoss,
    StateLoss,
    parse_netem,
)

SIGMAS = 5.0
TABLE_MAX = 32767 / 8192  # netem's int16 tables scaled by 8192


def loss_indicators(spec: NetemSpec, n: int, seed: int) -> list[int]:
    """1 for each packet the loss decision removed, 0 for each that got through."""
    link = NetemLink(spec, seed=seed)
    out = []
    for i in range(n):
        lost = link.stats.lost
        link.send(b"x", float(i))
        out.append(link.stats.lost - lost)
        link.deliver(float(i))
    return out


def delays(spec: NetemSpec, n: int, seed: int) -> list[float]:
    """The delay each of ``n`` packets got (sent 1 s apart, alone on the link)."""
    link = NetemLink(spec, seed=seed)
    out = []
    for i in range(n):
        now = float(i)
        link.send(b"x", now)
        due = link.next_delivery()
        assert due is not None
        out.append(due - now)
        assert len(link.deliver(max(due, now))) == 1
    return out


def runs(indicators: list[int], value: int) -> list[int]:
    """Lengths of the complete runs of ``value`` (the first and last, possibly cut, are dropped)."""
    lengths, current, started = [], 0, False
    for x in indicators:
        if x == value:
            current += 1
        else:
            if current and started:
                lengths.append(current)
            current, started = 0, True
    return lengths


def sd_standard_error(xs: list[float]) -> float:
    """Standard error of the sample standard deviation of independent draws: s sqrt((k - 1) / (4 n)),
    k the sample kurtosis (delta method on Var(s^2) = (mu4 - sigma^4) / n)."""
    m = fmean(xs)
    m2 = fmean([(x - m) ** 2 for x in xs])
    m4 = fmean([(x - m) ** 4 for x in xs])
    return math.sqrt(m2) * math.sqrt((m4 / m2**2 - 1) / (4 * len(xs)))


def lag1_autocorrelation(xs: list[float] | list[int]) -> float:
    m = fmean(xs)
    num = sum((a - m) * (b - m) for a, b in itertools.pairwise(xs))
    return num / sum((x - m) ** 2 for x in xs)


# -- random loss ----------------------------------------------------------------------------------------


def test_random_loss_rate_is_inside_its_binomial_interval() -> None:
    # Independent losses: the count is Binomial(n, p), standard deviation sqrt(n p (1 - p)).
    n, p = 100_000, 0.05
    lost = sum(loss_indicators(NetemSpec(loss=RandomLoss(p)), n, seed=1))
    assert abs(lost - n * p) < SIGMAS * math.sqrt(n * p * (1 - p))  # 5000 +/- 345


def test_uncorrelated_losses_are_uncorrelated_and_correlation_raises_it() -> None:
    # Null: the lag-1 sample autocorrelation of an i.i.d. sequence has standard error 1/sqrt(n).
    n = 50_000
    plain = loss_indicators(NetemSpec(loss=RandomLoss(0.3)), n, seed=2)
    assert abs(lag1_autocorrelation(plain)) < SIGMAS / math.sqrt(n)
    correlated = loss_indicators(NetemSpec(loss=RandomLoss(0.3, 0.5)), n, seed=2)
    assert lag1_autocorrelation(correlated) > 10 / math.sqrt(n)


def test_correlated_loss_loses_less_than_p_as_netems_approximation_does() -> None:
    # netem's correlated draw (1 - c) U + c last is not uniform: its values pile up around 1/2, so
    # P(draw < p) is far below p for small p. This is netem's behaviour (and why tc-netem(8) calls the
    # loss correlation deprecated); pin it so that nobody "fixes" it silently.
    n = 50_000
    lost = sum(loss_indicators(NetemSpec(loss=RandomLoss(0.05, 0.5)), n, seed=3))
    assert lost < 0.2 * 0.05 * n


# -- delay distributions ----------------------------------------------------------------------------------


def test_uniform_delay_bounds_mean_and_spread() -> None:
    # delay + jitter * (2U - 1): uniform on [delay - jitter, delay + jitter), variance jitter^2 / 3.
    # The sample variance of n draws has variance (mu4 - sigma^4) / n with mu4 = jitter^4 / 5.
    n, d, j = 20_000, 0.020, 0.005
    xs = delays(NetemSpec(delay=DelaySpec(d, j)), n, seed=4)
    assert min(xs) >= d - j - 1e-9  # (send times up to 2e4 s: float rounding ~ 4e-12)
    assert max(xs) < d + j + 1e-9
    sd = j / math.sqrt(3)
    assert abs(fmean(xs) - d) < SIGMAS * sd / math.sqrt(n)
    var = pstdev(xs) ** 2
    assert abs(var - sd**2) < SIGMAS * math.sqrt((j**4 / 5 - sd**4) / n)
    assert min(xs) < d - 0.99 * j and max(xs) > d + 0.99 * j  # the whole range is used


def test_normal_delay_mean_and_standard_deviation() -> None:
    # delay + jitter * Z, Z standard normal clipped at +/-4 (netem's table range; the clipping changes
    # the variance by ~1e-3 relative, far inside the bound). Var(S^2) ~ 2 sigma^4 / n.
    n, d, j = 20_000, 0.050, 0.010
    xs = delays(NetemSpec(delay=DelaySpec(d, j, distribution="normal")), n, seed=5)
    assert abs(fmean(xs) - d) < SIGMAS * j / math.sqrt(n)
    assert abs(pstdev(xs) ** 2 - j**2) < SIGMAS * math.sqrt(2 * j**4 / n) + 2e-3 * j**2
    assert d - TABLE_MAX * j - 1e-9 <= min(xs) and max(xs) <= d + TABLE_MAX * j + 1e-9


def pareto_clipped_moments() -> tuple[float, float]:
    """Mean and variance of netem's pareto table variable g = min(4/3 (P - 3/2), c).

    P is Pareto with shape 3 and scale 1: density 3 x^-4 on [1, inf). g reaches c at P = t = 3/2 + 3c/4.
    E[P; P < t] = 3/2 (1 - t^-2), E[P^2; P < t] = 3 (1 - 1/t), Pr(P < t) = 1 - t^-3; so
    E[g] = 4/3 (E[P; P<t] - 3/2 Pr(P<t)) + c t^-3 and E[g^2] = 16/9 E[(P - 3/2)^2; P<t] + c^2 t^-3.
    """
    c = TABLE_MAX
    t = 1.5 + 0.75 * c
    below = 1 - t**-3
    e_p = 1.5 * (1 - t**-2)
    e_p2 = 3 * (1 - 1 / t)
    mean = (4 / 3) * (e_p - 1.5 * below) + c * t**-3
    second = (16 / 9) * (e_p2 - 3 * e_p + 2.25 * below) + c * c * t**-3
    return mean, second - mean * mean


def quantile(distribution: str, v: float) -> float:
    """The standardised delay at quantile ``v``, written from iproute2's table generators."""
    normal = NormalDist().inv_cdf(v)
    pareto = min((4 / 3) * (math.pow(1 - v, -1 / 3) - 1.5), TABLE_MAX)
    return {"normal": normal, "pareto": pareto, "paretonormal": 0.25 * normal + 0.75 * pareto}[
        distribution
    ]


def test_pareto_delay_mean_spread_and_shape() -> None:
    n, d, j = 20_000, 0.050, 0.010
    xs = delays(NetemSpec(delay=DelaySpec(d, j, distribution="pareto")), n, seed=6)
    mean, var = pareto_clipped_moments()  # mean -0.033, sd 0.82 (in units of the jitter)
    assert abs(fmean(xs) - (d + j * mean)) < SIGMAS * j * math.sqrt(var / n)
    # Standard error of a sample standard deviation (delta method): s sqrt((kurtosis - 1) / (4 n)),
    # with the kurtosis estimated from the sample (this one is heavy-tailed).
    assert abs(pstdev(xs) - j * math.sqrt(var)) < SIGMAS * sd_standard_error(xs)
    # Floor at -2/3 of the jitter (P >= 1), ceiling at the table's +4, and a long right tail.
    assert min(xs) >= d - (2 / 3) * j - 1e-9
    assert max(xs) <= d + TABLE_MAX * j + 1e-9
    assert sorted(xs)[n // 2] < fmean(xs)  # median below the mean: right-skewed


def test_table_distributions_match_their_quantiles() -> None:
    # P(delay <= d + j q(v)) = v for the increasing quantile function q: the count below each
    # checkpoint is Binomial(n, v). Checkpoints stay clear of the clipped atoms at the ends.
    n, d, j = 20_000, 0.050, 0.010
    tables: tuple[Distribution, ...] = ("normal", "pareto", "paretonormal")
    for seed, distribution in enumerate(tables, start=7):
        xs = delays(NetemSpec(delay=DelaySpec(d, j, distribution=distribution)), n, seed)
        for v in (0.05, 0.25, 0.5, 0.75, 0.95, 0.98):
            below = sum(x <= d + j * quantile(distribution, v) for x in xs)
            assert abs(below - n * v) < SIGMAS * math.sqrt(n * v * (1 - v)), (distribution, v)


def test_paretonormal_mean() -> None:
    # 0.25 * normal + 0.75 * pareto at the same quantile: the mean is 0.75 * E[g] (the clipped normal
    # has mean 0); the standard error uses the sample's own standard deviation.
    n, d, j = 20_000, 0.050, 0.010
    xs = delays(NetemSpec(delay=DelaySpec(d, j, distribution="paretonormal")), n, seed=10)
    mean, _ = pareto_clipped_moments()
    assert abs(fmean(xs) - (d + 0.75 * j * mean)) < SIGMAS * pstdev(xs) / math.sqrt(n)


def test_delay_correlation_is_the_lag1_autocorrelation_of_uniform_jitter() -> None:
    # With uniform jitter the delay is affine in x_n = (1 - c) U_n + c x_{n-1}: an AR(1) sequence whose
    # lag-1 autocorrelation is exactly c; its estimate has standard error ~ sqrt((1 - c^2) / n).
    # Without correlation the draws are independent: standard error 1/sqrt(n).
    n, c = 20_000, 0.5
    plain = delays(NetemSpec(delay=DelaySpec(0.02, 0.005)), n, seed=11)
    assert abs(lag1_autocorrelation(plain)) < SIGMAS / math.sqrt(n)
    correlated = delays(NetemSpec(delay=DelaySpec(0.02, 0.005, c)), n, seed=11)
    assert abs(lag1_autocorrelation(correlated) - c) < SIGMAS * math.sqrt((1 - c * c) / n)
    # The mix keeps the mean but narrows the spread: Var x = (1 - c) / (12 (1 + c)) instead of 1/12
    # (stationary variance of the AR(1) with innovations (1 - c) U). The draws are correlated, so the
    # standard error of the sample standard deviation comes from 40 batches of 500 (the correlation
    # dies out within a few packets, so batches are nearly independent).
    expected_sd = 2 * 0.005 * math.sqrt((1 - c) / (12 * (1 + c)))
    batch_sds = [pstdev(correlated[i : i + 500]) for i in range(0, n, 500)]
    standard_error = pstdev(batch_sds) / math.sqrt(len(batch_sds))
    assert abs(pstdev(correlated) - expected_sd) < SIGMAS * standard_error
    normal = delays(NetemSpec(delay=DelaySpec(0.05, 0.005, c, "normal")), n, seed=12)
    assert lag1_autocorrelation(normal) > 0.3  # raised through the quantile function too


# -- Gilbert-Elliott and the 4-state model ---------------------------------------------------------------


def test_gilbert_burst_and_gap_lengths_match_the_model() -> None:
    # Simple Gilbert: h = 0 (every packet in the bad state is lost), k = 1 (none in the good state), so a
    # packet is lost exactly when the chain is in B when it arrives. After each packet the chain leaves B
    # with probability r, so a loss burst lasts L packets with P(L = l) = (1 - r)^(l-1) r: geometric,
    # mean 1/r, variance (1 - r)/r^2. Likewise a gap between bursts: mean 1/p, variance (1 - p)/p^2.
    # Bursts are independent (renewals of the chain), so the mean of M of them has standard error
    # sqrt(variance / M). The stationary loss rate is pi_B = p / (p + r).
    n, p, r = 100_000, 0.05, 0.25
    xs = loss_indicators(NetemSpec(loss=GilbertElliottLoss(p, r, h=0.0, k=1.0)), n, seed=13)
    bursts, gaps = runs(xs, 1), runs(xs, 0)
    assert len(bursts) > 3000  # ~ n p r / (p + r) = 4167
    assert abs(fmean(bursts) - 1 / r) < SIGMAS * math.sqrt((1 - r) / r**2 / len(bursts))
    assert abs(fmean(gaps) - 1 / p) < SIGMAS * math.sqrt((1 - p) / p**2 / len(gaps))
    rate = p / (p + r)
    assert abs(fmean(xs) - rate) < SIGMAS * markov_loss_sd(p, r, 1.0, 0.0) / math.sqrt(n)


def markov_loss_sd(p: float, r: float, loss_bad: float, loss_good: float) -> float:
    """Asymptotic standard deviation per packet of the loss indicator of a Gilbert-Elliott chain.

    Given the states, packets are lost independently with a_S; Cov(X_i, X_j) = (a_B - a_G)^2 pi_B pi_G
    lambda^|i-j| with lambda = 1 - p - r. Summing: Var(sum X) / n -> q (1 - q) + 2 (a_B - a_G)^2 pi_B
    pi_G lambda / (1 - lambda), q being the mean loss rate.
    """
    pi_b = p / (p + r)
    pi_g = 1 - pi_b
    q = pi_g * loss_good + pi_b * loss_bad
    lam = 1 - p - r
    return math.sqrt(q * (1 - q) + 2 * (loss_bad - loss_good) ** 2 * pi_b * pi_g * lam / (1 - lam))


def test_gilbert_elliott_loss_rate() -> None:
    # netem's "loss gemodel 2% 20% 70% 1%": p, r, then the LOSS probabilities 1-h and 1-k.
    n = 100_000
    spec = parse_netem("loss gemodel 2% 20% 70% 1%")
    assert spec.loss == GilbertElliottLoss(0.02, 0.2, h=0.3, k=0.99)
    xs = loss_indicators(spec, n, seed=14)
    pi_b = 0.02 / 0.22
    q = (1 - pi_b) * 0.01 + pi_b * 0.7  # ~ 0.0727
    assert abs(fmean(xs) - q) < SIGMAS * markov_loss_sd(0.02, 0.2, 0.7, 0.01) / math.sqrt(n)


def test_gemodel_with_only_p_is_bernoulli() -> None:
    # tc's defaults r = 1 - p, 1-h = 1, 1-k = 0: the next state is B with probability p whatever the
    # current one, so losses are i.i.d. with rate p.
    n, p = 50_000, 0.1
    xs = loss_indicators(parse_netem("loss gemodel 10%"), n, seed=15)
    assert abs(sum(xs) - n * p) < SIGMAS * math.sqrt(n * p * (1 - p))
    assert abs(lag1_autocorrelation(xs)) < SIGMAS / math.sqrt(n)


def test_state_model_with_only_p13_is_bernoulli() -> None:
    # tc's defaults p31 = 1 - p13, p32 = 0, p23 = 1, p14 = 0: from state 1 or 3 the next is 3 (lost)
    # with probability p13, so losses are i.i.d. with rate p13 (tc-netem(8): "the Bernoulli model").
    n, p = 50_000, 0.05
    xs = loss_indicators(parse_netem("loss state 5%"), n, seed=16)
    assert abs(sum(xs) - n * p) < SIGMAS * math.sqrt(n * p * (1 - p))
    assert abs(lag1_autocorrelation(xs)) < SIGMAS / math.sqrt(n)


def test_four_state_model_loss_rate_and_burst_length() -> None:
    # Stationary distribution (state 4 always returns to 1): pi4 = pi1 p14, pi3 p31 = pi1 p13, and
    # pi2 p23 = pi3 p32. A packet is lost when the chain enters 3 or 4 (or stays in 3): rate pi3 + pi4.
    # Loss runs are either an isolated loss (state 4, length 1) or a stay in 3, geometric with mean
    # 1 / (p31 + p32); they start at rates pi1 p14 and pi1 p13 + pi2 p23 per packet respectively.
    # The loss-rate bound uses batch means (50 batches of 2000 packets: the chain mixes within a few
    # tens of packets); the run-length bound uses the runs' own sample standard deviation.
    p13, p31, p32, p23, p14 = 0.02, 0.3, 0.1, 0.4, 0.01
    n = 100_000
    xs = loss_indicators(NetemSpec(loss=StateLoss(p13, p31, p32, p23, p14)), n, seed=17)
    pi1 = 1 / (1 + p14 + p13 / p31 + p13 * p32 / (p31 * p23))
    pi3 = pi1 * p13 / p31
    pi2 = pi3 * p32 / p23
    rate = pi3 + pi1 * p14
    batches = [fmean(xs[i : i + 2000]) for i in range(0, n, 2000)]
    standard_error = pstdev(batches) / math.sqrt(len(batches))
    assert abs(fmean(xs) - rate) < SIGMAS * standard_error
    isolated, bursty = pi1 * p14, pi1 * p13 + pi2 * p23
    expected_run = (isolated * 1 + bursty / (p31 + p32)) / (isolated + bursty)
    lengths = runs(xs, 1)
    assert abs(fmean(lengths) - expected_run) < SIGMAS * pstdev(lengths) / math.sqrt(len(lengths))


# -- rate, duplicate, corrupt, reorder -----------------------------------------------------------------


def test_rate_limited_throughput_is_the_rate_including_the_overhead() -> None:
    # Offer 1.5x the link rate of random-size datagrams; over a saturated window the link delivers R bits
    # per second counting each datagram's wire size (payload + overhead), within 2 %. Counting payload
    # only falls short by the overhead's share, which shows that the overhead is charged.
    rate, overhead = 2e6, 28
    link = NetemLink(parse_netem(f"rate 2mbit {overhead} limit 100000"), seed=18)
    rng = random.Random(18)
    now = 0.0
    wire = payload = 0  # bits delivered within the window [1 s, 9 s)
    while now < 10.0:
        size = rng.randint(50, 1400)
        now += (size + overhead) * 8 / (1.5 * rate) * rng.expovariate(1.0)
        for data, _ in link.deliver(now):  # collected at arrivals, ~1 ms apart: edge error < 0.1 %
            if 1.0 <= now < 9.0:
                wire += (len(data) + overhead) * 8
                payload += len(data) * 8
        link.send(bytes(size), now)
    assert abs(wire / 8.0 - rate) < 0.02 * rate
    assert payload / 8.0 < 0.97 * rate


def test_duplicate_corrupt_and_reorder_rates_are_binomial() -> None:
    # Each decision is an independent Bernoulli trial per packet (no correlation): counts are binomial.
    n = 40_000
    link = NetemLink(parse_netem("delay 10ms duplicate 10% corrupt 5% reorder 25%"), seed=19)
    for i in range(n):
        link.send(b"payload", i * 0.001)
        link.deliver(i * 0.001)
    s = link.stats
    assert abs(s.duplicated - 0.1 * n) < SIGMAS * math.sqrt(n * 0.1 * 0.9)
    copies = n + s.duplicated  # corrupt and reorder decide for every copy
    assert abs(s.corrupted - 0.05 * copies) < SIGMAS * math.sqrt(copies * 0.05 * 0.95)
    assert abs(s.reordered - 0.25 * copies) < SIGMAS * math.sqrt(copies * 0.25 * 0.75)
