"""Who may take a full slave's slot (PROTOCOL.md 5.1, rule 2.7; tdtp/admission/slots.py), in fake time.

A slot goes only to a master whose predecessor is *gone* (nothing heard for ``reclaim_after``) or,
keyed, to the same master opening again from another address while its old session is silent. A
flood of cookie-validated OPENs during a live operator's 0.2 s hiccup takes nothing (before: the
operator's slot went to the attacker in every hiccup longer than the 0.1 s watchdog), and one source
holds at most its share of the slots.
"""

from __future__ import annotations

import pytest
from slave_table import SLAVE, Master, Network, SlaveTable

from tdtp import AdmissionConfig, CloseCause, ConnectionConfig, InvalidArgumentError, State
from tdtp.admission.slots import EvictionNotices, SessionSlots, Verdict, source_of
from tdtp.protection.keys import KeyRing, PresharedKey
from tdtp.wire.control import CloseReason

OPERATOR_KEY = PresharedKey(bytes(range(32)), name="operator")
ATTACKER_KEY = PresharedKey(bytes(range(100, 132)), name="attacker")
OPERATOR = ("198.51.100.10", 40000)
ATTACKER_HOST = "203.0.113.66"
ATTACKER_HOSTS = ("203.0.113.66", "203.0.113.67", "203.0.113.68")
"""Three addresses: each holds one session, below its share, so that the slot rule (and not the
per-source share) is what stands between the flood and the operator's slot."""


def _rate(times: list[float], start: float, end: float) -> float:
    return sum(start <= t < end for t in times) / (end - start)


def _attack(
    net: Network, keyed: bool, loops: int, *, share: int = 3, settle: float = 0.0
) -> tuple[list[Master], dict[str, int]]:
    """The attacker, from three addresses: ``share`` live sessions of its own (it keeps them
    alive), then ``loops`` masters that open, are refused, and open again from the next port at
    once: every OPEN that reaches a slot decision carries a valid cookie (and, keyed, a tag under
    the attacker's key). ``settle``: seconds between taking its slots and the flood. The flood
    stops when ``counts["stop"]`` is set."""
    key = ATTACKER_KEY if keyed else None
    counts = {"opens": 0, "port": 41000, "stop": 0}

    def next_master() -> Master:
        counts["port"] += 1
        counts["opens"] += 1
        host = ATTACKER_HOSTS[counts["port"] % len(ATTACKER_HOSTS)]
        return net.add_master((host, counts["port"]), key=key, seed=counts["port"])

    held = []
    for _ in range(share):
        master = next_master()
        master.rate = 100.0
        held.append(master)
    net.run_for(0.05)
    assert all(m.conn.state is State.ESTABLISHED for m in held)
    net.run_for(settle)

    def again(closed: Master) -> None:
        if closed.rate == 0.0:  # a flooding one, refused: the next from a new port, at once
            del net.masters[closed.addr]
            if not counts["stop"]:
                next_master()

    net.on_master_closed = again
    for _ in range(loops):
        next_master()
    return held, counts


@pytest.mark.parametrize("keyed", [False, True], ids=["unkeyed", "keyed-another-key"])
def test_an_open_flood_during_a_live_operators_hiccup_takes_nothing(keyed: bool) -> None:
    config = ConnectionConfig()
    keys = KeyRing([OPERATOR_KEY, ATTACKER_KEY]) if keyed else None
    slave = SlaveTable(config, max_peers=4, keys=keys)
    net = Network(slave)
    operator = net.add_master(OPERATOR, rate=1000.0, key=OPERATOR_KEY if keyed else None)
    net.run_for(0.05)
    assert operator.conn.state is State.ESTABLISHED
    # The operator has been at work for a second (a session in its first half second comes back
    # more slowly from any silence: the controller resumes at half its rate before it).
    _, counts = _attack(net, keyed, loops=4, settle=0.9)
    net.run_for(0.2)
    refused_before = slave.slots.stats.refused_busy
    net.freeze(operator, 0.2)  # a GC pause: it neither sends nor reads for 0.2 s
    net.run_for(0.2)
    thawed = net.now
    refused_during = slave.slots.stats.refused_busy - refused_before
    net.run_for(0.3)
    counts["stop"] = 1
    net.run_for(0.8)
    (mine,) = [s for s in slave.all_sessions() if s.master == OPERATOR]
    # The flood went on throughout: validated OPENs by the hundred, a few hundred in the freeze.
    assert counts["opens"] > 500 and refused_during > 200, (counts, refused_during)
    assert slave.slots.stats.reclaimed == 0 and slave.slots.stats.refused_share == 0
    assert mine.closed is None and operator.conn.state is State.ESTABLISHED
    assert _rate(mine.delivered, thawed + 0.1, thawed + 1.1) >= 900.0


def test_a_gone_master_is_reclaimed_and_told_why_when_it_comes_back() -> None:
    config = ConnectionConfig(admission=AdmissionConfig(reclaim_after=1.0))
    slave = SlaveTable(config, max_peers=4)
    net = Network(slave)
    operator = net.add_master(OPERATOR, rate=1000.0)
    net.run_for(0.05)
    _attack(net, keyed=False, loops=1)
    net.cut(operator, 1.3)  # its path is down longer than reclaim_after: the CLOSE is lost too
    net.run_for(0.95)
    assert slave.slots.stats.reclaimed == 0  # 0.95 s of silence: not gone yet
    net.run_for(0.35)
    (mine,) = [s for s in slave.all_sessions() if s.master == OPERATOR]
    assert mine.closed is not None and mine.closed.cause is CloseCause.EVICTED
    assert mine.closed.reason == CloseReason.EVICTED
    assert "reclaims a slot after 1 s" in mine.closed.detail
    assert slave.slots.stats.reclaimed == 1
    net.run_for(0.2)  # the path is back: the master's datagrams draw the CLOSE EVICTED, no RESET
    event = operator.conn.close_event
    assert event is not None and event.cause is CloseCause.EVICTED, event
    assert event.reason == CloseReason.EVICTED
    assert slave.notices.sent >= 1
    assert slave.admission.stats.resets_sent == 0


def test_the_same_master_restarting_elsewhere_takes_back_its_own_slot_at_once() -> None:
    """Keyed: a master that restarted opens from a new port while its old session is silent; the
    old one is its own and gives way (the watchdog's silence suffices). Another key may not."""
    config = ConnectionConfig()
    slave = SlaveTable(config, max_peers=4, keys=KeyRing([OPERATOR_KEY, ATTACKER_KEY]))
    net = Network(slave)
    old = net.add_master(OPERATOR, rate=1000.0, key=OPERATOR_KEY)
    net.run_for(0.05)
    _attack(net, keyed=True, loops=4)
    net.freeze(old, 60.0)  # the old process is gone
    net.run_for(0.3)
    assert slave.slots.stats.reclaimed == 0  # the attacker's key took nothing meanwhile
    new = net.add_master(("198.51.100.10", 40999), rate=1000.0, key=OPERATOR_KEY, seed=77)
    net.run_for(0.3)
    assert new.conn.state is State.ESTABLISHED
    (gone,) = [s for s in slave.all_sessions() if s.master == OPERATOR]
    assert gone.closed is not None and gone.closed.cause is CloseCause.EVICTED
    assert "same master" in gone.closed.detail
    assert slave.slots.stats.reclaimed_same_master == 1


def test_one_source_holds_at_most_its_share() -> None:
    """max_peers 4, share 0.5: two per source; a third from the same address (another port) is
    refused while slots are free, and a master elsewhere still gets in."""
    config = ConnectionConfig()
    slave = SlaveTable(config, max_peers=4, rate=0.0)
    net = Network(slave)
    ours = [net.add_master((ATTACKER_HOST, 42000 + i), rate=100.0, seed=i) for i in range(3)]
    net.run_for(0.1)
    states = [m.conn.state for m in ours]
    assert states.count(State.ESTABLISHED) == 2 and states.count(State.CLOSED) == 1
    refused = next(m for m in ours if m.conn.state is State.CLOSED)
    event = refused.conn.close_event
    assert event is not None and event.cause is CloseCause.REJECTED
    assert event.reason == CloseReason.BUSY
    assert slave.slots.stats.refused_share == 1
    other = net.add_master(OPERATOR, rate=100.0, seed=9)
    net.run_for(0.1)
    assert other.conn.state is State.ESTABLISHED


def test_sources_group_an_ipv6_64_and_spare_loopback() -> None:
    # Global unicast (2001:db8::/32, the documentation prefix, is not global: it is each its own).
    one, two = source_of("2a00:1450:4001:80b::1"), source_of("2a00:1450:4001:80b:ffff::9")
    assert one == two == "2a00:1450:4001:80b::/64"
    assert source_of("2a00:1450:4001:80c::1") != one
    assert source_of("fd00::1") != source_of("fd00::2")  # a LAN's stations: each its own
    assert source_of("198.51.100.7") == "198.51.100.7" != source_of("198.51.100.8")
    assert source_of("::ffff:198.51.100.7") == "198.51.100.7"
    assert (
        source_of("127.0.0.1") is None
        and source_of("::1") is None
        and source_of("127.9.9.9") is None
    )


class _Holder:
    def __init__(self, host: str, quiet: float, key: PresharedKey | None = None) -> None:
        self.peer = (host, 1)
        self.key = key
        self._quiet = quiet

    def quiet_for(self, now: float) -> float:
        return self._quiet


def test_the_policy_prefers_the_same_master_then_the_longest_gone() -> None:
    config = ConnectionConfig()
    slots = SessionSlots(config, max_peers=3)
    live, gone, older = _Holder("a", 0.05), _Holder("b", 12.0), _Holder("c", 20.0)
    placed = slots.place(None, ("d", 1), [live, gone, older], 0.0)
    assert placed.verdict is Verdict.RECLAIM and placed.holder is older
    hiccup = [_Holder("a", 0.3), _Holder("b", 0.3), _Holder("c", 9.9)]
    assert slots.place(None, ("d", 1), hiccup, 0.0).verdict is Verdict.BUSY
    same = _Holder("b", 0.15, OPERATOR_KEY)
    keyed = [_Holder("a", 0.3, ATTACKER_KEY), same, _Holder("c", 15.0, ATTACKER_KEY)]
    placed = slots.place(OPERATOR_KEY, ("e", 1), keyed, 0.0)
    assert placed.holder is same  # its own old session before anyone else's
    assert slots.place(ATTACKER_KEY, ("e", 1), keyed[:2], 0.0).verdict is Verdict.FREE


def test_eviction_notices_are_bounded_every_way() -> None:
    notices = EvictionNotices(capacity=2, lifetime=10.0, interval=0.1, repeats=3)
    close = b"C" * 23
    notices.add("a", close, 0.0)
    assert notices.answer("a", 22, 0.2) is None  # never larger than what it answers
    sent = [notices.answer("a", 100, 0.2 + i * 0.05) for i in range(20)]
    assert sum(x is not None for x in sent) == 3  # at most `repeats`, one per interval
    notices.add("b", close, 0.0)
    notices.add("c", close, 0.0)
    assert len(notices) == 2 and not notices.holds("a", 0.0)  # the oldest forgotten first
    assert notices.holds("b", 9.9) and not notices.holds("b", 10.0)


def test_reclaim_after_and_the_share_are_validated() -> None:
    with pytest.raises(InvalidArgumentError, match="reclaim_after"):
        ConnectionConfig(admission=AdmissionConfig(reclaim_after=0.5))  # < 10 x 0.1 s
    ConnectionConfig(silence_timeout=0.05, admission=AdmissionConfig(reclaim_after=0.5))
    for share in (0.0, 1.5, True, "half"):
        with pytest.raises(InvalidArgumentError, match="source_share"):
            AdmissionConfig(source_share=share)  # type: ignore[arg-type]
    with pytest.raises(InvalidArgumentError, match="reclaim_after"):
        AdmissionConfig(reclaim_after=float("inf"))
    assert SLAVE  # the fake slave's address
