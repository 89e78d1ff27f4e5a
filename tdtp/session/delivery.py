"""What reaches the application of the peer's samples: in order through the reorder wait, with an age.

The connection classifies each data packet (new, late, duplicate, stale) and counts it; this piece
decides when the sample goes up and with what figures: the reorder wait (:mod:`reorder_buffer`) holds
samples that arrived after a gap, and every sample delivered carries its send time when its own header
timed it and an estimated age otherwise (docs/PROTOCOL.md 3.6), both measured at delivery (a sample
that waited is older by its wait). The ages go into a bounded histogram for ``stats``.
"""

from __future__ import annotations

import math

from tdtp.config import ConnectionConfig
from tdtp.session.event_queue import EventQueue
from tdtp.session.events import DataReceived, new_data_received
from tdtp.session.one_way import OneWayDelay
from tdtp.session.reorder_buffer import ReorderBuffer
from tdtp.session.rtt import RttEstimator
from tdtp.session.sample_age import SampleAgeHistogram
from tdtp.session.stats import ConnectionStats


class SampleDelivery:
    """Hands the peer's samples to the event queue, in order and timed."""

    __slots__ = (
        "_config",
        "_events",
        "_one_way",
        "_rtt",
        "_stats",
        "ages",
        "newest_held",
        "opening_rtt",
        "opening_sent_at",
        "reorder",
    )

    def __init__(
        self,
        config: ConnectionConfig,
        *,
        events: EventQueue,
        stats: ConnectionStats,
        rtt: RttEstimator,
        one_way: OneWayDelay,
    ) -> None:
        self._config = config
        self._events = events
        self._stats = stats
        self._rtt = rtt
        self._one_way = one_way
        self.reorder: ReorderBuffer | None = None
        """Samples that arrived after a gap, waiting for it (``None``: delivered as they arrive)."""
        self.ages = SampleAgeHistogram()
        self.opening_rtt: float | None = None
        """The opening's round trip: all the receiving end of a one-way stream ever measures."""
        self.newest_held: DataReceived | None = None
        """The newest sample that arrived and waits in the reorder wait behind a gap, if it is
        newer than every sample delivered: a latest-value reader wants it now, not in order."""
        self.opening_sent_at = math.nan
        """When our last OPEN (master) or OPEN_ACK (slave) left."""

    def on_opened(self, now: float) -> None:
        """The opening's answer arrived: its round trip, from our last OPEN (OPEN_ACK) to the
        OPEN_ACK (the master's first packet). If an earlier copy was answered it reads short, as
        TCP's handshake sample can."""
        sent_at = self.opening_sent_at
        if not math.isnan(sent_at) and now >= sent_at:
            self.opening_rtt = now - sent_at

    def open(self, initial_seq: int, keyed: bool) -> None:
        """The peer's data starts at ``initial_seq``: deliver it in order, through a reorder wait,
        unless the application asked for arrival order or for no wait (unkeyed: one that forged
        numbers cannot lengthen)."""
        config = self._config
        if config.deliver_late or config.max_reorder_wait <= 0.0:
            self.reorder = None
        else:
            self.reorder = ReorderBuffer(initial_seq, config.max_reorder_wait, guarded=not keyed)

    def on_gap(self, seq: int, gap: int, now: float) -> None:
        """A new sample ``seq`` skipped the ``gap`` sequence numbers below it (reorder wait on)."""
        reorder = self.reorder
        if reorder is not None:
            reorder.on_gap(seq - gap, seq, now)

    def on_late(self, seq: int, highest: int, now: float) -> bool:
        """A sample arrived after a newer one (reorder wait on; ``highest`` the newest arrived):
        measure its displacement. True if its gap is still open (it goes up in order), False if the
        gap was given up (it is late)."""
        reorder = self.reorder
        if reorder is None:
            return False
        reorder.on_late(seq, now, highest)
        self._stats.reorder_wait = reorder.wait
        return seq >= reorder.next_seq

    def on_duplicate(self, seq: int) -> None:
        """A sample arrived a second time (reorder wait on): it may unmask a forgery (5.5)."""
        reorder = self.reorder
        if reorder is not None:
            reorder.on_duplicate(seq)

    def arrive(self, payload: bytes, seq: int, now: float, sent_at: float | None) -> bool:
        """A sample taken in while the reorder wait is on: deliver it, or hold it for a gap below
        it. True if it was held (the caller's timer may have moved)."""
        reorder = self.reorder
        if reorder is None:  # (the caller delivers directly when the wait is off)
            self.deliver(payload, seq, now, now, sent_at)
            return False
        if seq == reorder.next_seq and not reorder.held:
            # In order with nothing waiting (the common case): what accept() would say, without it.
            reorder.next_seq = seq + 1
            self.deliver(payload, seq, now, now, sent_at)
            return False
        held = not reorder.accept(seq, payload, now, sent_at)
        if not held:
            self.deliver(payload, seq, now, now, sent_at)
        else:
            newest = self.newest_held
            if newest is None or seq > newest.seq:
                self.newest_held = new_data_received(
                    payload, seq, self._estimate(now, now), now, sent_at
                )
        if reorder.held:
            self.release(now)
        return held

    def release(self, now: float) -> None:
        """Deliver what the reorder wait no longer holds back."""
        reorder = self.reorder
        if reorder is None:
            return
        for seq, payload, arrival, sent_at in reorder.release(now):
            self.deliver(payload, seq, arrival, now, sent_at)
        stats = self._stats
        stats.reorder_held = reorder.held_total
        stats.reorder_wait = reorder.wait

    def deadline(self) -> float | None:
        reorder = self.reorder
        return None if reorder is None else reorder.deadline()

    def deliver(
        self, payload: bytes, seq: int, arrival: float, now: float, sent_at: float | None
    ) -> None:
        """Hand a sample to the application (``arrival`` earlier than ``now`` if it waited;
        ``sent_at`` when its header timed it)."""
        stats = self._stats
        stats.samples_delivered += 1
        estimate = self._estimate(arrival, now)
        newest = self.newest_held
        if newest is not None and seq >= newest.seq:
            self.newest_held = None  # delivered in order now
        if sent_at is not None:
            # Timed by its own header: the middle of the round trip (PROTOCOL.md 3.6).
            age: float | None = now - sent_at
            stats.samples_timed += 1
        else:
            age = estimate
        if age is not None:
            ages = self.ages
            if ages.run_low <= age <= ages.run_high:
                ages.run += 1  # the histogram's add, its common case inline
            else:
                ages.add(age)
        event = new_data_received(payload, seq, estimate, now, sent_at)
        events = self._events
        if events.solo is None and not events.items:
            events.solo = event  # EventQueue.push_data's common case, inline
        else:
            events.push_data(event)

    def _estimate(self, arrival: float, now: float) -> float | None:
        """The inbound one-way delay the peer's stamps measure, or half the smoothed RTT (or of the
        opening's round trip), plus the reorder wait spent."""
        rtt = self._rtt
        estimate = self._one_way.estimate()
        if estimate is None and rtt.has_sample:
            estimate = rtt.srtt / 2
        elif estimate is None:
            opening = self.opening_rtt
            estimate = None if opening is None else opening / 2
        if estimate is not None:
            estimate += now - arrival  # the reorder wait it spent
        return estimate
