"""One path of a multipath session: its two addresses, its validation, and what was measured on it.

A path is a pair (local socket, remote address). Each side keeps one :class:`Path` per pair and
numbers it with the id the side that opened it chose (0 for the path the session opened on). A path
is *validated* by this side once the peer has echoed, on that path, a token this side sent on it: the
peer receives what we send there and answers from there (docs/PROTOCOL.md 5.11). Until then nothing
but the validation exchange goes on it, and a path whose remote address was only learned from a
datagram is held to three times the bytes received on it (QUIC's amplification limit).

Both directions are measured here. As a sender: the copies sent on the path, and from the peer's
MP_REPORTs the path's round trip, loss, first copies and lag behind the first copy. As a receiver:
the peer's datagrams that arrived on it, the first copies among them, how far they lagged the first
copy, and when its next report is due.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from tdtp.session.events import Address
from tdtp.session.multipath.congestion import PathPacer
from tdtp.session.multipath.report_clock import PathDelay
from tdtp.session.rtt import RttEstimator

PROBING: Final = "probing"
"""Not validated yet: only MP_CHALLENGE and MP_RESPONSE travel on it."""
ACTIVE: Final = "active"
"""Validated and heard from recently: carries what the scheduler gives it."""
DEGRADED: Final = "degraded"
"""Validated and heard, but its recent delay or loss is out of bounds (still used)."""
FAILED: Final = "failed"
"""Validated once, but nothing has arrived on it for the path timeout: probed until it answers."""
CLOSED: Final = "closed"
"""Abandoned or refused: gone from the session."""

AMPLIFICATION_FACTOR: Final = 3
"""Bytes this side may send on a learned, unvalidated path per byte received on it."""
RING: Final = 4096
"""Sequence numbers whose per-path send count is remembered (the 12-bit SEQ space)."""
RECENT_GAIN: Final = 0.25
"""Gain of the recent RTT and loss averages: a few reports."""
LAG_GAIN: Final = 0.125
"""Gain of the receiver's average lag behind the first copy."""
MAX_TOKENS: Final = 4
"""Outstanding challenge tokens kept per path (a response to an older challenge still counts)."""
MIN_RTT_WINDOW: Final = 10.0
"""Seconds over which a path's lowest RTT is remembered (it may rise when the route changes)."""


def unwrap32(value: int, previous: int) -> int:
    """A 32-bit counter from the wire, unwrapped near ``previous`` (counters only grow)."""
    delta = (value - previous) & 0xFFFFFFFF
    return previous + delta


@dataclass(frozen=True, slots=True)
class PathStats:
    """What ``ep.paths`` shows of one path (a snapshot)."""

    path_id: int
    state: str
    local: int
    """The driver's number for the local socket it goes through (0: the session's own)."""
    remote: Address
    validated: bool
    sent: int
    """Our DATA datagrams sent on it (copies included)."""
    first_delivered: int
    """Of those, how many were the first copy of their sample to reach the peer (its reports)."""
    peer_received: int
    """Of those, how many reached the peer at all (its reports)."""
    received: int
    """The peer's DATA datagrams that arrived on it (copies included)."""
    first_received: int
    """Of those, the first copy of their sample."""
    duplicates: int
    """Of those, copies whose sample had arrived already (on another path, or twice)."""
    bytes_sent: int
    """Every datagram of ours on it, copies and path control included (TDTP bytes)."""
    srtt: float
    """Smoothed round trip on this path, from its reports and probes (s; 0 before a sample)."""
    min_rtt: float
    one_way_delay: float
    """Estimated one-way delay towards the peer: half the recent round trip plus the lag the peer
    measured behind the first copy (s; 0 before a sample)."""
    one_way_queue: float
    """Our copies' queue on their way along it, in our direction alone (s, moving average; from
    the clocks of the peer's reports, 0 before a sample)."""
    loss: float
    """Recent loss of our copies on it (fraction, from the peer's reports)."""
    lag: float
    """How far behind the first copy the peer receives ours on it (s, its reports)."""
    rate: float
    """The path's congestion control: copies per second it allows (``inf`` unlimited)."""


class Path:
    """One path: addresses, validation, amplification budget, and both directions' figures."""

    def __init__(
        self,
        path_id: int,
        local: int,
        remote: Address,
        *,
        learned: bool,
        validated: bool,
        initial_rtt: float,
        pacer: PathPacer,
        now: float,
    ) -> None:
        self.path_id = path_id
        self.local = local
        self.remote: Address = (remote[0], remote[1])
        self.learned = learned
        """Its remote address came from a datagram (the peer opened it): held to the 3x limit
        until validated."""
        self.validated = validated
        self.state = ACTIVE if validated else PROBING
        self.state_since = now
        self.created_at = now
        self.ever_active = validated
        # Validation and probing.
        self.tokens: list[tuple[bytes, float]] = []
        """Our outstanding challenges on it: (token, sent at), newest last."""
        self.last_challenge = -math.inf
        self.challenges = 0
        self.owed_token = b""
        """Learned path: the token of ours its opener must echo to validate it here."""
        # The amplification budget (learned, unvalidated paths).
        self.bytes_in = 0
        self.bytes_out = 0
        # Liveness, each way.
        self.last_heard = now
        self.last_sent = -math.inf
        # Sender side: what we sent on it and what the peer's reports say of it.
        self.sent_data = 0
        self.datagrams_sent = 0
        self.bytes_sent = 0
        self._counts = [0] * RING  # copies sent on it up to each sequence number (its slot)
        self.rtt = RttEstimator(initial_rtt)
        self.recent_rtt = 0.0
        self._min_rtt = math.inf
        self._min_rtt_next = math.inf
        self._min_rtt_since = now
        self.loss = 0.0
        self.lag = 0.0
        self.lag_at = -math.inf
        self.peer_received = 0
        self.peer_first = 0
        self._reported_expected = 0
        self._reported_seq = -1
        self._reported_hold: float | None = -1.0
        self.deficit = 0
        self._resync = False  # after an outage: the next report sets the baselines, counts nothing
        self.pacer = pacer
        self.delay = PathDelay()
        """Our direction's delay on it, from the clocks of the peer's reports."""
        # Receiver side: the peer's data that arrived on it.
        self.received = 0
        self.first = 0
        self.duplicates = 0
        self.rx_highest = -1
        self.rx_highest_at = 0.0
        self.rx_lag = 0.0
        self.unreported = False
        self.last_report = -math.inf

    # ------------------------------------------------------------------ state

    @property
    def usable(self) -> bool:
        """Validated and live: the scheduler may give it samples."""
        return self.validated and (self.state is ACTIVE or self.state is DEGRADED)

    def allowance(self) -> int:
        """Bytes that may still go on it (a learned path before validation), else a large number."""
        if self.validated or not self.learned:
            return 1 << 62
        return AMPLIFICATION_FACTOR * self.bytes_in - self.bytes_out

    def new_token(self, token: bytes, now: float) -> None:
        tokens = self.tokens
        tokens.append((token, now))
        if len(tokens) > MAX_TOKENS:
            del tokens[0]
        self.last_challenge = now
        self.challenges += 1

    def take_token(self, echo: bytes) -> float | None:
        """When our challenge with this token left, if it is one of ours (it is then used up)."""
        for index, (token, sent_at) in enumerate(self.tokens):
            if token == echo:
                del self.tokens[index]
                return sent_at
        return None

    def recovered(self) -> None:
        """Heard again after a failure: what was lost in the outage says nothing about congestion
        (the session's outage rule, PROTOCOL.md 5.4), so the next report only resets the counts."""
        self._resync = True
        self.loss = 0.0
        self.pacer.reset()

    # ------------------------------------------------------------------ sender side

    def on_data_sent(self, seq: int) -> None:
        """A copy of sample ``seq`` goes on this path (counted as a datagram by :meth:`on_sent`)."""
        self.sent_data += 1
        self._counts[seq & (RING - 1)] = self.sent_data

    def on_sent(self, size: int, now: float) -> None:
        self.datagrams_sent += 1
        self.bytes_sent += size
        self.bytes_out += size
        self.last_sent = now

    def on_rtt_sample(self, sample: float, now: float) -> None:
        self.rtt.on_sample(sample)
        sample = self.rtt.latest
        if self.recent_rtt <= 0.0:
            self.recent_rtt = sample
        else:
            self.recent_rtt += RECENT_GAIN * (sample - self.recent_rtt)
        # The lowest RTT over the last 10 to 20 s: two overlapping windows.
        if now - self._min_rtt_since >= MIN_RTT_WINDOW:
            self._min_rtt = self._min_rtt_next
            self._min_rtt_next = math.inf
            self._min_rtt_since = now
        if sample < self._min_rtt:
            self._min_rtt = sample
        if sample < self._min_rtt_next:
            self._min_rtt_next = sample

    def copies_through(self, seq: int) -> int:
        """Copies sent on the path up to sample ``seq`` (one of the last ``RING`` sent here): a
        number of the path's own, counting its copies alone."""
        return self._counts[seq & (RING - 1)]

    @property
    def reported_copies(self) -> int:
        """Copies sent on the path up to the one the peer's latest report names."""
        return self._reported_expected

    @property
    def min_rtt(self) -> float:
        return self._min_rtt if self._min_rtt < math.inf else 0.0

    @property
    def queue_delay(self) -> float:
        """How far the recent round trip lies above the lowest (0 before samples)."""
        if not self.rtt.has_sample or self._min_rtt == math.inf:
            return 0.0
        return max(0.0, self.recent_rtt - self._min_rtt)

    def one_way_delay(self, now: float) -> float:
        """Half the recent round trip, plus the peer's measured lag behind the first copy while it
        is fresh (it measures our direction alone)."""
        if not self.rtt.has_sample:
            return math.inf
        lag = self.lag if now - self.lag_at < 1.0 else 0.0
        return self.recent_rtt / 2.0 + lag

    def on_report(
        self,
        full_seq: int | None,
        sent_here: bool,
        hold: float | None,
        send_time: float | None,
        received: int,
        first: int,
        lag: float,
        now: float,
    ) -> tuple[int, int, float | None]:
        """The peer's report on this path: returns (newly received, newly lost, RTT sample)."""
        sample: float | None = None
        fresh = full_seq != self._reported_seq or hold != self._reported_hold
        if fresh and sent_here and send_time is not None and hold is not None:
            sample = now - send_time - hold  # (a repeated report times nothing new)
            self.on_rtt_sample(sample, now)
        received = unwrap32(received, self.peer_received)
        first = unwrap32(first, self.peer_first)
        got = received - self.peer_received
        lost = 0
        if self._resync and full_seq is not None and sent_here:
            self._resync = False
            expected = self._counts[full_seq & (RING - 1)]
            self._reported_expected = expected
            self.deficit = max(0, expected - received)
            self._reported_seq = full_seq
        elif full_seq is not None and sent_here:
            expected = self._counts[full_seq & (RING - 1)]
            if full_seq != self._reported_seq and expected > self._reported_expected:
                wanted = expected - self._reported_expected
                fraction = 1.0 - got / wanted if got < wanted else 0.0
                self.loss += RECENT_GAIN * (fraction - self.loss)
                self._reported_expected = expected
            deficit = expected - received
            if deficit > self.deficit:
                lost = deficit - self.deficit
            self.deficit = max(0, deficit)
            self._reported_seq = full_seq
        self._reported_hold = hold
        self.peer_received = received
        self.peer_first = first
        self.lag = lag
        self.lag_at = now
        return got, lost, sample

    # ------------------------------------------------------------------ receiver side

    def on_data_received(self, seq: int, first: bool, lag: float, now: float) -> None:
        """A DATA datagram of the peer arrived on this path (``first``: the first copy of its
        sample; else ``lag`` behind the first copy)."""
        self.received += 1
        if first:
            self.first += 1
        else:
            self.duplicates += 1
        self.rx_lag += LAG_GAIN * (lag - self.rx_lag)
        if seq > self.rx_highest:
            self.rx_highest = seq
            self.rx_highest_at = now
        self.unreported = True

    def snapshot(self, now: float) -> PathStats:
        rtt = self.rtt
        owd = self.one_way_delay(now)
        return PathStats(
            path_id=self.path_id,
            state=self.state,
            local=self.local,
            remote=self.remote,
            validated=self.validated,
            sent=self.sent_data,
            first_delivered=self.peer_first,
            peer_received=self.peer_received,
            received=self.received,
            first_received=self.first,
            duplicates=self.duplicates,
            bytes_sent=self.bytes_sent,
            srtt=rtt.srtt if rtt.has_sample else 0.0,
            min_rtt=self.min_rtt,
            one_way_delay=owd if owd < math.inf else 0.0,
            one_way_queue=self.delay.queue,
            loss=self.loss,
            lag=self.lag,
            rate=self.pacer.rate,
        )
