"""A datagram from an unknown address is offered to path migration before it may draw a RESET
(docs/PROTOCOL.md 5.7, 5.8): only one that no session can own is ``unclaimed``."""

from __future__ import annotations

import random

from tdtp.admission.path_migration import PathMigration
from tdtp.admission.rate_limit import TokenBucket
from tdtp.config import AdmissionConfig
from tdtp.session.events import Address
from tdtp.wire import encode_header

NEW: Address = ("127.0.0.1", 40001)
DATA = encode_header(0, 7, 0, 0, 255) + bytes(40)


class FakeSession:
    """What path migration asks of a session; ``owns`` says whether a keyed trial succeeds."""

    def __init__(self, *, keyed: bool, last_heard: float, owns: bool = False) -> None:
        self.migratable = True
        self.keyed = keyed
        self.master_nonce = bytes(16)
        self._last = last_heard
        self._owns = owns
        self.moved_to: Address | None = None

    def quiet_for(self, now: float) -> float:
        return now - self._last

    def roam(self, data: bytes, addr: Address, *, now: float) -> bool:
        if self._owns:
            self.moved_to = addr
        return self._owns

    def migrate(self, addr: Address, *, now: float) -> None:
        self.moved_to = addr


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
