"""The receive window (sections 3.1, 3.2, 5.3, 5.5): arrival kinds, re-anchoring, far-ahead DATA and
the stand-alone ACKs a receiver owes in bidirectional mode."""

from __future__ import annotations

from dataclasses import dataclass, field

from .wire import expand

WINDOW = 64  # the highest and the 63 below it (section 3.1)
SACK_BITS = 6
REANCHOR_RUN = 3  # consecutive numbers older than the window (section 3.1)
FAR_AHEAD_SLACK = 32  # section 5.5
MIN_PEER_RATE = 1000.0  # R is at least 1000/s (section 5.5)


@dataclass(frozen=True)
class OwedAck:
    """A stand-alone ACK the receiver owes: ACK = `ack` (full), its SACK bits, HOLD from `since`."""

    ack: int
    sack: int
    since: float


@dataclass
class Arrival:
    kind: str  # new, late, duplicate, stale, far_ahead
    full: int
    gap: int = 0
    acks: list[OwedAck] = field(default_factory=list)


class ReceiveWindow:
    def __init__(self, initial_seq: int, silence_timeout: float, far_ahead_check: bool) -> None:
        self.initial_seq = initial_seq
        self.silence_timeout = silence_timeout
        self.far_ahead_check = far_ahead_check  # unkeyed sessions only (section 5.5)
        self.highest: int | None = None
        self.arrivals: dict[int, float] = {}  # full number -> arrival time, within the window
        # Section 3.2's bookkeeping. L starts one below the initial sequence number: nothing before
        # it exists, so P = max(L + 1, H - 6) never reaches below the first packet.
        self.last_acked = initial_seq - 1  # L
        self.pending = False
        self.oldest_unreported = 0  # P (meaningful while pending)
        self.pending_since: float | None = None  # for ack_delay (section 5.3 (a))
        # The re-anchoring run (section 3.1).
        self.run = 0
        self.run_last = 0
        # The far-ahead rate (section 5.5): 1-s windows of H's advance.
        self.rate_window: tuple[float, int] | None = None  # (opened at, the number that opened it)
        self.closed_rates: list[float] = []

    # -- helpers --
    def received(self, n: int) -> bool:
        return n in self.arrivals

    def sack_of(self, n: int) -> int:
        return sum(1 << (i - 1) for i in range(1, SACK_BITS + 1) if self.received(n - i))

    def ack_of_highest(self) -> OwedAck | None:
        if self.highest is None:
            return None
        return OwedAck(self.highest, self.sack_of(self.highest), self.arrivals[self.highest])

    def _report_highest(self) -> OwedAck:
        """Any acknowledgement of H leaves: it clears what was pending (section 3.2)."""
        owed = self.ack_of_highest()
        assert owed is not None
        self.last_acked = max(self.last_acked, owed.ack)
        self.pending = False
        self.pending_since = None
        return owed

    def _set_pending(self, p: int, now: float) -> None:
        if not self.pending:
            self.pending = True
            self.oldest_unreported = p
            self.pending_since = now
        elif p < self.oldest_unreported:
            self.oldest_unreported = p

    # -- the two ways an acknowledgement of H leaves besides the rules --
    def piggyback(self) -> OwedAck | None:
        """A DATA or KEEPALIVE leaves now carrying the acknowledgement of H (None: no data yet)."""
        if self.highest is None:
            return None
        return self._report_highest()

    def ack_delay_due(self, now: float, ack_delay: float) -> bool:
        return (
            self.pending
            and self.pending_since is not None
            and now >= self.pending_since + ack_delay
        )

    def ack_delay_ack(self) -> OwedAck | None:
        """ack_delay passed with nothing sent: the ACK owed, if any."""
        return self._report_highest() if self.pending else None

    # -- arrivals --
    def peer_rate(self) -> float:
        return max(self.closed_rates[-2:], default=0.0)

    def decode(self, seq12: int) -> int:
        expected = self.highest + 1 if self.highest is not None else self.initial_seq
        return expand(seq12, expected)

    def arrive(self, seq12: int, now: float) -> Arrival:
        """A DATA packet that passed the size checks reaches the window (row 11 of section 5.5)."""
        d = self.decode(seq12)
        h = self.highest
        # Re-anchoring (section 3.1): a packet counts if it decodes as older than the window, or,
        # after a silence, inside the window at or below the newest.
        if h is None:
            counts = False
        elif d <= h - WINDOW:
            counts = True
        elif d <= h:
            counts = now - self.arrivals[h] >= self.silence_timeout
        else:
            counts = False
        reanchored = False
        if counts:
            self.run = self.run + 1 if self.run > 0 and d == self.run_last + 1 else 1
            self.run_last = d
            if self.run == REANCHOR_RUN:
                d += 4096
                self.run = 0
                reanchored = True
        else:
            self.run = 0
        if h is not None and d > h:
            return self._new(d, now, reanchored)
        if h is None:
            return self._new(d, now, reanchored)
        if d <= h - WINDOW:
            return Arrival("stale", d)
        if self.received(d):
            return Arrival("duplicate", d)
        return self._late(d, now)

    def _new(self, n: int, now: float, reanchored: bool) -> Arrival:
        h = self.highest
        if self.far_ahead_check and h is not None and not reanchored and n - h > FAR_AHEAD_SLACK:
            since = now - self.arrivals[h]
            rate = max(2.0 * self.peer_rate(), MIN_PEER_RATE)
            if since < self.silence_timeout and n - h - FAR_AHEAD_SLACK > since * rate:
                return Arrival("far_ahead", n)
        acks: list[OwedAck] = []
        # Jump rule (section 3.2): N - 6 > P: report H as it was before N.
        if self.pending and n - SACK_BITS > self.oldest_unreported:
            acks.append(self._report_highest())
        gap = n - h - 1 if h is not None else n - self.initial_seq
        self.highest = n
        self.arrivals[n] = now
        for old in [k for k in self.arrivals if k <= n - WINDOW]:
            del self.arrivals[old]
        self._track_rate(n, now)
        if not self.pending:
            self._set_pending(max(self.last_acked + 1, n - SACK_BITS), now)
        self._full_rule(acks)
        return Arrival("new", n, max(gap, 0), acks)

    def _late(self, n: int, now: float) -> Arrival:
        h = self.highest
        assert h is not None
        self.arrivals[n] = now
        acks: list[OwedAck] = []
        if h - n > SACK_BITS:
            # Late rule: no acknowledgement of H can name it; an ACK of its own does.
            acks.append(OwedAck(n, self.sack_of(n), now))
        else:
            # A late packet within 6 below H, arriving with nothing pending or below P, becomes P.
            self._set_pending(n, now)
            self._full_rule(acks)
        return Arrival("late", n, 0, acks)

    def _full_rule(self, acks: list[OwedAck]) -> None:
        h = self.highest
        if self.pending and h is not None and h - self.oldest_unreported >= SACK_BITS:
            acks.append(self._report_highest())

    def _track_rate(self, n: int, now: float) -> None:
        # Section 5.5: the first new packet opens a window; a window closes (and the next opens) at
        # the first new packet 1 s or more after it opened; its rate is H's advance since it opened,
        # counting that packet, over the time since it opened.
        if self.rate_window is None:
            self.rate_window = (now, n)
            return
        opened, start = self.rate_window
        if now - opened >= 1.0:
            self.closed_rates.append((n - start) / (now - opened))
            del self.closed_rates[:-2]
            self.rate_window = (now, n)
