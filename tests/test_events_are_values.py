"""Events are plain frozen dataclasses in both builds (tests/test_*.py also runs on the pure build):
an application may pickle them (to another process), copy them and compare them."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import pytest

import tdtp
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


def test_the_compiled_build_fills_the_slots_in_c() -> None:
    """Beside the compiled core, samples are built by tdtp/session/_slot_filler.c; in the pure build
    (and where it was not built) through the slots' descriptors. Same object either way (above)."""
    filler = type(new_data_received).__name__
    if tdtp.build_info().compiled:
        assert filler == "SlotFiller"
    else:
        assert filler != "SlotFiller"


def test_the_slot_filler_refuses_what_it_cannot_build() -> None:
    slot_filler = pytest.importorskip("tdtp.session._slot_filler")
    fill = slot_filler.SlotFiller(DataReceived, ("payload", "seq"))
    with pytest.raises(TypeError, match="takes 2 values, got 1"):
        fill(b"x")
    with pytest.raises(TypeError, match="by position only"):
        fill(b"x", seq=1)
    with pytest.raises(TypeError, match="is not a slot"):
        slot_filler.SlotFiller(DataReceived, ("payload", "age"))  # a property, not a slot

    class WithNew:
        __slots__ = ("a",)

        def __new__(cls) -> WithNew:
            return super().__new__(cls)

    with pytest.raises(TypeError, match="own __new__"):
        slot_filler.SlotFiller(WithNew, ("a",))
    partial = fill(b"x", 3)
    assert partial.payload == b"x" and partial.seq == 3
    with pytest.raises(AttributeError):
        _ = partial.sent_at  # a slot not filled stays empty, as after object.__new__
