"""Events are plain frozen dataclasses in both builds (tests/test_*.py also runs on the pure build):
an application may pickle them (to another process), copy them and compare them."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import pytest

from tdtp.session.events import (
    CloseCause,
    ConnectionClosed,
    ConnectionEstablished,
    DataReceived,
    PeerResumed,
    PeerSilent,
    new_data_received,
)

EVENTS = [
    ConnectionEstablished(("127.0.0.1", 9000)),
    DataReceived(b"sample", 7, 0.002, 12.5),
    new_data_received(b"sample", 7, 0.002, 12.5, None),
    ConnectionClosed(CloseCause.IDLE_TIMEOUT, "nothing heard for 30 s"),
    PeerSilent(1.0, 1.1),
    PeerResumed(1.0, 2.5),
]


@pytest.mark.parametrize("event", EVENTS, ids=lambda event: type(event).__name__)
def test_an_event_pickles_copies_and_stays_frozen(event: object) -> None:
    assert pickle.loads(pickle.dumps(event)) == event
    assert copy.copy(event) == event
    assert copy.deepcopy(event) == event
    assert hash(copy.copy(event)) == hash(event)
    field = dataclasses.fields(event)[0].name  # type: ignore[arg-type]
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(event, field, None)


def test_the_fast_constructor_builds_the_same_sample() -> None:
    fast = new_data_received(b"x", 1, None, 2.0, None)
    assert fast == DataReceived(b"x", 1, None, 2.0)
    assert repr(fast) == repr(DataReceived(b"x", 1, None, 2.0))
