"""The ``--json`` summary of ``tdtp demo``, ``tdtp master`` and ``tdtp slave``: the whole story of each
direction, as far as this process can see it.

A direction has a sending end and a receiving end. The sender knows what it offered, sent, got
acknowledged, lost and never heard about, with its RTT, loss-event rate p and allowed rate; the receiver
knows what arrived, the gaps in the sequence, and what it dropped and why. ``tdtp demo`` runs both ends
and reports both views of each direction; ``tdtp master`` and ``tdtp slave`` see one end of each
direction, so every field of the other end is ``null`` and ``observed_at`` says whose counters are in
it. Every key is always present, so a script can read the output without guessing.

One-way latency needs the sample's send time on the receiver's clock: it is measured only for samples
in the demo's haptic format (``tdtp.teleop.haptic_sample``) sent from the same host (the monotonic clocks
agree); ``latency_note`` says why ``latency_ms`` is ``null`` otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from tdtp.capture.pcap import PcapWriter
from tdtp.cli.live_stats import LatencyRecorder
from tdtp.session.stats import ConnectionStats

_SENDER_KEYS = (
    "samples_offered",
    "samples_superseded",
    "packets_sent",
    "packets_acked",
    "losses",
    "packets_unreported",
    "packets_in_flight",
    "loss_ratio",
    "loss_events",
    "loss_event_rate",
    "spurious_losses",
    "packets_reordered",
    "rate_limit",
    "queue_delay_ms",
    "srtt_ms",
    "rttvar_ms",
    "min_rtt_ms",
    "allowed_rate",
    "bytes_sent",
    "header_bytes",
)
_RECEIVER_KEYS = (
    "packets_received",
    "samples_delivered",
    "gaps",
    "reordered",
    "reorder_held",
    "reorder_wait_ms",
    "drops_at_receiver",
    "ack_packets_sent_back",
    "mean_rate",
    "sample_age_ms",
    "samples_timed",
    "queue_delay_ms",
)


@dataclass(slots=True)
class LatencyCounts:
    """What became of the samples one end received, for the latency report."""

    recorder: LatencyRecorder
    not_haptic: int = 0
    """Samples too short to be in the haptic format: sent by something else than the tdtp command."""
    clock_mismatch: int = 0
    """Haptic samples whose send time is not on this host's monotonic clock (another host)."""


def _ms(seconds: float) -> float | None:
    """Milliseconds, or ``None`` for a figure a closed session no longer has (NaN)."""
    return None if math.isnan(seconds) else round(seconds * 1e3, 4)


def sender_view(stats: ConnectionStats) -> dict[str, Any]:
    sent = stats.sent.data_packets
    acked, lost, unknown = stats.packets_acked, stats.packets_lost, stats.packets_unreported
    return {
        "samples_offered": stats.samples_offered,
        "samples_superseded": stats.samples_superseded,
        "packets_sent": sent,
        "packets_acked": acked,
        "losses": lost,
        "packets_unreported": unknown,
        "packets_in_flight": max(0, sent - acked - lost - unknown),
        "loss_ratio": round(lost / sent, 6) if sent else 0.0,
        "loss_events": stats.loss_events,
        "loss_event_rate": round(stats.loss_event_rate, 6),
        "spurious_losses": stats.spurious_losses,
        "packets_reordered": stats.packets_reordered,
        "rate_limit": stats.rate_limit or None,
        # This direction's own queue, as the peer's send times measure it (PROTOCOL.md 5.13).
        "queue_delay_ms": _ms(stats.queue_delay_out) if stats.timestamps else None,
        "srtt_ms": _ms(stats.srtt),
        "rttvar_ms": _ms(stats.rttvar),
        "min_rtt_ms": _ms(stats.min_rtt),
        "allowed_rate": None if math.isinf(stats.rate) else round(stats.rate, 2),
        "bytes_sent": stats.sent.bytes,
        "header_bytes": stats.sent.header_bytes,
    }


def receiver_view(stats: ConnectionStats, duration: float) -> dict[str, Any]:
    received = stats.received.data_packets
    return {
        "packets_received": received,
        "samples_delivered": stats.samples_delivered,
        "gaps": stats.peer_gaps,
        "reordered": stats.reordered,
        "reorder_held": stats.reorder_held,
        "reorder_wait_ms": round(stats.reorder_wait * 1e3, 3),
        "drops_at_receiver": dict(sorted(stats.drops.items())),
        "ack_packets_sent_back": stats.sent.ack_packets,
        "mean_rate": round(received / duration, 2) if duration > 0 else 0.0,
        # The transport's own estimate (PROTOCOL.md 3.6), beside the payload-timed latency_ms.
        "sample_age_ms": (
            {"p50": _ms(stats.sample_age_p50), "p99": _ms(stats.sample_age_p99)}
            if stats.samples_delivered
            else None
        ),
        "samples_timed": stats.samples_timed,
        "queue_delay_ms": _ms(stats.queue_delay_in) if stats.timestamps else None,
    }


def latency_report(counts: LatencyCounts | None) -> dict[str, Any]:
    """``latency_ms`` (p50, p99, max) and, when it is ``null`` or partial, ``latency_note``."""
    if counts is None:
        return {
            "latency_ms": None,
            "latency_note": "not measured here: the receiving end is another process",
        }
    measured = len(counts.recorder.all)
    summary = counts.recorder.summary_ms()
    note: str | None = None
    if summary is None:
        if counts.not_haptic:
            note = (
                f"not measurable: the {counts.not_haptic} samples received are not in tdtp's "
                "haptic format (they carry no send time)"
            )
        elif counts.clock_mismatch:
            note = (
                "not measurable: the samples' send times are not on this host's monotonic clock "
                "(the peer runs on another host); half the srtt estimates the one-way delay"
            )
        else:
            note = "no samples received"
    elif counts.not_haptic or counts.clock_mismatch:
        note = (
            f"measured on {measured} samples; {counts.not_haptic} not in the haptic format and "
            f"{counts.clock_mismatch} from another clock left out"
        )
    return {"latency_ms": summary, "latency_note": note}


def direction_report(
    *,
    sender: ConnectionStats | None,
    receiver: ConnectionStats | None,
    observed_at: list[str],
    duration: float,
    latency: LatencyCounts | None,
) -> dict[str, Any]:
    """One direction: the sender's and the receiver's views (``null`` fields where this process is
    not that end), and the latency."""
    report: dict[str, Any] = {"observed_at": observed_at}
    report.update(sender_view(sender) if sender is not None else dict.fromkeys(_SENDER_KEYS))
    report.update(
        receiver_view(receiver, duration) if receiver is not None else dict.fromkeys(_RECEIVER_KEYS)
    )
    offered = report["samples_offered"]
    received = report["packets_received"]
    report["delivery_ratio"] = (
        round(received / offered, 6) if offered and received is not None else None
    )
    report.update(latency_report(latency))
    return report


def capture_report(writer: PcapWriter | None) -> dict[str, Any] | None:
    """The ``pcap`` entry: file, datagrams written, and why writing stopped (if it did)."""
    if writer is None:
        return None
    return {"file": writer.path, "packets": writer.packets, "error": writer.error}


def srtt_text(srtt_ms: float | None) -> str:
    """``srtt 0.312 ms``, or ``srtt - (closed)`` for a session that has ended."""
    return "srtt - (closed)" if srtt_ms is None else f"srtt {srtt_ms:.3f} ms"


def direction_line(label: str, report: dict[str, Any]) -> str:
    """One direction of a ``--json`` report in one line, with what this end saw of it."""
    parts: list[str] = []
    if report.get("packets_sent") is not None:
        sent = report["packets_sent"]
        lost = report["losses"]
        parts.append(
            f"offered {report['samples_offered']}, sent {sent}, acked {report['packets_acked']}, "
            f"lost {lost} ({lost / sent * 100 if sent else 0.0:.2f} %), "
            + srtt_text(report["srtt_ms"])
        )
    if report.get("packets_received") is not None:
        parts.append(
            f"received {report['packets_received']} ({report['mean_rate']:.1f}/s), "
            f"gaps {report['gaps']}, reordered {report['reordered']}"
            + (
                f" (held in order up to {report['reorder_wait_ms']:.1f} ms)"
                if report.get("reorder_held")
                else ""
            )
        )
        latency = report.get("latency_ms")
        if latency:
            parts.append(f"latency p50 {latency['p50']:.3f} ms p99 {latency['p99']:.3f} ms")
        age = report.get("sample_age_ms")
        if age:
            parts.append(f"age p50 {age['p50']:.3f} ms p99 {age['p99']:.3f} ms")
    return f"{label}: " + ", ".join(parts)


def summary_text(summary: dict[str, Any]) -> str:
    """What ``tdtp master`` and ``tdtp slave`` print at the end without ``--json``."""
    if summary.get("command") == "slave":
        lines = [
            f"served {summary['masters_served']} master(s), refused {summary['masters_refused']}"
        ]
        for session in summary["sessions"]:
            close = session.get("close")
            ended = "open" if close is None else f"closed ({close['cause']})"
            lines.append(f"master {session['master']}: {ended}, {session['duration_s']:.1f} s")
            lines.append("  " + direction_line("M->S", session["master_to_slave"]))
            lines.append("  " + direction_line("S->M", session["slave_to_master"]))
            if session.get("task_error"):
                lines.append(f"  failed: {session['task_error']}")
        return "\n".join(lines)
    lines = [
        direction_line(label, summary[key])
        for key, label in (("master_to_slave", "M->S"), ("slave_to_master", "S->M"))
        if key in summary
    ]
    reconnects = summary.get("reconnects")
    if reconnects and reconnects["count"]:
        causes = ", ".join(f"{c} {n}" for c, n in sorted(reconnects["causes"].items()))
        lines.append(
            f"reconnected {reconnects['count']} time(s) ({causes}), last at "
            f"t={reconnects['last_at_s']:.1f} s; samples received {summary['samples_received']}, "
            f"{reconnects['samples_received_since_last']} since the last reconnect"
        )
    if "peer_silences" in summary:
        close = summary.get("close")
        ended = "open at the end" if close is None else f"closed ({close['cause']})"
        lines.append(
            f"session {ended}, slave silent {summary['peer_silences']} time(s), longest "
            f"{summary['longest_silence_s']:.1f} s"
        )
    return "\n".join(lines)
