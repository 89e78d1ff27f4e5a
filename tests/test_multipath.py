"""Multipath sessions in fake time (PROTOCOL.md 5.11): the first copy wins, the session rides out one
path's failure, the scheduler and each path's congestion control, and what forged packets can do."""

from __future__ import annotations

import statistics
from collections.abc import Callable, Sequence

import pytest

from tdtp import (
    ConnectionConfig,
    ControlReceived,
    DataReceived,
    MultipathConfig,
    PathChanged,
    PeerResumed,
    PeerSilent,
)
from tdtp.session.multipath.paths import Multipath
from tdtp.wire import (
    HEADER_SIZE,
    ControlCode,
    PacketType,
    encode_header,
    encode_mp_abandon,
    encode_mp_challenge,
    encode_mp_report,
    encode_mp_response,
)
from tdtp.wire.control import MpReportBody

from multipath_pair import SLAVE_ADDR, MultipathPair, PathLink, master_addr
from pair import Direction

KEY = bytes(range(32))


def config(
    scheduler: str = "redundant", max_reorder_wait: float = 0.02, **multipath: object
) -> ConnectionConfig:
    return ConnectionConfig(
        max_reorder_wait=max_reorder_wait,
        multipath=MultipathConfig(scheduler=scheduler, **multipath),  # type: ignore[arg-type]
    )


def two_paths(fast: float = 0.020, slow: float = 0.035) -> list[PathLink]:
    return [
        PathLink(Direction(delay=fast), Direction(delay=fast)),
        PathLink(Direction(delay=slow), Direction(delay=slow)),
    ]


def running(
    links: list[PathLink],
    scheduler: str = "redundant",
    *,
    keyed: bool = False,
    rate: float = 1000.0,
    warmup: float = 1.0,
    max_reorder_wait: float = 0.02,
    **multipath: object,
) -> MultipathPair:
    cfg = config(scheduler, max_reorder_wait, **multipath)
    pair = MultipathPair(
        links,
        cfg,
        cfg,
        master_key=KEY if keyed else None,
        slave_keys=KEY if keyed else None,
    )
    pair.open()
    pair.start_samples(rate, rate)
    pair.run_for(warmup)
    return pair


def numbers(samples: list[DataReceived]) -> list[int]:
    return [int.from_bytes(sample.payload[:4], "big") for sample in samples]


def path_events(events: Sequence[object]) -> list[tuple[int, str]]:
    return [(e.path_id, e.state) for e in events if isinstance(e, PathChanged)]


def silences(events: Sequence[object]) -> int:
    return sum(isinstance(e, PeerSilent) for e in events)


def assert_conserved(pair: MultipathPair) -> None:
    for side in (pair.master, pair.slave):
        stats = side.conn.stats
        assert stats.datagrams_in == stats.received.datagrams + stats.dropped


# --------------------------------------------------------------------------- the first copy wins


@pytest.mark.parametrize("keyed", [False, True])
def test_redundant_the_first_copy_wins_and_the_others_are_duplicates(keyed: bool) -> None:
    pair = running(two_paths(), keyed=keyed)
    pair.run_for(2.0)
    for side, peer in ((pair.slave, pair.master), (pair.master, pair.slave)):
        got = numbers(side.received)
        assert len(got) == len(set(got)), "a sample delivered twice"
        assert len(got) >= peer.offered - 40  # all but those in flight
        paths = side.conn.multipath
        assert paths is not None
        drops = side.conn.stats.drops
        # Every copy after the first is dropped as a duplicate, never as a replay or stale.
        assert drops.get("duplicate", 0) == paths.stats.duplicates > 1800
        assert "replayed" not in drops and "stale" not in drops and "late" not in drops
        # The fast path delivered (nearly) every first copy; latency is the fast path's.
        stats = {p.path_id: p for p in paths.path_stats(pair.now)}
        assert stats[0].first_received > 0.95 * len(got)
        assert stats[1].duplicates > 0.95 * stats[1].received
        assert max(side.latency[-1000:]) == pytest.approx(0.020, abs=0.0015)
    assert silences(pair.master.events) == silences(pair.slave.events) == 0
    assert_conserved(pair)


def test_each_path_reports_its_own_round_trip_loss_and_first_copies() -> None:
    links = two_paths(0.010, 0.030)
    links[1].ms.drop = lambda i: i % 10 == 0  # 10 % of what the master sends on path 1
    pair = running(links)
    pair.run_for(1.5)
    paths = pair.master.conn.multipath
    assert paths is not None
    fast, slow = sorted(paths.path_stats(pair.now), key=lambda p: p.path_id)
    assert fast.srtt == pytest.approx(0.020, rel=0.1)
    assert slow.srtt == pytest.approx(0.060, rel=0.1)
    assert fast.loss < 0.01
    assert slow.loss == pytest.approx(0.10, abs=0.05)
    assert slow.lag == pytest.approx(0.020, abs=0.002)  # 20 ms behind the first copy
    assert fast.first_delivered > 0.95 * fast.peer_received
    assert slow.first_delivered < 0.05 * slow.peer_received
    assert fast.one_way_delay < slow.one_way_delay


def test_independent_losses_on_two_paths_lose_almost_nothing() -> None:
    links = two_paths(0.020, 0.022)
    # 20 % loss on each path, independent: a sample is lost only when both copies are (4 %).
    links[0].ms.drop = lambda i: (i * 7919) % 5 == 0
    links[1].ms.drop = lambda i: (i * 104729 + 3) % 5 == 0
    pair = running(links)
    before, offered = len(pair.slave.received), pair.master.offered
    pair.run_for(1.5)
    delivered = len(pair.slave.received) - before
    sent = pair.master.offered - offered
    assert delivered >= 0.94 * sent  # one path alone would deliver 80 %


# --------------------------------------------------------------------------- one path fails


@pytest.mark.parametrize(
    ("scheduler", "cut", "outage"),
    [("redundant", 0, 10.0), ("redundant", 1, 2.0), ("adaptive", 0, 2.0), ("adaptive", 1, 2.0)],
)
def test_a_path_cut_costs_at_most_five_samples(scheduler: str, cut: int, outage: float) -> None:
    """The netns test's figures in fake time: veth-like paths, 1 kHz, one path's link down (for
    10 s, and for 2 s in the other cases) and back. No PeerSilent; <= 5 samples lost; the path is
    used again within 1 s."""
    links = two_paths(0.0003, 0.0005)
    pair = running(links, scheduler)
    master, slave = pair.master, pair.slave
    got_before = set(numbers(slave.received))
    offered_before = master.offered
    links[cut].up = False
    down_at = pair.now
    pair.run_for(outage)
    links[cut].up = True
    up_at = pair.now
    paths = master.conn.multipath
    assert paths is not None
    sent_at_restore = paths.paths[cut].sent_data
    pair.run_for(1.0)
    # The session never went silent, and nearly every sample of the outage arrived.
    assert silences(master.events) == silences(slave.events) == 0
    got = set(numbers(slave.received)) - got_before
    wanted = set(range(offered_before + 1, master.offered - 5))
    assert len(wanted - got) <= 5
    assert len(set(numbers(master.received))) >= pair.slave.offered - 10  # the other way too
    # The path failed, came back, and carries samples again within a second of the restore.
    events = [e for e in master.events if isinstance(e, PathChanged) and e.at >= down_at]
    assert [(e.path_id, e.state) for e in events] == [(cut, "failed"), (cut, "active")]
    assert events[1].at - up_at < 1.0
    if scheduler == "redundant" or cut == 0:  # adaptive uses the spare only when needed
        assert paths.paths[cut].sent_data - sent_at_restore > 500
    assert_conserved(pair)


def test_both_paths_down_is_an_outage_the_session_survives() -> None:
    links = two_paths(0.005, 0.008)
    pair = running(links)
    for link in links:
        link.up = False
    pair.run_for(3.0)
    for link in links:
        link.up = True
    before = len(pair.slave.received)
    pair.run_for(1.0)
    for side in (pair.master, pair.slave):
        assert silences(side.events) == 1
        assert any(isinstance(e, PeerResumed) for e in side.events)
        paths = side.conn.multipath
        assert paths is not None
        assert {p.state for p in paths.path_stats(pair.now)} == {"active"}
    assert len(pair.slave.received) - before > 800  # flowing again within the second


# --------------------------------------------------------------------------- adaptive


def test_adaptive_uses_the_best_path_alone_while_it_behaves() -> None:
    links = two_paths(0.010, 0.020)
    pair = running(links, "adaptive", warmup=1.5)
    paths = pair.master.conn.multipath
    assert paths is not None
    single, spread = paths.stats.single_samples, paths.stats.spread_samples
    carried = [link.carried_ms for link in links]
    pair.run_for(1.5)
    # One sample in eight goes on every path (each path's lag stays measured), the rest on the
    # better path alone; path 1 carries those and its probes and reports.
    assert paths.stats.single_samples - single > 1250
    assert paths.stats.spread_samples - spread < 1500 / 8 + 15
    extra = [link.carried_ms - c for link, c in zip(links, carried, strict=True)]
    assert extra[1] < 0.3 * extra[0]


def stalling(outage: float) -> tuple[MultipathPair, Multipath]:
    """An adaptive pair whose path 0 (the better) has from now a capacity outage of ``outage``
    towards the slave: its samples queue, then arrive late, all at the end of it."""
    links = two_paths(0.010, 0.020)
    pair = running(links, "adaptive", warmup=2.0)
    paths = pair.master.conn.multipath
    assert paths is not None
    start = links[0].ms.datagrams
    links[0].ms.extra_delay = lambda i: max(0.0, outage - 0.001 * (i - start)) if i >= start else 0
    return pair, paths


def test_adaptive_spreads_while_the_best_path_stalls() -> None:
    pair, paths = stalling(0.3)
    before = paths.stats.spread_samples
    latency_from = len(pair.slave.latency)
    pair.run_for(1.5)
    assert paths.stats.breaches >= 1
    assert paths.stats.spread_samples - before > 100
    late = [x for x in pair.slave.latency[latency_from:] if x > 0.05]
    assert len(late) < 40  # the stall was noticed within about a round trip and a margin


def test_adaptive_copies_through_a_short_stall_without_a_breach() -> None:
    # A 50 ms outage: the acknowledgements of the samples path 0 carried alone come late, but
    # overdue by less than the adaptive hold.
    pair, paths = stalling(0.05)
    breaches, stalled = paths.stats.breaches, paths.scheduler.stall_samples
    spread = paths.stats.spread_samples
    pair.run_for(0.07)
    copies = paths.scheduler.stall_samples - stalled
    # Once the acknowledgements are overdue every sample goes on both paths, each one copied for
    # the stall itself: no breach, no hold (the late reports degrade the path afterwards, which
    # is the loss and delay bounds' business).
    assert copies > 20
    assert paths.stats.breaches == breaches
    assert paths.stats.spread_samples - spread <= copies + 5  # (the probes' copies)


# --------------------------------------------------------------------------- ACKs and control


def test_stand_alone_acks_go_on_the_best_path() -> None:
    links = two_paths(0.010, 0.030)
    for link in links:
        link.sm.keep_wire = True
    pair = running(links, rate=1000.0)
    pair.slave.rate = 0.0  # a one-way stream: the slave acknowledges with stand-alone ACKs
    pair.run_for(2.0)
    acks = [sum(d[0] >> 6 == PacketType.ACK for d in link.sm.wire[-4000:]) for link in links]
    assert acks[0] > 100
    assert acks[1] == 0


def test_a_retransmitted_control_message_goes_on_another_path() -> None:
    links = two_paths(0.010, 0.030)
    pair = running(links, rate=1000.0)

    def first_message_lost(datagram: bytes) -> bool:
        return len(datagram) > HEADER_SIZE and datagram[HEADER_SIZE] == ControlCode.MESSAGE

    links[0].ms.drop_datagram = first_message_lost
    pair.master.conn.send_control(b"stop", now=pair.now)
    pair.run_for(1.0)
    received = [e for e in pair.slave.events if isinstance(e, ControlReceived)]
    assert [e.payload for e in received] == [b"stop"]
    assert pair.master.conn.stats.control_retransmits >= 1


# --------------------------------------------------------------------------- congestion, coupled


def _growing_queue(start: int, per_packet: float, cap: float) -> Callable[[int], float]:
    return lambda i: min(cap, max(0.0, (i - start) * per_packet))


def test_a_congested_path_carries_fewer_copies() -> None:
    links = two_paths(0.010, 0.012)
    pair = running(links)
    paths = pair.master.conn.multipath
    assert paths is not None
    start = links[1].ms.datagrams
    links[1].ms.extra_delay = _growing_queue(start, 0.0005, 0.2)  # path 1's queue fills
    sent = paths.paths[1].sent_data
    pair.run_for(3.0)
    assert paths.paths[1].pacer.rate < 1000.0
    assert paths.paths[1].sent_data - sent < 0.8 * 3000
    assert not paths.paths[0].pacer.congested()  # the other path's copies go on as before


def test_a_shared_bottleneck_carries_one_copy_not_two() -> None:
    """Both paths' queues grow together (one bottleneck): at most one copy of a sample goes into
    congestion, so the session is no more aggressive there than one flow."""
    links = two_paths(0.010, 0.012)
    pair = running(links)
    paths = pair.master.conn.multipath
    assert paths is not None
    for link in links:
        start = link.ms.datagrams
        link.ms.extra_delay = _growing_queue(start, 0.0005, 0.2)
    pair.run_for(1.5)
    spread = paths.stats.spread_samples
    single = paths.stats.single_samples
    pair.run_for(1.5)
    assert all(path.pacer.congested() for path in paths.paths.values())
    # (Which rule keeps the second copy out, the one-copy rule or a path's full window, does
    # not matter here; the FIFO test below holds the one-copy rule to account.)
    assert paths.stats.spread_samples - spread < 0.2 * (paths.stats.single_samples - single)


def test_a_shared_fifo_takes_one_copy_where_it_is_congested() -> None:
    """Both paths cross one FIFO that carries 1500 datagrams/s: two copies of every sample
    (2000/s) would fill it. The paths see their one-way queues rise and fall together, the
    one-copy rule keeps the second copy out while both are congested, and the shared queue stays
    short: the copies together are no more aggressive there than one flow that fills it."""
    links = two_paths(0.010, 0.012)
    pair = running(links)
    paths = pair.master.conn.multipath
    assert paths is not None
    free = [0.0]
    waits: list[float] = []

    def fifo(_: int) -> float:
        now = pair.now
        free[0] = max(now, free[0]) + 1.0 / 1500.0
        waits.append(free[0] - now)
        return free[0] - now

    for link in links:
        link.ms.extra_delay = fifo
    before = len(pair.slave.received)
    pair.run_for(3.0)
    assert paths.stats.bottleneck_skips > 0
    settled = sorted(waits[len(waits) // 3 :])
    assert settled[int(0.95 * len(settled))] < 0.04  # p95 of the shared queue, after the start
    assert len(pair.slave.received) - before > 0.9 * 3000


def _fading(pair: MultipathPair, period: float, phase: float) -> Callable[[int], float]:
    """A FIFO queue whose link carries 2000 datagrams/s but 600/s for 0.3 s of every ``period``
    (a radio's fades): the extra delay each datagram waits behind those before it."""
    free = [0.0]

    def wait(_: int) -> float:
        now = pair.now
        capacity = 600.0 if (now + phase) % period < 0.3 else 2000.0
        free[0] = max(now, free[0]) + 1.0 / capacity
        return free[0] - now

    return wait


def test_independent_congestion_keeps_the_copies_on_both_paths() -> None:
    """Each path's queue fills and drains on a rhythm of its own (two radio links): both are
    congested, often at once, but they share no bottleneck, so each carries its copies at its own
    controller's rate, rather than one path alone whenever both are congested."""
    links = two_paths(0.010, 0.012)
    pair = running(links)
    paths = pair.master.conn.multipath
    assert paths is not None
    links[0].ms.extra_delay = _fading(pair, 0.7, 0.0)
    links[1].ms.extra_delay = _fading(pair, 1.1, 0.35)
    pair.run_for(6.0)
    pacers = [path.pacer for path in paths.paths.values()]
    assert all(path.pacer.controller.delay_decrease_count > 0 for path in paths.paths.values())  # type: ignore[attr-defined]
    assert not pacers[0].shares_bottleneck(pacers[1], pair.now)
    assert paths.stats.bottleneck_skips < 0.02 * 6000


# --------------------------------------------------------------------------- paths come and go


def test_the_application_removes_a_path_and_the_peer_learns_it() -> None:
    pair = running(two_paths())
    paths = pair.master.conn.multipath
    assert paths is not None
    paths.close_path(1, pair.now)
    pair.run_for(0.5)
    slave_paths = pair.slave.conn.multipath
    assert slave_paths is not None
    assert sorted(slave_paths.paths) == [0]
    assert (1, "closed") in path_events(pair.slave.events)
    assert (1, "closed") in path_events(pair.master.events)
    before = len(pair.slave.received)
    pair.run_for(0.5)
    assert len(pair.slave.received) - before > 450


def test_a_slave_refuses_paths_beyond_its_limit() -> None:
    links = [PathLink(Direction(delay=0.005), Direction(delay=0.005)) for _ in range(3)]
    master_cfg = config(max_paths=4)
    slave_cfg = config(max_paths=2)
    pair = MultipathPair(links, master_cfg, slave_cfg)
    pair.open()
    pair.run_for(1.0)
    slave_paths = pair.slave.conn.multipath
    master_paths = pair.master.conn.multipath
    assert slave_paths is not None and master_paths is not None
    assert sorted(slave_paths.paths) == [0, 1]
    assert sorted(master_paths.paths) == [0, 1]  # path 2 refused (MP_ABANDON PATH_LIMIT)
    assert pair.slave.conn.stats.drops.get("path_limit", 0) >= 1
    assert master_paths.stats.paths_refused == 1


def test_a_path_whose_address_changes_is_validated_again() -> None:
    """A NAT rebinding on path 1: the slave sees its challenges from a new address and moves the
    path there after validating it."""
    links = two_paths()
    pair = running(links)
    slave_paths = pair.slave.conn.multipath
    assert slave_paths is not None
    old = slave_paths.paths[1].remote
    new = ("198.51.100.7", 61000)
    # From now on what the master sends on path 1 arrives from ``new``.
    original = pair._deliver

    def rebound(data: bytes, to_slave: bool, local: int, src: tuple[str, int]) -> None:
        original(data, to_slave, local, new if to_slave and local == 1 else src)

    sent_to_old = pair._send

    def old_mapping_gone(
        data: bytes, to_slave: bool, local: int, src: tuple[str, int], dst: tuple[str, int]
    ) -> None:
        if not to_slave and dst == old:
            return  # the NAT forgot it
        sent_to_old(data, to_slave, local, src, dst)

    pair.alias[new] = 1
    pair._deliver = rebound  # type: ignore[method-assign]
    pair._send = old_mapping_gone  # type: ignore[method-assign]
    pair.run_for(1.0)
    assert slave_paths.paths[1].remote == new != old
    assert slave_paths.paths[1].validated


# --------------------------------------------------------------------------- forged and replayed


def _probe(code: ControlCode, body: bytes) -> bytes:
    return encode_header(PacketType.CONTROL, 0, 0, 0, 255) + body


def test_a_forged_new_path_never_gets_more_than_three_times_what_it_sent() -> None:
    """An on-path attacker who read the nonce (unkeyed) forges a challenge from a victim's
    address: the slave answers there within 3x the bytes, never sends it a sample, and forgets the
    path when the victim never answers."""
    pair = running(two_paths(), validation_timeout=0.5, warmup=0.5)
    nonce = pair.master.conn.master_nonce
    victim = ("203.0.113.9", 4444)
    forged = _probe(ControlCode.MP_CHALLENGE, encode_mp_challenge(nonce, 7, b"attacker"))
    sent_to_victim: list[bytes] = []
    original = pair._send

    def watch(
        data: bytes, to_slave: bool, local: int, src: tuple[str, int], dst: tuple[str, int]
    ) -> None:
        if not to_slave and dst == victim:
            sent_to_victim.append(data)
            return
        original(data, to_slave, local, src, dst)

    pair._send = watch  # type: ignore[method-assign]
    pair.inject(forged, to_slave=True, source=victim)
    pair.run_for(1.0)
    assert sum(map(len, sent_to_victim)) <= 3 * len(forged)
    assert all(d[0] >> 6 == PacketType.CONTROL for d in sent_to_victim)  # never DATA
    slave_paths = pair.slave.conn.multipath
    assert slave_paths is not None
    assert 7 not in slave_paths.paths  # never validated: forgotten
    assert silences(pair.slave.events) == 0


def test_a_challenge_without_the_nonce_is_dropped_and_answered_with_nothing() -> None:
    pair = running(two_paths())
    forged = _probe(ControlCode.MP_CHALLENGE, encode_mp_challenge(bytes(16), 9, b"12345678"))
    sent = pair.slave.conn.stats.sent.datagrams
    pair.inject(forged, to_slave=True, source=("203.0.113.9", 4444))
    assert pair.slave.conn.stats.drops.get("wrong_address", 0) == 1
    assert pair.slave.conn.stats.sent.datagrams == sent


def test_a_keyed_challenge_must_authenticate() -> None:
    pair = running(two_paths(), keyed=True)
    nonce = pair.master.conn.master_nonce
    # The unkeyed layout (no tag) of a keyed session's challenge: does not authenticate.
    forged = _probe(ControlCode.MP_CHALLENGE, encode_mp_challenge(nonce, 9, b"12345678"))
    forged += bytes(2 + 16)
    pair.inject(forged, to_slave=True, source=("203.0.113.9", 4444))
    slave_paths = pair.slave.conn.multipath
    assert slave_paths is not None
    assert 9 not in slave_paths.paths
    assert pair.slave.conn.stats.drops.get("unauthenticated", 0) == 1


def test_a_flood_of_new_paths_is_bounded() -> None:
    pair = running(two_paths(), max_paths=4, new_paths_per_second=10.0)
    nonce = pair.master.conn.master_nonce
    for k in range(200):
        body = encode_mp_challenge(nonce, 1 + k % 100, k.to_bytes(8, "big"))
        pair.inject(
            _probe(ControlCode.MP_CHALLENGE, body), to_slave=True, source=("203.0.113.9", 5000 + k)
        )
    slave_paths = pair.slave.conn.multipath
    assert slave_paths is not None
    assert len(slave_paths.paths) <= 4
    drops = pair.slave.conn.stats.drops
    assert drops.get("path_limit", 0) >= 190
    before = len(pair.slave.received)
    pair.run_for(1.0)
    assert len(pair.slave.received) - before > 950  # the session's paths carry on
    assert silences(pair.slave.events) == 0


def test_forged_multipath_packets_are_dropped_by_reason() -> None:
    pair = running(two_paths())
    nonce = pair.master.conn.master_nonce
    slave = pair.slave.conn
    # A response echoing a token nobody sent.
    bogus = _probe(ControlCode.MP_RESPONSE, encode_mp_response(nonce, 1, b"notmine!", bytes(8)))
    pair.inject(bogus, to_slave=True, local=1)
    assert slave.stats.drops.get("bad_token", 0) == 1
    # A report naming path 1 arriving on path 0.
    report = encode_mp_report(MpReportBody(nonce, 1, 5, 0, 10, 10, 0, 0))
    pair.inject(_probe(ControlCode.MP_REPORT, report), to_slave=True, local=0)
    assert slave.stats.drops.get("unknown_path", 0) == 1
    # A report and an abandon with another session's nonce (a blind forgery).
    report = encode_mp_report(MpReportBody(bytes(16), 1, 5, 0, 10, 10, 0, 0))
    pair.inject(_probe(ControlCode.MP_REPORT, report), to_slave=True, local=1)
    abandon = encode_mp_abandon(bytes(16), 1, 19)
    pair.inject(_probe(ControlCode.MP_ABANDON, abandon), to_slave=True, local=0)
    assert slave.stats.drops.get("nonce_mismatch", 0) == 2
    assert slave.multipath is not None and 1 in slave.multipath.paths
    assert_conserved(pair)


def test_keyed_replays_of_copies_are_never_accepted() -> None:
    links = two_paths()
    for link in links:
        link.ms.keep_wire = True
    pair = running(links, keyed=True)
    pair.run_for(1.0)
    slave = pair.slave.conn
    delivered = len(pair.slave.received)
    data = [d for d in links[0].ms.wire if d[0] >> 6 == PacketType.DATA]
    recent, old = data[-220:-200], data[:20]  # taken in 200 ms ago, and at the start
    duplicates = slave.stats.drops.get("duplicate", 0)
    replayed = slave.stats.drops.get("replayed", 0)
    for datagram in recent:
        pair.inject(datagram, to_slave=True, local=0)
    for datagram in old:
        pair.inject(datagram, to_slave=True, local=1)
    assert len(pair.slave.received) == delivered  # nothing taken twice
    drops = slave.stats.drops
    assert (
        drops.get("duplicate", 0)
        - duplicates
        + drops.get("replayed", 0)
        - replayed
        + drops.get("stale", 0)
        >= 40
    )
    assert drops.get("duplicate", 0) - duplicates >= 20  # recent copies: duplicates
    assert replayed == 0  # the copies of the run itself never counted as replays


@pytest.mark.parametrize("keyed", [False, True])
def test_replayed_copies_keep_a_silent_peer_alive_only_unkeyed(keyed: bool) -> None:
    """A copy dropped as a duplicate never met the packet protection: keyed, an attacker replaying
    captured copies from the master's address must not hide the master's silence from the slave's
    watchdog (PROTOCOL.md 5.2). Unkeyed, anyone at that address can forge DATA anyway, and a
    duplicate counts as it does on one path."""
    links = two_paths()
    links[0].ms.keep_wire = True
    pair = running(links, keyed=keyed, warmup=0.5)
    copies = [d for d in links[0].ms.wire if d[0] >> 6 == PacketType.DATA][-60:]
    for link in links:
        link.up = False  # the master is gone
    pair.run_for(0.05)  # what was in flight arrives
    slave = pair.slave.conn
    duplicates = slave.stats.drops.get("duplicate", 0)
    for datagram in copies:
        pair.run_for(0.005)
        pair.inject(datagram, to_slave=True, local=0)
    assert slave.stats.drops.get("duplicate", 0) - duplicates == len(copies)
    assert silences(pair.slave.events) == (1 if keyed else 0)
    assert_conserved(pair)


def test_a_slow_paths_keyed_datagrams_are_not_taken_for_replays() -> None:
    """Path 1 is 300 ms slower: its reports and probes arrive hundreds of packet numbers behind
    path 0's, inside the wide replay window."""
    pair = running(two_paths(0.005, 0.305), keyed=True, warmup=1.0)
    pair.run_for(1.0)
    for side in (pair.master, pair.slave):
        assert side.conn.stats.drops.get("replayed", 0) == 0
        paths = side.conn.multipath
        assert paths is not None
        assert {p.state for p in paths.path_stats(pair.now)} <= {"active", "degraded"}


def test_latency_is_the_per_sample_minimum_of_the_paths() -> None:
    """Jitter on two independent paths: each sample's latency is the lower of its two copies'."""
    links = two_paths(0.020, 0.020)
    links[0].ms.extra_delay = lambda i: 0.015 * ((i * 7919) % 100 < 20)
    links[1].ms.extra_delay = lambda i: 0.015 * ((i * 104729 + 50) % 100 < 20)
    pair = running(links, max_reorder_wait=0.0)  # delivery as it comes: no wait behind a gap
    pair.run_for(1.5)
    latencies = sorted(pair.slave.latency[-2000:])
    p50 = statistics.median(latencies)
    assert p50 == pytest.approx(0.020, abs=0.002)
    share_slow = sum(x > 0.030 for x in latencies) / len(latencies)
    assert share_slow < 0.08  # ~4 % of samples are late on both paths; one path alone: 20 %


def test_datagrams_from_no_path_are_wrong_address() -> None:
    pair = running(two_paths())
    stranger = ("198.51.100.1", 1234)
    datagram = encode_header(PacketType.DATA, 1, 0, 0, 255) + b"x"
    pair.inject(datagram, to_slave=True, source=stranger)
    assert pair.slave.conn.stats.drops.get("wrong_address", 0) == 1
    assert stranger not in (master_addr(0), master_addr(1), SLAVE_ADDR)
