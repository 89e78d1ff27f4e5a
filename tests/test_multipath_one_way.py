"""Each path's own direction in a multipath session (PROTOCOL.md 5.11, "What a report tells"): the
clock of the peer's MP_REPORTs gives a path's queue in our direction alone, and a path that stops
delivering our copies stops taking them. Fake time."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import pytest
from test_multipath import running, silences, two_paths

from tdtp.session.multipath.congestion import STALL_PROBE
from tdtp.session.multipath.paths import Multipath
from tdtp.session.multipath.report_clock import PathDelay
from tdtp.session.multipath.scheduler import OUTBOUND_FRESH, fastest_out, rank
from tdtp.session.one_way import RESET_AFTER, PeerClock
from tdtp.wire import HEADER_SIZE, ControlCode

from multipath_pair import MultipathPair, PathLink
from pair import Direction


def _queue_growing_to(cap: float, per_datagram: float = 0.0005) -> Callable[[int], float]:
    return lambda i: min(cap, i * per_datagram)


def _running() -> tuple[list[PathLink], MultipathPair, Multipath]:
    """Two paths (10 and 12 ms each way), 1 kHz both ways past the warm-up; the master's paths."""
    links = two_paths(0.010, 0.012)
    pair = running(links)
    paths = pair.master.conn.multipath
    assert paths is not None
    return links, pair, paths


def test_a_queue_on_the_way_back_does_not_cut_the_way_out() -> None:
    """Path 1's way back (the slave's uplink, which carries the reports on path 1) queues up to
    150 ms; the master's copies on path 1 cross freely. Judged from round trips the master's
    path 1 controller would cut its copies for a queue that is not in its direction; judged from
    the reports' clocks it sees none, and path 1 keeps every copy."""
    links, pair, paths = _running()
    start = links[1].sm.datagrams
    links[1].sm.extra_delay = lambda i: min(0.15, (i - start) * 0.0005)
    path = paths.paths[1]
    pair.run_for(1.0)
    sent = path.sent_data
    pair.run_for(2.0)
    assert path.rtt.srtt > 0.15  # the round trip shows the way back's queue ...
    assert path.delay.queue < 0.005  # ... our direction's own delay does not
    assert path.delay.samples > 100
    assert not path.pacer.congested()
    assert path.sent_data - sent > 0.97 * 2000  # every copy still goes on path 1
    assert paths.stats.report_clocks_rejected == 0


def test_a_queue_on_the_way_out_is_seen_and_drained() -> None:
    """The converse: path 1's way out queues. The reports' clocks show it as our direction's
    queue, and the path's controller cuts its copies (path 0 carries the samples meanwhile)."""
    links, pair, paths = _running()
    free = [0.0]

    def slow_link(_: int) -> float:  # path 1's way out carries 500 datagrams/s
        free[0] = max(pair.now, free[0]) + 1.0 / 500.0
        return free[0] - pair.now

    links[1].ms.extra_delay = slow_link
    before = len(pair.slave.received)
    pair.run_for(3.0)
    path = paths.paths[1]
    assert path.pacer.rate < 700.0
    assert path.delay.samples > 100
    assert free[0] - pair.now < 0.1  # the queue it built was drained
    assert len(pair.slave.received) - before > 0.97 * 3000


def test_a_path_whose_way_out_fails_takes_only_probes_and_returns() -> None:
    """Path 1's way out drops everything while its way back works: the slave, which hears
    nothing on it, judges it failed yet sends a probe copy there every STALL_PROBE, so the
    master keeps hearing it. The master stops feeding it after a round trip, two report
    intervals and a margin, sends one copy per STALL_PROBE there, and uses it again as soon as a
    report shows progress (a stall over LONG_STALL restarts the path's controller, which had no
    feedback all along)."""
    links, pair, paths = _running()
    path = paths.paths[1]
    links[1].ms.drop = lambda _: True
    before = len(pair.slave.received)
    pair.run_for(0.2)
    sent = path.sent_data
    pair.run_for(1.3)  # (a stall over LONG_STALL: its end restarts the path's controller)
    probes = path.sent_data - sent
    assert probes <= 1.3 / STALL_PROBE + 2
    assert path.pacer.stalled(pair.now)
    assert len(pair.slave.received) - before > 0.97 * 1500  # path 0 carried every sample
    assert silences(pair.master.events) == silences(pair.slave.events) == 0
    links[1].ms.drop = lambda _: False
    pair.run_for(0.3)
    sent = path.sent_data
    pair.run_for(0.5)
    assert not path.pacer.stalled(pair.now)
    assert path.sent_data - sent > 0.95 * 500


def test_a_path_silent_on_its_way_in_still_takes_probe_copies_out() -> None:
    """The converse: path 1's way back drops everything, so the master hears nothing on it and
    judges it failed, while its way out works (two radios' uplink and downlink fail apart). When
    path 0's way out fails too, one copy per STALL_PROBE on the failed path is all that reaches
    the slave: a sample every 50 ms instead of none (redundant's dropouts on two recorded LTE
    paths were one above what the traces allow until failed paths took these copies)."""
    links, pair, paths = _running()
    path = paths.paths[1]
    links[1].sm.drop = lambda _: True
    pair.run_for(0.5)
    assert path.state == "failed"
    links[0].ms.drop = lambda _: True
    sent, before, start = path.sent_data, len(pair.slave.received), pair.now
    pair.run_for(1.0)
    copies = path.sent_data - sent
    assert copies <= 1.0 / STALL_PROBE + 2  # probes only: the path may be out both ways
    arrivals = [start] + [e.received_at for e in pair.slave.received[before:]]
    assert len(arrivals) > 1.0 / STALL_PROBE - 2
    assert max(b - a for a, b in itertools.pairwise(arrivals)) < 1.5 * STALL_PROBE
    assert path.state == "failed"  # (nothing heard on it yet)


def test_a_report_clock_beyond_the_round_trip_is_not_used() -> None:
    """An on-path attacker (or corruption) moves every fifth report's clock on path 1 five
    seconds ahead: those reports would read a 5 s queue in our direction, more than their round
    trip allows. They are counted and not used; the path's copies go on."""
    links, pair, paths = _running()
    seen = [0]

    def rewrite(_: int, datagram: bytes) -> bytes:
        if len(datagram) > HEADER_SIZE and datagram[HEADER_SIZE] == ControlCode.MP_REPORT:
            seen[0] += 1
            if seen[0] % 5 == 0:
                clock = int.from_bytes(datagram[-4:], "big")
                moved = (clock + 5_000_000) & 0xFFFFFFFF
                return datagram[:-4] + moved.to_bytes(4, "big")
        return datagram

    pair.run_for(0.5)
    links[1].sm.rewrite = rewrite
    path = paths.paths[1]
    sent = path.sent_data
    pair.run_for(2.0)
    assert paths.stats.report_clocks_rejected >= seen[0] // 5 - 1 > 20
    assert path.delay.queue < 0.005
    assert path.sent_data - sent > 0.97 * 2000


def test_adaptive_takes_the_path_whose_way_out_is_fastest() -> None:
    """Path 0 is 10 ms each way; path 1 is 8 ms out and 30 ms back. By round trips path 0 is the
    better (half of 20 ms and the peer's 2 ms lag against half of 38 ms), but our samples cross
    path 1 faster, and the reports' clocks say so: adaptive sends them there alone."""
    links = [
        PathLink(Direction(delay=0.010), Direction(delay=0.010)),
        PathLink(Direction(delay=0.008), Direction(delay=0.030)),
    ]
    pair = running(links, "adaptive", warmup=1.5)
    paths = pair.master.conn.multipath
    assert paths is not None
    carried = [link.carried_ms for link in links]
    pair.run_for(1.5)
    extra = [link.carried_ms - c for link, c in zip(links, carried, strict=True)]
    assert extra[0] < 0.3 * extra[1]
    # (Acknowledgements and control messages still go by the round trips.)
    ranked = rank(list(paths.paths.values()), pair.now)
    assert [path.path_id for path in ranked] == [0, 1]
    assert [path.path_id for path in fastest_out(ranked, pair.now)] == [1, 0]
    # Without a recent sample of every path's own direction, the round trips decide again.
    later = pair.now + OUTBOUND_FRESH + 0.1
    assert [path.path_id for path in fastest_out(ranked, later)] == [0, 1]


# --------------------------------------------------------------------------- the pieces


def test_the_report_clock_unwraps_forward_and_back() -> None:
    clock = PeerClock()
    assert clock.read(0xFFFF_FF00) == 0.0
    assert clock.read(0x0000_0100) == pytest.approx(512e-6)  # across the wrap
    assert clock.read(0x0000_0000) == pytest.approx(256e-6)  # an older report, overtaken
    assert clock.read(0x0000_0200) == pytest.approx(768e-6)  # (the newest stays the anchor)


def test_path_delay_bounds_and_restart() -> None:
    delay = PathDelay()
    assert delay.base == math.inf
    assert delay.outbound(0.0, OUTBOUND_FRESH) == math.inf
    assert delay.take(1.000, echo=0.040, min_rtt=0.040, now=0.0)
    assert delay.take(1.010, echo=0.050, min_rtt=0.040, now=0.1)
    assert delay.queue == pytest.approx(0.125 * 0.010)
    assert delay.outbound(0.1, OUTBOUND_FRESH) == pytest.approx(1.000 + 0.125 * 0.010)
    assert delay.outbound(0.1 + OUTBOUND_FRESH + 0.01, OUTBOUND_FRESH) == math.inf
    # Below the base by more than the smallest round trip plus 2 ms: no real sample is.
    assert not delay.take(0.950, echo=0.040, min_rtt=0.040, now=0.2)
    # A queue longer than the round trip it came with: neither.
    assert not delay.take(1.100, echo=0.050, min_rtt=0.040, now=0.3)
    assert delay.rejected == 2
    # The peer's clock jumped: after RESET_AFTER rejections in a row the base starts over.
    for k in range(RESET_AFTER - 2):
        assert not delay.take(-5.0, echo=0.040, min_rtt=0.040, now=0.4 + k * 0.01)
    assert delay.base == math.inf
    assert delay.take(-5.0, echo=0.040, min_rtt=0.040, now=2.0)
    assert delay.base == -5.0
