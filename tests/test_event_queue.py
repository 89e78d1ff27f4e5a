"""The connection's event queue: order, bounds and what it drops, with its one-sample slot."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from tdtp.session.event_queue import EventQueue
from tdtp.session.events import (
    ConnectionEstablished,
    ControlReceived,
    DataReceived,
    Event,
    PeerResumed,
    PeerSilent,
)
from tdtp.session.stats import ConnectionStats


def _data(seq: int) -> DataReceived:
    return DataReceived(b"x", seq, None, float(seq))


def test_a_sample_alone_and_what_follows_it_keep_their_order() -> None:
    queue = EventQueue(8, ConnectionStats())
    queue.push_data(_data(1))  # alone: the slot
    assert queue.count() == 1
    queue.push(ConnectionEstablished(("127.0.0.1", 1)))  # behind it
    queue.push_data(_data(2))
    assert queue.count() == 3
    assert [type(queue.pop()).__name__ for _ in range(3)] == [
        "DataReceived",
        "ConnectionEstablished",
        "DataReceived",
    ]
    assert queue.pop() is None and queue.count() == 0


def test_a_full_queue_drops_the_oldest_sample_even_from_the_slot() -> None:
    stats = ConnectionStats()
    queue = EventQueue(1, stats)
    queue.push_data(_data(1))
    queue.push_data(_data(2))  # full: sample 1 goes
    assert stats.events_discarded == 1
    popped = queue.pop()
    assert isinstance(popped, DataReceived) and popped.seq == 2
    queue.push_data(_data(3))
    queue.push_watchdog(PeerSilent(1.0, 4.0))  # full: the sample makes room
    assert stats.events_discarded == 2
    assert isinstance(queue.pop(), PeerSilent) and queue.pop() is None


class _Model:
    """The queue as a plain list: the reference for the slot's bookkeeping."""

    def __init__(self, bound: int) -> None:
        self.items: list[Event] = []
        self.bound = bound
        self.discarded = 0

    def drop_oldest(self, kinds: tuple[type, ...]) -> bool:
        for index, item in enumerate(self.items):
            if isinstance(item, kinds):
                del self.items[index]
                self.discarded += 1
                return True
        return False

    def push(self, kind: str, event: Event) -> None:
        full = len(self.items) >= self.bound
        if kind == "data" and full:
            self.drop_oldest((DataReceived,))
        if kind == "watchdog" and full and not self.drop_oldest((DataReceived,)):
            self.drop_oldest((PeerSilent, PeerResumed))
        self.items.append(event)


@settings(max_examples=200, deadline=None)
@given(ops=st.lists(st.sampled_from(["data", "control", "life", "watchdog", "pop"]), max_size=60))
def test_the_queue_behaves_as_a_list(ops: list[str]) -> None:
    stats = ConnectionStats()
    queue = EventQueue(4, stats)
    model = _Model(4)
    for index, op in enumerate(ops):
        if op == "pop":
            expected = model.items.pop(0) if model.items else None
            assert queue.pop() == expected
            continue
        event: Event
        if op == "data":
            event = _data(index)
            queue.push_data(event)
        elif op == "control":
            event = ControlReceived(bytes([index]), index, float(index))
            queue.push_control(event)
        elif op == "life":
            event = ConnectionEstablished(("127.0.0.1", index))
            queue.push(event)
        else:
            event = PeerResumed(float(index), float(index))
            queue.push_watchdog(event)
        model.push(op, event)
        assert queue.count() == len(model.items)
    assert stats.events_discarded == model.discarded
