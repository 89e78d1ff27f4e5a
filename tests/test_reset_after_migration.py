"""A datagram from an unknown address is offered to path migration before it may draw a RESET
(docs/PROTOCOL.md 5.7, 5.8): only one that no session can own is ``unclaimed``."""

from __future__ import annotations

import random

from tdtp.admission.path_migration import NOT_OURS, OURS, ROAMED, PathMigration
from tdtp.admission.rate_limit import TokenBucket
from tdtp.config import AdmissionConfig
from tdtp.session.events import Address
from tdtp.wire import encode_header

NEW: Address = ("127.0.0.1", 40001)
DATA = encode_header(0, 7, 0, 0, 255) + bytes(40)


class FakeSession:
    """What path migration asks of a session; ``owns`` says whether a keyed trial succeeds (and
    ``replayed`` whether it authenticates at an old packet number)."""

    def __init__(
        self, *, keyed: bool, last_heard: float, owns: bool = False, replayed: bool = False
    ) -> None:
        self.migratable = True
        self.keyed = keyed
        self.master_nonce = bytes(16)
        self.live_gap = 0.075
        self._last = last_heard
        self._owns = owns
        self._replayed = replayed
        self.moved_to: Address | None = None

    def quiet_for(self, now: float) -> float:
        return now - self._last

    def roam(self, data: bytes, addr: Address, *, now: float) -> int:
        if self._replayed:
            return OURS
        if self._owns:
            self.moved_to = addr
            return ROAMED
        return NOT_OURS

    def migrate(self, addr: Address, *, now: float) -> None:
        self.moved_to = addr

    def move_back(self, data: bytes, addr: Address, *, now: float) -> bool:
        return False

    def take_challenge(self, now: float) -> bool:
        return True


def _paths() -> PathMigration:
    return PathMigration(AdmissionConfig(), random.Random(1), TokenBucket(1000.0, 100.0))


def test_no_session_at_all_leaves_the_datagram_unclaimed() -> None:
    paths = _paths()
    assert paths.on_unattached(DATA, NEW, 1.0, []) is None
    assert paths.unclaimed


def test_a_session_still_heard_at_its_old_address_may_own_it() -> None:
    """A master that just moved: its old path still delivers, so the session is not quiet yet."""
    paths = _paths()
    live = FakeSession(keyed=True, last_heard=1.0)
    assert paths.on_unattached(DATA, NEW, 1.001, [live]) is None
    assert not paths.unclaimed


def test_a_keyed_session_that_moves_claims_it() -> None:
    paths = _paths()
    moved = FakeSession(keyed=True, last_heard=0.0, owns=True)
    assert paths.on_unattached(DATA, NEW, 1.0, [moved]) is moved
    assert not paths.unclaimed and moved.moved_to == NEW


def test_quiet_keyed_sessions_that_all_refuse_it_leave_it_unclaimed() -> None:
    paths = _paths()
    sessions = [FakeSession(keyed=True, last_heard=0.0) for _ in range(3)]
    assert paths.on_unattached(DATA, NEW, 1.0, sessions) is None
    assert paths.unclaimed


def test_an_unkeyed_quiet_session_gets_a_challenge_not_a_reset() -> None:
    paths = _paths()
    quiet = FakeSession(keyed=False, last_heard=0.0)
    assert isinstance(paths.on_unattached(DATA, NEW, 1.0, [quiet]), bytes)
    assert not paths.unclaimed


def test_a_copy_of_a_live_keyed_sessions_datagram_is_never_unclaimed() -> None:
    """A datagram that authenticates at a packet number its session accepted already: a replay of
    the master's, sent from elsewhere. The session is alive, so nothing may answer it with a RESET
    (PROTOCOL.md 5.7); it moves nothing either (counted ``replayed``)."""
    paths = _paths()
    sessions = [
        FakeSession(keyed=True, last_heard=0.0),
        FakeSession(keyed=True, last_heard=0.0, replayed=True),
    ]
    assert paths.on_unattached(DATA, NEW, 1.0, sessions) is None
    assert not paths.unclaimed
    assert paths.stats.drops == {"replayed": 1}


def test_an_unkeyed_session_is_quiet_only_when_silent_longer_than_a_live_master() -> None:
    """A master that still sends keep-alives has not moved (PROTOCOL.md 5.8): no challenge until
    its silence exceeds a keep-alive interval and two round trips (``live_gap``)."""
    paths = _paths()
    quiet = FakeSession(keyed=False, last_heard=1.0)
    assert paths.on_unattached(DATA, NEW, 1.05, [quiet]) is None
    assert paths.stats.drops == {"no_quiet_session": 1} and not paths.unclaimed
    assert isinstance(paths.on_unattached(DATA, NEW, 1.08, [quiet]), bytes)
