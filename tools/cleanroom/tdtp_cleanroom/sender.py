"""The sender's record of its DATA packets (sections 3.1 and 5.4): ACK expansion, optimistic ACKs,
verdicts (acknowledged, lost, unknown), RTT estimation and the loss delay."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from .wire import HOLD_NO_ACK, HOLD_SATURATED, expand, hold_decode_ns

MAX_TRACKED = 16384
RECENT_LOSSES = 256
MIN_SAMPLE = 1e-6


@dataclass
class Record:
    send_time: float
    verdict: str | None = None  # acked, lost, unknown
    reported_absent: bool = False


@dataclass
class AckResult:
    optimistic: bool
    ack_full: int | None = None
    newly_acked: int = 0
    rtt_sample: float | None = None
    lost: list[int] = field(default_factory=list)
    spurious: int = 0


class SentLog:
    def __init__(
        self,
        first_seq: int,
        initial_rtt: float = 0.1,
        ack_delay: float = 0.02,
        reorder_threshold: int = 3,
    ) -> None:
        self.first_seq = first_seq
        self.next_seq = first_seq
        self.initial_rtt = initial_rtt
        self.ack_delay = ack_delay
        self.reorder_threshold = reorder_threshold
        self.records: dict[int, Record] = {}
        self.oldest = first_seq  # the oldest record without a verdict
        self.largest_acked: int | None = None  # LA, once an acknowledgement named one
        self.srtt = initial_rtt
        self.rttvar = initial_rtt / 2
        self.min_rtt: float | None = None
        self.has_sample = False
        self.k = 1
        self.seen_reordering = False
        self.recent_losses: deque[int] = deque(maxlen=RECENT_LOSSES)
        self.unknown_total = 0
        self.reordered = 0
        self.loss_delay = self._compute_loss_delay()

    # -- sending --
    def on_sent(self, now: float) -> int:
        seq = self.next_seq
        self.next_seq += 1
        self.records[seq] = Record(now)
        if len(self.records) > MAX_TRACKED:
            self._retire_oldest()
        return seq

    def _retire_oldest(self) -> None:
        old = min(self.records)
        rec = self.records.pop(old)
        if rec.verdict is None:
            if rec.reported_absent:
                rec.verdict = "lost"
                self.recent_losses.append(old)
            else:
                self.unknown_total += 1
        self.oldest = max(self.oldest, old + 1)

    @property
    def highest_sent(self) -> int:
        return self.next_seq - 1

    # -- section 3.1: reading a 12-bit ACK --
    def expand_ack(self, ack12: int, hold_code: int, now: float) -> int | None:
        """The full number the ACK names, or None for an optimistic ACK (a packet never sent)."""
        la = self.largest_acked if self.largest_acked is not None else self.first_seq - 1
        c0 = expand(ack12, la + 1024)  # the value in [LA - 1024, LA + 3071]
        if c0 < self.first_seq:
            c0 += 4096
        if c0 > self.highest_sent:
            return None
        hold_ns = hold_decode_ns(hold_code) if hold_code < HOLD_SATURATED else 0
        hold = (hold_ns or 0) / 1e9
        best: int | None = None
        best_err = 0.0
        cand = c0
        while cand <= self.highest_sent:
            rec = self.records.get(cand)
            if rec is not None:
                err = abs(now - rec.send_time - hold - self.srtt)
                if best is None or err < best_err:
                    best, best_err = cand, err
            cand += 4096
        return best if best is not None else c0

    # -- section 5.4 --
    def _compute_loss_delay(self) -> float:
        if self.min_rtt is None:
            return self.initial_rtt + max(4 * (self.initial_rtt / 2), 0.001) + self.ack_delay
        reorder_window = min(self.k * self.min_rtt / 4, self.srtt)
        return self.srtt + max(reorder_window, 4 * self.rttvar, 0.001) + self.ack_delay

    def on_ack(self, ack12: int, sack: int, hold_code: int, now: float) -> AckResult:
        """An accepted acknowledgement (HOLD not 255)."""
        full = self.expand_ack(ack12, hold_code, now)
        if full is None:
            return AckResult(optimistic=True)  # ignored before step 1
        res = AckResult(optimistic=False, ack_full=full)
        named = {full} | {full - i for i in range(1, 7) if sack >> (i - 1) & 1}
        top = self.records.get(full)
        top_was_open = top is not None and top.verdict is None
        # 1. Mark.
        spurious_here = 0
        for n in range(full - 6, full + 1):
            rec = self.records.get(n)
            if rec is None:
                continue
            if n in named:
                if rec.verdict is None:
                    rec.verdict = "acked"
                    res.newly_acked += 1
                    if rec.reported_absent:
                        self.reordered += 1
                        self.seen_reordering = True
                elif rec.verdict == "lost" and n in self.recent_losses:
                    # Counted once: the first acknowledgement naming a declared loss proves it
                    # spurious; later ones name it again and count nothing (finding F3).
                    self.recent_losses.remove(n)
                    spurious_here += 1
            elif rec.verdict is None:
                rec.reported_absent = True
        if spurious_here:
            res.spurious = spurious_here
            self.k = min(self.k + 1, 4)  # one step per acknowledgement that counts one
        # 2. RTT.
        if self.largest_acked is None or full > self.largest_acked:
            self.largest_acked = full
            if top_was_open and top is not None and hold_code not in (HOLD_SATURATED, HOLD_NO_ACK):
                hold = (hold_decode_ns(hold_code) or 0) / 1e9
                sample = max(now - top.send_time - hold, MIN_SAMPLE)
                self._rtt_sample(sample)
                res.rtt_sample = sample
        # 3. Verdicts.
        res.lost = self.run_verdicts(now)
        return res

    def _rtt_sample(self, s: float) -> None:
        if not self.has_sample:
            self.srtt, self.rttvar = s, s / 2
            self.has_sample = True
        else:
            self.rttvar = 0.75 * self.rttvar + 0.25 * abs(self.srtt - s)
            self.srtt = 0.875 * self.srtt + 0.125 * s
        self.min_rtt = s if self.min_rtt is None else min(self.min_rtt, s)
        self.loss_delay = self._compute_loss_delay()

    def run_verdicts(self, now: float) -> list[int]:
        """Rule 3, oldest record first, stopping at the first record that gets no verdict."""
        lost: list[int] = []
        la = self.largest_acked
        while self.oldest < self.next_seq:
            p = self.oldest
            rec = self.records.get(p)
            if rec is None:
                self.oldest += 1
                continue
            if rec.verdict is not None:
                self.oldest += 1
                continue
            if la is None:
                break
            if rec.reported_absent:
                if (p < la and now >= rec.send_time + self.loss_delay) or (
                    not self.seen_reordering and p <= la - self.reorder_threshold
                ):
                    rec.verdict = "lost"
                    self.recent_losses.append(p)
                    lost.append(p)
                    self.oldest += 1
                    continue
                break
            if p < la - 6:
                rec.verdict = "unknown"
                self.unknown_total += 1
                self.oldest += 1
                continue
            break
        return lost

    def loss_timer(self) -> float | None:
        """When the timer for the oldest reported-absent record below LA is due (None: not armed)."""
        la = self.largest_acked
        if la is None:
            return None
        for n in range(self.oldest, min(la, self.next_seq)):
            rec = self.records.get(n)
            if rec is not None and rec.verdict is None and rec.reported_absent:
                return rec.send_time + self.loss_delay
        return None

    def on_timer(self, now: float) -> list[int]:
        return self.run_verdicts(now)
