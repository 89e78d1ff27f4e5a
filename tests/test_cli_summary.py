"""The --json story of each direction (tdtp.cli.summary): both views, nulls, latency notes."""

from __future__ import annotations

from tdtp import ConnectionConfig
from tdtp.cli.live_stats import LatencyRecorder
from tdtp.cli.summary import LatencyCounts, direction_report, latency_report
from tdtp.control.fixed import FixedConfig
from tdtp.session.stats import ConnectionStats

from pair import Direction, Pair


def _lossy_pair() -> Pair:
    unlimited = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=1e9))
    pair = Pair(unlimited, unlimited, ms=Direction(drop=lambda i: i % 25 == 13))
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(1.0)
    pair.drain()
    return pair


def test_a_direction_seen_from_both_ends_adds_up() -> None:
    pair = _lossy_pair()
    master, slave = pair.master.conn.stats, pair.slave.conn.stats
    report = direction_report(
        sender=master, receiver=slave, observed_at=["master", "slave"], duration=1.0, latency=None
    )
    sent = report["packets_sent"]
    assert report["losses"] > 20
    # Every packet sent has exactly one fate, and the receiver saw the same.
    assert sent == (
        report["packets_acked"]
        + report["losses"]
        + report["packets_unreported"]
        + report["packets_in_flight"]
    )
    assert report["packets_received"] == report["packets_acked"] == sent - report["losses"]
    assert report["gaps"] == report["losses"]
    assert report["srtt_ms"] > 0 and report["loss_event_rate"] > 0 and report["allowed_rate"] > 0
    assert report["latency_ms"] is None and "another process" in report["latency_note"]


def test_one_end_only_leaves_the_other_ends_fields_null() -> None:
    pair = _lossy_pair()
    master = pair.master.conn.stats
    outgoing = direction_report(
        sender=master, receiver=None, observed_at=["master"], duration=1.0, latency=None
    )
    incoming = direction_report(
        sender=None, receiver=master, observed_at=["master"], duration=1.0, latency=None
    )
    assert outgoing["packets_acked"] == master.packets_acked
    assert outgoing["packets_received"] is None and outgoing["drops_at_receiver"] is None
    assert outgoing["delivery_ratio"] is None
    assert incoming["packets_received"] == master.received.data_packets
    assert incoming["srtt_ms"] is None and incoming["allowed_rate"] is None
    assert set(outgoing) == set(incoming)  # the same keys whatever this process sees


def test_latency_says_why_it_is_missing() -> None:
    empty = LatencyRecorder()
    assert latency_report(LatencyCounts(empty)) == {
        "latency_ms": None,
        "latency_note": "no samples received",
    }
    foreign = latency_report(LatencyCounts(empty, not_haptic=12))
    assert (
        foreign["latency_ms"] is None and "not in tdtp's haptic format" in foreign["latency_note"]
    )
    remote = latency_report(LatencyCounts(empty, clock_mismatch=40))
    assert remote["latency_ms"] is None and "another host" in remote["latency_note"]
    some = LatencyRecorder()
    some.add(0.001)
    mixed = latency_report(LatencyCounts(some, not_haptic=3))
    assert mixed["latency_ms"] == {"p50": 1.0, "p99": 1.0, "max": 1.0}
    assert "measured on 1 samples; 3 not in the haptic format" in mixed["latency_note"]
    assert latency_report(LatencyCounts(some))["latency_note"] is None


def test_an_idle_connection_reports_zeros_not_errors() -> None:
    report = direction_report(
        sender=ConnectionStats(),
        receiver=ConnectionStats(),
        observed_at=["master", "slave"],
        duration=0.0,
        latency=None,
    )
    assert report["loss_ratio"] == 0.0 and report["mean_rate"] == 0.0
    assert report["delivery_ratio"] is None


def test_a_reordering_path_reports_the_samples_held_in_order_and_the_wait() -> None:
    unlimited = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=1e9))
    shuffled = Direction(extra_delay=lambda i: 0.003 if i % 20 == 7 else 0.0)
    pair = Pair(unlimited, unlimited, ms=shuffled)
    pair.open()
    pair.start_samples(1000, 1000)
    pair.run_for(1.0)
    pair.drain()
    report = direction_report(
        sender=pair.master.conn.stats,
        receiver=pair.slave.conn.stats,
        observed_at=["master", "slave"],
        duration=1.0,
        latency=None,
    )
    assert report["reordered"] > 40 and report["reorder_held"] >= report["reordered"] - 1
    assert report["reorder_wait_ms"] == 2.5  # 1.25 x the 2 ms its gap stayed open
    assert report["drops_at_receiver"]["late"] == 1  # before the wait had measured anything
    assert report["samples_delivered"] == report["packets_received"]  # a late one is a drop
