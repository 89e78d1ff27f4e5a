"""Who holds a slave's ``max_peers`` slots, and who may take one (docs/PROTOCOL.md 5.1, rule 2.7).

Sans-IO, like the admission it follows. A validated OPEN (:class:`~tdtp.admission.AdmittedOpen`) from
an address that holds no session asks :meth:`SessionSlots.place` for a slot and gets a
:class:`Placement`:

* ``FREE``: a slot is free and the OPEN's source holds less than its share;
* ``RECLAIM``: the slave is full (or the source holds its share), and the session named must end
  first (closed as ``EVICTED``, its master told so): its master is *gone*, not hiccuping. Gone means
  nothing heard from it for ``reclaim_after`` (10 s: a hundred watchdog periods, longer than any
  Wi-Fi hiccup, GC pause or handover the watchdog reports), or, keyed, that the same master (the same
  key) now opens from another address while its old session is silent (it restarted);
* ``BUSY`` / ``SHARE``: refused with REJECT ``BUSY``; every slot is held by a master heard within
  ``reclaim_after`` (BUSY), or the source already holds its share of the slots (SHARE).

Before issue 31 a full slave gave the slot of any session silent for the watchdog's
``silence_timeout`` (0.1 s) to any validated OPEN: an attacker re-sending cookie-validated OPENs took
a live operator's slot in every 0.2 s hiccup.

**Per-source share.** One source may hold at most ``floor(source_share * max_peers)`` slots (at
least 1; ``source_share`` is 0.5 by default, so no source ever holds most of them). A source is an
IPv4 address, or the /64 of a global IPv6 address (a host gets a whole /64 and picks any address in
it; SLAAC privacy addresses change within it), or the whole address of a non-global IPv6 one. IPv4
is not grouped by /24: a site's operator stations usually share one LAN and would share one share,
while an attacker with many IPv4 addresses is a botnet, which a share cannot stop. Loopback sources
(127.0.0.0/8, ::1) are exempt: they are processes of the slave's own host, which has every other
means to limit them, and a slave whose masters run beside it (a simulation, a test bench) keeps all
its slots.

:class:`EvictionNotices` repeats an evicted session's CLOSE ``EVICTED`` to its master's later
datagrams: it was away when the CLOSE left, and would otherwise draw a RESET ("the slave restarted")
and reopen at once instead of backing off.
"""

from __future__ import annotations

import enum
import functools
import ipaddress
import math
from collections import OrderedDict
from collections.abc import Hashable, Iterable
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

from tdtp.config import ConnectionConfig
from tdtp.protection.keys import PresharedKey
from tdtp.wire.address import Address

SAME_MASTER_TEXT = (
    "the same master (key {key}) opened a new session from {where} while this one was silent "
    "({quiet:.1f} s): it restarted, and its new session took this one's slot"
)
GONE_TEXT = (
    "the server was full and nothing had been heard from this master for {quiet:.1f} s (the "
    "server reclaims a slot after {after:g} s); its slot went to a new master"
)


class SlotHolder(Protocol):
    """What the slot policy needs of a session (:class:`~tdtp.session.connection.Connection`)."""

    @property
    def peer(self) -> Address | None: ...
    @property
    def key(self) -> PresharedKey | None: ...
    def quiet_for(self, now: float) -> float: ...


Holder = TypeVar("Holder", bound=SlotHolder)


class Verdict(enum.Enum):
    """What :meth:`SessionSlots.place` decided for a validated OPEN."""

    FREE = "free"
    """A slot is free: open the session."""
    RECLAIM = "reclaim"
    """End :attr:`Placement.holder` (its master is gone, or it is the same master's old session),
    then open the session in its slot."""
    BUSY = "busy"
    """Every slot is held by a master heard within ``reclaim_after``: REJECT ``BUSY``."""
    SHARE = "share"
    """The OPEN's source holds its share of the slots already: REJECT ``BUSY``."""


@dataclass(frozen=True, slots=True)
class Placement(Generic[Holder]):
    verdict: Verdict
    holder: Holder | None = None
    """The session to end first (``RECLAIM``)."""
    detail: str = ""
    """Why, in words: the evicted session's close detail (``RECLAIM``)."""


@functools.lru_cache(maxsize=4096)
def source_of(host: str) -> str | None:
    """The fairness group of a source host (see the module docstring): ``None`` for loopback
    (exempt), the /64 of a global IPv6 address, else the address itself."""
    try:
        address = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return host  # not an address (a test's name): itself
    if isinstance(address, ipaddress.IPv6Address):
        mapped = address.ipv4_mapped
        if mapped is not None:
            address = mapped
        elif address.is_global:
            return str(ipaddress.IPv6Network((address, 64), strict=False))
    if address.is_loopback:
        return None
    return str(address)


@dataclass(slots=True)
class SlotStats:
    """What the slot policy decided."""

    reclaimed: int = 0
    """Sessions ended to give their slot to a new master (``peers_evicted`` on a server)."""
    reclaimed_same_master: int = 0
    """Of ``reclaimed``: the same master's (same key's) silent old session."""
    refused_busy: int = 0
    """Validated OPENs refused because every slot was held by a master heard recently."""
    refused_share: int = 0
    """Validated OPENs refused because their source held its share of the slots."""


class SessionSlots:
    """The slot policy of one slave socket serving at most ``max_peers`` masters."""

    def __init__(self, config: ConnectionConfig, max_peers: int) -> None:
        policy = config.admission
        self.max_peers = max_peers
        self.reclaim_after = policy.reclaim_after
        """Silence after which a session's slot may go to another master (its master is gone)."""
        self.same_master_after = config.silence_timeout
        """Keyed: silence after which the same key opening from elsewhere takes the old slot."""
        self.per_source = max(1, math.floor(policy.source_share * max_peers + 1e-9))
        """Slots one source (see :func:`source_of`) may hold."""
        self.stats = SlotStats()

    def place(
        self,
        key: PresharedKey | None,
        addr: Address,
        holders: Iterable[Holder],
        now: float,
    ) -> Placement[Holder]:
        """Where a validated OPEN from ``addr`` (keyed: with ``key``) may go, given the sessions
        that hold slots now (their masters at other addresses)."""
        sessions = list(holders)
        group = source_of(str(addr[0]))
        mine = [] if group is None else [s for s in sessions if _group(s) == group]
        stats = self.stats
        if group is not None and len(mine) >= self.per_source:
            # At its share: only a slot of its own may be taken back.
            reclaim = self._reclaimable(key, addr, mine, now)
            if reclaim is None:
                stats.refused_share += 1
                return Placement(Verdict.SHARE)
            return reclaim
        if len(sessions) < self.max_peers:
            return Placement(Verdict.FREE)
        reclaim = self._reclaimable(key, addr, sessions, now)
        if reclaim is None:
            stats.refused_busy += 1
            return Placement(Verdict.BUSY)
        return reclaim

    def _reclaimable(
        self, key: PresharedKey | None, addr: Address, sessions: list[Holder], now: float
    ) -> Placement[Holder] | None:
        """The session to end for the OPEN, if any: the same master's silent old session first,
        else the one whose master has been gone longest."""
        same: Holder | None = None
        gone: Holder | None = None
        same_quiet = gone_quiet = 0.0
        for session in sessions:
            quiet = session.quiet_for(now)
            if (
                key is not None
                and session.key is not None
                and session.key.key_id == key.key_id
                and quiet >= self.same_master_after
                and quiet > same_quiet
            ):
                same, same_quiet = session, quiet
            if quiet >= self.reclaim_after and quiet > gone_quiet:
                gone, gone_quiet = session, quiet
        stats = self.stats
        if same is not None and key is not None:
            stats.reclaimed += 1
            stats.reclaimed_same_master += 1
            where = f"{addr[0]}:{addr[1]}"
            detail = SAME_MASTER_TEXT.format(key=key.label, where=where, quiet=same_quiet)
            return Placement(Verdict.RECLAIM, same, detail)
        if gone is not None:
            stats.reclaimed += 1
            detail = GONE_TEXT.format(quiet=gone_quiet, after=self.reclaim_after)
            return Placement(Verdict.RECLAIM, gone, detail)
        return None


def _group(session: SlotHolder) -> str | None:
    peer = session.peer
    return None if peer is None else source_of(str(peer[0]))


@dataclass(slots=True)
class _Notice:
    datagram: bytes
    until: float
    next_at: float
    left: int


class EvictionNotices:
    """The CLOSE ``EVICTED`` of recently evicted sessions (and an exclusive server's CLOSE
    ``TAKEN_OVER``, PROTOCOL.md 5.9), by their master's address, repeated to the datagrams that
    still come from there (the master was away when it was sent, or it was lost or overtaken).

    Bounded every way: at most ``capacity`` addresses (the oldest forgotten first), each for
    ``lifetime`` (the master's own idle timeout ends its session by then), at most ``repeats``
    CLOSEs each, at most one per ``interval``, and never in answer to a datagram smaller than the
    CLOSE (so it amplifies nothing, whoever forges that address)."""

    def __init__(self, capacity: int, lifetime: float, interval: float, repeats: int = 8) -> None:
        self._notices: OrderedDict[Hashable, _Notice] = OrderedDict()
        self._capacity = capacity
        self._lifetime = lifetime
        self._interval = interval
        self._repeats = repeats
        self.sent = 0
        """CLOSEs repeated."""

    def __len__(self) -> int:
        return len(self._notices)

    def add(self, where: Hashable, datagram: bytes, now: float) -> None:
        """The session at ``where`` was evicted with ``datagram`` (its CLOSE, sent once already)."""
        notices = self._notices
        notices.pop(where, None)
        notices[where] = _Notice(
            datagram, now + self._lifetime, now + self._interval, self._repeats
        )
        while len(notices) > self._capacity:
            notices.popitem(last=False)

    def forget(self, where: Hashable) -> None:
        """A new session opens at ``where``: its evicted predecessor is history."""
        self._notices.pop(where, None)

    def answer(self, where: Hashable, size: int, now: float) -> bytes | None:
        """The CLOSE to send for a datagram of ``size`` bytes from ``where``, if one is due (see
        :meth:`holds` for whether the address is an evicted master's at all)."""
        notice = self._notices.get(where)
        if notice is None:
            return None
        if now >= notice.until:
            del self._notices[where]
            return None
        if notice.left <= 0 or now < notice.next_at or size < len(notice.datagram):
            return None
        notice.left -= 1
        notice.next_at = now + self._interval
        self.sent += 1
        return notice.datagram

    def holds(self, where: Hashable, now: float) -> bool:
        """Whether ``where`` is a recently evicted master's address: its datagrams get the CLOSE
        (when due) and nothing else, no RESET ("restarted") and no path migration."""
        notice = self._notices.get(where)
        return notice is not None and now < notice.until
