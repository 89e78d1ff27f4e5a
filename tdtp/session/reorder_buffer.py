"""The receiver's reorder wait: samples reach the application in sequence order, at most a short wait late.

A path that reorders (netem's jitter, multipath, a Wi-Fi retry) delivers a sample after a newer one.
Dropping it keeps only the newest value but throws most of the stream away: with 20 +- 5 ms of jitter
and 1 ms between samples, three in five arrive behind a newer one. Handing it up as it comes makes
the application's signal run backwards. This buffer does what a media jitter buffer does, bounded
and adaptive:

* A sample that arrives in order (the next sequence number) is delivered at once: on a path that
  does not reorder, the buffer costs nothing.
* A sample that arrives after a gap waits while the gap may still be reordering rather than loss: at
  most the *reorder wait* after the gap opened. When the missing sample arrives in that time, it
  and the ones behind it are delivered in order; when the wait runs out, the gap is given up and the
  held samples go. A sample whose gap was given up is late (dropped and counted, as before).
* The wait adapts to the reordering measured: every sample that arrives after a newer one says how
  long its gap stayed open (its *displacement*). The wait is the largest displacement of the last
  one to two seconds, with a quarter added, capped by ``max_reorder_wait``. With no reordering seen
  it is zero and gaps are given up at once (so losses alone never delay a sample); it decays back
  to zero two seconds after reordering stops. Losses never lengthen it: a lost sample has no
  displacement.

It holds at most :data:`SPAN` sequence numbers: a sample further ahead gives up the oldest gaps first,
so a peer cannot grow it. Sans-IO: every call takes ``now``; :meth:`deadline` says when
:meth:`release` has work.

In an unkeyed session (``guarded``) a displacement counts only once a sample newer than the one that
opened its gap has arrived, and only if that one never arrives a second time: a blind forgery
numbered ahead of the flow opens a gap that the real samples then fill in order, one after another,
and would otherwise prime the wait with their "displacement" (the maximum, after every loss, for
seconds); the real sample with the forgery's number then arrives as a duplicate, which gives it
away. Real reordering moves on past the sample that opened the gap, and nothing arrives twice.
"""

from __future__ import annotations

from typing import Final

SPAN: Final = 64
"""Sequence numbers the buffer spans from the next one to deliver (the receive window's width)."""
_SLOT: Final = SPAN - 1
BUCKET: Final = 1.0
"""Seconds per bucket of the displacement maximum; the wait is the larger of two buckets."""
MARGIN: Final = 1.25
"""The wait is the largest displacement measured times this."""


class ReorderBuffer:
    """Holds samples that arrived after a gap, for the application in sequence order."""

    __slots__ = (
        "_bucket_end",
        "_bucket_max",
        "_guarded",
        "_newest",
        "_opened",
        "_opener",
        "_pending",
        "_pending_opener",
        "_previous_max",
        "given_up",
        "held",
        "held_total",
        "max_wait",
        "next_seq",
        "wait",
    )

    def __init__(self, next_seq: int, max_wait: float, *, guarded: bool = False) -> None:
        self.next_seq = next_seq
        """Every sequence number below it was delivered or given up."""
        self.max_wait = max_wait
        self.wait = 0.0
        """The reorder wait in force (s): 0 until reordering is seen."""
        self.held: dict[int, tuple[bytes, float, float | None]] = {}
        """Samples waiting for a gap below them: sequence number -> (payload, arrival, the send
        time its header gave, if any)."""
        self.held_total = 0
        """Samples delivered after a wait (they arrived after a gap)."""
        self.given_up = 0
        """Sequence numbers given up (lost, or later than the wait)."""
        self._opened = [0.0] * SPAN
        """When the gap at each sequence number (mod SPAN) opened: a newer sample arrived."""
        self._opener = [0] * SPAN
        """Which sample opened the gap at each sequence number (mod SPAN)."""
        self._guarded = guarded
        self._pending_opener = -1
        """Guarded: the sample whose gap the displacement :attr:`_pending` was measured in, until a
        newer sample arrives (it counts) or the same number arrives again (it does not); -1: none."""
        self._pending = 0.0
        self._bucket_max = 0.0
        self._previous_max = 0.0
        self._bucket_end = 0.0
        self._newest = next_seq
        """The highest sequence number held (meaningful while anything is)."""

    def on_gap(self, first: int, end: int, now: float) -> None:
        """A new sample skipped ``first .. end - 1``: their gaps open now."""
        if self._pending_opener >= 0:
            self._settle(end, now)
        if end - first > SPAN:
            first = end - SPAN
        # opened[seq & _SLOT] = now for each, as at most two slices (a burst of losses skips dozens)
        start = first & _SLOT
        stop = start + end - first
        opened = self._opened
        opener = self._opener
        if stop <= SPAN:
            opened[start:stop] = [now] * (stop - start)
            opener[start:stop] = [end] * (stop - start)
        else:
            opened[start:] = [now] * (SPAN - start)
            opened[: stop - SPAN] = [now] * (stop - SPAN)
            opener[start:] = [end] * (SPAN - start)
            opener[: stop - SPAN] = [end] * (stop - SPAN)

    def on_late(self, seq: int, now: float, highest: int = 0) -> None:
        """A sample arrived after a newer one (within the receive window; ``highest`` is the newest
        arrived): measure its displacement."""
        displacement = now - self._opened[seq & _SLOT]
        if self._guarded:
            if self._pending_opener >= 0:
                self._settle(highest, now)
            opener = self._opener[seq & _SLOT]
            if highest <= opener:
                # Nothing arrived past the sample that opened its gap yet: keep the largest such
                # displacement until something does (PROTOCOL.md 5.5).
                if opener != self._pending_opener or displacement > self._pending:
                    self._pending_opener = opener
                    self._pending = displacement
                return
        self._count(displacement, now)

    def on_duplicate(self, seq: int) -> None:
        """A sample arrived a second time: if it opened the gap of a pending displacement, it was a
        forgery's number (or a duplicate of the network's), and proves no reordering."""
        if seq == self._pending_opener:
            self._pending_opener = -1

    def _settle(self, highest: int, now: float) -> None:
        """A pending displacement counts once a sample past its gap's opener has arrived."""
        if highest > self._pending_opener:
            self._pending_opener = -1
            self._count(self._pending, now)

    def _count(self, displacement: float, now: float) -> None:
        self._age_buckets(now)
        if displacement > self._bucket_max:
            self._bucket_max = displacement
            self._update_wait()

    def _age_buckets(self, now: float) -> None:
        if now >= self._bucket_end:
            # A bucket older than two ends both.
            self._previous_max = self._bucket_max if now < self._bucket_end + BUCKET else 0.0
            self._bucket_max = 0.0
            self._bucket_end = now + BUCKET
            self._update_wait()

    def _update_wait(self) -> None:
        largest = max(self._bucket_max, self._previous_max) * MARGIN
        self.wait = largest if largest < self.max_wait else self.max_wait

    def accept(self, seq: int, payload: bytes, now: float, sent_at: float | None = None) -> bool:
        """A sample not seen before. True: deliver it now (then :meth:`release` may have more);
        False: it is held (with ``sent_at``, handed back by :meth:`release`), or (``seq <
        next_seq``) it is late and the caller drops it."""
        nxt = self.next_seq
        if seq == nxt:
            self.next_seq = nxt + 1
            return True
        if seq < nxt:
            return False
        self._age_buckets(now)
        if self.wait <= 0.0 and not self.held:
            # No reordering on this path lately: a gap is a loss, given up at once.
            self.given_up += seq - nxt
            self.next_seq = seq + 1
            return True
        held = self.held
        if not held or seq > self._newest:
            self._newest = seq
        held[seq] = (payload, now, sent_at)
        return False

    def deadline(self) -> float | None:
        """When the oldest gap's wait runs out, if anything is held."""
        if not self.held:
            return None
        return self._opened[self.next_seq & _SLOT] + self.wait

    def release(self, now: float) -> list[tuple[int, bytes, float, float | None]]:
        """Held samples now deliverable, oldest first, as (sequence number, payload, arrival,
        sent_at): those
        whose gaps have filled, and those behind gaps whose wait has run out (or that fall out of
        :data:`SPAN` behind the newest held)."""
        out: list[tuple[int, bytes, float, float | None]] = []
        held = self.held
        if not held:
            return out
        self._age_buckets(now)
        newest = self._newest
        nxt = self.next_seq
        while held:
            entry = held.pop(nxt, None)
            if entry is not None:
                out.append((nxt, entry[0], entry[1], entry[2]))
                self.held_total += 1
                nxt += 1
                continue
            if newest - nxt >= SPAN:
                # Out of the span behind the newest held: give it up, and every gap up to the
                # oldest held or to the span's start, whichever comes first.
                oldest = min(held)
                target = oldest if oldest < newest - _SLOT else newest - _SLOT
            elif now >= self._opened[nxt & _SLOT] + self.wait:
                target = min(held)  # the wait ran out: give up the gap below the oldest held
            else:
                break
            self.given_up += target - nxt
            nxt = target
        self.next_seq = nxt
        return out
