"""The connection's bounded queue of events waiting for the application.

A peer can fill it (every data packet is an event), so it is bounded by ``max_pending_events``. When the
application does not keep up, stale supermedia data is worth least: the oldest :class:`DataReceived`
goes first. Watchdog events (:class:`PeerSilent`, :class:`PeerResumed`) and a multipath session's
path events (:class:`PathChanged`) share the bound: with no data event left to drop, the oldest of
them goes. Lifecycle events (established, closed) are never
dropped; there is at most one of each. Control messages (:class:`ControlReceived`) are never dropped
either: they must arrive exactly once, so the control channel bounds them itself (it takes no more
from the peer while ``control_window`` of them wait here or in the driver).

The common case is one sample at a time: it arrives, the driver takes it. That one waits in a slot of
its own (:attr:`EventQueue.solo`) instead of the deque, whose methods the compiled build can only call
by name (about 600 instructions per sample for an append and a popleft, on the way to the
application's callback). The slot holds a sample only while the deque is empty, and anything pushed
behind it moves it to the deque first, so the order is kept.
"""

from __future__ import annotations

from collections import deque

from tdtp.session.events import (
    ControlReceived,
    DataReceived,
    Event,
    PathChanged,
    PeerResumed,
    PeerSilent,
)
from tdtp.session.stats import ConnectionStats


class EventQueue:
    """Events in the order they happened; drops count in ``stats.events_discarded``."""

    def __init__(self, max_events: int, stats: ConnectionStats) -> None:
        self.items: deque[Event] = deque()
        """The events, oldest first (after :attr:`solo`). Read outside only by the connection's
        per-packet paths, which test it and :attr:`solo` before :meth:`pop` (most calls would find
        both empty) and fill :attr:`solo` directly (:meth:`push_data`'s common case)."""
        self.solo: DataReceived | None = None
        """The one sample waiting while nothing else does (only while :attr:`items` is empty)."""
        self.max_events = max_events
        self.control_pending = 0
        """ControlReceived events among them (the control channel's receive bound counts them)."""
        self._stats = stats

    def count(self) -> int:
        if self.solo is not None:
            return 1  # (the deque is empty)
        return len(self.items)

    def pop(self) -> Event | None:
        """The oldest event, or ``None``."""
        solo = self.solo
        if solo is not None:
            self.solo = None
            return solo
        events = self.items
        if not events:
            return None
        event = events.popleft()
        if type(event) is ControlReceived:
            self.control_pending -= 1
        return event

    def push_data(self, event: DataReceived) -> None:
        """A sample delivered: when the queue is full, the oldest data event makes room."""
        events = self.items
        if self.solo is None and not events:  # nothing waits: the slot
            self.solo = event
            return
        events = self._unsolo()
        if len(events) >= self.max_events:
            self._discard_oldest_data()
        events.append(event)

    def push_control(self, event: ControlReceived) -> None:
        """A control message delivered: always kept (the channel bounds how many wait)."""
        self._unsolo().append(event)
        self.control_pending += 1

    def push(self, event: Event) -> None:
        """A lifecycle event: always kept."""
        self._unsolo().append(event)

    def push_watchdog(self, event: PeerSilent | PeerResumed | PathChanged) -> None:
        """A watchdog (or multipath path) event: within the bound, making room by dropping the
        oldest data event, or failing that the oldest watchdog or path event."""
        events = self._unsolo()
        if len(events) >= self.max_events and not self._discard_oldest_data():
            for index, pending in enumerate(events):
                if isinstance(pending, PeerSilent | PeerResumed | PathChanged):
                    del events[index]
                    self._stats.events_discarded += 1
                    break
        events.append(event)

    def _unsolo(self) -> deque[Event]:
        """The deque, with the sample of the slot moved into it first (something joins it)."""
        events = self.items
        solo = self.solo
        if solo is not None:
            self.solo = None
            events.append(solo)
        return events

    def _discard_oldest_data(self) -> bool:
        """Drop the oldest data event, if there is one (False if none waits). The queue holds few
        other events (one of each lifecycle event, watchdog events within the bound, control
        messages within the channel's window), so the walk ends early."""
        events = self.items
        for index, pending in enumerate(events):
            if type(pending) is DataReceived:
                del events[index]
                self._stats.events_discarded += 1
                return True
        return False
