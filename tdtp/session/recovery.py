"""Loss recovery: what our data packets became, read from the peer's piggybacked acknowledgements.

TDTP never retransmits (stale supermedia data is worth nothing), so "recovery" here is what RFC 9002
calls loss detection plus the congestion signals it feeds: every data packet we send is recorded in the
:class:`~tdtp.session.sent_log.SentPacketLog`; each acknowledgement that arrives in the peer's header is
expanded, marks packets acknowledged, yields an RTT sample for the :class:`~tdtp.session.rtt.RttEstimator`
and reports absences; a packet absent for longer than the loss delay is declared lost, and losses close
loss intervals in the :class:`~tdtp.session.loss_rate.LossIntervalEstimator`. The rate controller hears
about it through ``on_ack`` and ``on_loss_event``.

:class:`LossRecovery` owns all of that state. It reads the watchdog's outage from
:class:`~tdtp.session.liveness.Liveness` (packets sent into a silent path are lost together, one loss
event per outage) and lowers the session's :class:`~tdtp.session.timer_hint.TimerHint` when a loss
deadline moves earlier.
"""

from __future__ import annotations

import math
from typing import Final

from tdtp.config import ConnectionConfig
from tdtp.control.base import RateController
from tdtp.session.liveness import Liveness
from tdtp.session.loss_rate import LossIntervalEstimator
from tdtp.session.rtt import RttEstimator
from tdtp.session.sent_log import LostPacket, SentPacketLog
from tdtp.session.stats import ConnectionStats
from tdtp.session.timer_hint import TimerHint
from tdtp.wire.hold import decode_hold

LOSS_DELAY_RTTVAR: Final = 4.0
REORDER_WINDOW_MIN_RTT: Final = 0.25
"""RACK's initial reorder window, a quarter of the minimum RTT (RFC 8985 section 6.2)."""
TIMER_GRANULARITY: Final = 0.001
"""Slack for timers firing late (RFC 9002's kGranularity)."""


def loss_delay_of(rtt: RttEstimator, reorder_scale: int, ack_delay: float) -> float:
    """The loss delay of docs/PROTOCOL.md 5.4: how long a packet reported absent may still turn up.

    ``srtt + max(reorder_window, 4 rttvar, 1 ms) + ack_delay``: srtt plus a reorder window (RFC 8985:
    ``reorder_scale x min_rtt / 4``, at most srtt; none before the first RTT sample, when there is no
    ``min_rtt``), never less than RAP's ``4 rttvar`` nor the timer granularity, plus the peer's ACK
    delay (``ack_delay``, ours standing for it), because RTT samples exclude it: a late arrival is
    reported only with the peer's next reverse packet.
    """
    srtt = rtt.srtt
    # (min and max written out: this runs after every RTT sample)
    margin = LOSS_DELAY_RTTVAR * rtt.rttvar
    if rtt.has_sample:
        reorder = REORDER_WINDOW_MIN_RTT * rtt.min_rtt * reorder_scale
        if srtt < reorder:
            reorder = srtt
        if margin < reorder:
            margin = reorder
    if margin < TIMER_GRANULARITY:
        margin = TIMER_GRANULARITY
    return srtt + margin + ack_delay


class LossRecovery:
    """The sent log, the RTT and loss-rate estimators, and the loss delay derived from them."""

    def __init__(
        self,
        first_seq: int,
        config: ConnectionConfig,
        *,
        controller: RateController,
        stats: ConnectionStats,
        liveness: Liveness,
        hint: TimerHint,
    ) -> None:
        self.sent = SentPacketLog(
            first_seq,
            reorder_threshold=config.reorder_threshold,
            max_tracked=config.max_tracked_packets,
        )
        self.rtt = RttEstimator(config.initial_rtt)
        self.loss = LossIntervalEstimator(first_seq)
        self._ack_delay = config.ack_delay
        # The peer holds ACKs up to its ack_delay; not negotiated, so ours stands for it.
        controller.feedback_delay = config.ack_delay
        self.loss_delay = self._compute_loss_delay()
        """How long a packet reported absent may still turn up, as of the last RTT sample."""
        self.echo: float | None = None
        """The round trip timed by the last acknowledgement handed in: from our send of the packet
        it names to its arrival here, less the peer's HOLD; ``None`` if it cannot tell (HOLD 254, or
        a packet no longer on record)."""
        self.echo_sent = 0.0
        """When the packet the last acknowledgement named was sent (when :attr:`echo_seq` >= 0)."""
        self.echo_seq = -1
        """Its sequence number, in full; -1 if the acknowledgement named none on record."""
        self.pending = False
        """An acknowledgement taken (:meth:`take_feedback`) and not yet settled."""
        self._taken_ack = first_seq - 1
        self._taken_sack = 0
        self._taken_hold: float | None = None
        self._taken_at = 0.0
        self._hint = hint
        self._lost: list[LostPacket] = []  # reused: filled by the sent log, emptied by _on_losses
        self._controller = controller
        self._stats = stats
        self._liveness = liveness

    def on_sent(self, now: float, size: int) -> None:
        """A data packet of ``size`` bytes left at ``now`` (it takes the log's next sequence number).
        Settles a pending acknowledgement first (the packet has left: this costs the answer nothing),
        so the log's bound never drops a record that acknowledgement names."""
        if self.pending:
            self.settle()
        lost = self._lost
        self.sent.on_sent(now, size, lost)
        if lost:
            self._on_losses(now)

    def take_feedback(self, ack: int, sack: int, hold_code: int, now: float) -> bool:
        """The part of an acknowledgement the datagram's own fate needs, done at once: the ACK
        expanded (False if it names a packet never sent: an optimistic ACK, the caller drops the
        datagram) and :attr:`echo` timed. The rest (packets acknowledged, RTT sample, losses, the
        controller's ``on_ack``) waits in :attr:`pending` for :meth:`settle`, so that what the
        application sends in answer leaves first; any later input settles it before its own."""
        if self.pending:
            self.settle()
        sent = self.sent
        hold = decode_hold(hold_code)
        full = sent.expand_ack(ack, hold, now, self.rtt.srtt)
        if full is None:
            return False
        # The round trip our packet and this datagram made together (PROTOCOL.md 3.6), before the
        # acknowledgement retires the packet's record.
        echo: float | None = None
        send_time = sent.send_time(full)
        if send_time is None:
            self.echo_seq = -1
        else:
            self.echo_sent = send_time
            self.echo_seq = full
            if hold is not None:
                echo = now - send_time - hold
                if echo < 0.0:  # (max(echo, 0.0) without the call)
                    echo = 0.0
        self.echo = echo
        self._taken_ack = full
        self._taken_sack = sack
        self._taken_hold = hold
        self._taken_at = now
        self.pending = True
        return True

    def settle(self) -> int:
        """Finish the acknowledgement :meth:`take_feedback` took: how many packets it newly
        acknowledged (0 if none was pending)."""
        if not self.pending:
            return 0
        self.pending = False
        now = self._taken_at
        sent = self.sent
        rtt = self.rtt
        newly = sent.acknowledge(self._taken_ack, self._taken_sack, self._taken_hold, now)
        stats = self._stats
        if sent.spurious:
            stats.spurious_losses += sent.spurious
        sample = sent.rtt_sample
        if sample is not None:
            rtt.on_sample(sample)
            stats.rtt_samples += 1
            delay = self._compute_loss_delay()
            if delay < self.loss_delay:
                # A shorter loss delay brings a pending loss deadline forward.
                due = sent.loss_deadline(delay)
                hint = self._hint
                if due is not None and due < hint.value:
                    hint.value = due
            self.loss_delay = delay
        if sent.marked_missing:
            sent.marked_missing = False
            self._hint.value = -math.inf  # a loss deadline may be due earlier
        lost = self._lost
        sent.detect_losses(now, self.loss_delay, lost)
        if lost:
            self._on_losses(now)
        if newly:
            stats.packets_acked += newly
            self._controller.on_ack(
                now=now,
                acked=newly,
                rtt_sample=sample,
                srtt=rtt.srtt,
                rttvar=rtt.rttvar,
                loss_event_rate=self.loss.update(sent.largest_acked),
            )
            self._hint.check_controller()
        return newly

    def refresh(self, stats: ConnectionStats) -> None:
        """Copy the derived figures (RTT, loss-event rate, packets unreported and reordered) into ``stats``."""
        if self.pending:
            self.settle()
        rtt = self.rtt
        stats.srtt = rtt.srtt if rtt.has_sample else 0.0
        stats.rttvar = rtt.rttvar if rtt.has_sample else 0.0
        stats.min_rtt = rtt.min_rtt if rtt.has_sample else 0.0
        stats.loss_event_rate = self.loss.loss_event_rate
        stats.packets_unreported = self.sent.unknown
        stats.packets_reordered = self.sent.reordered

    def detect_losses(self, now: float) -> None:
        """Declare lost what has been absent longer than the loss delay (the timer's check)."""
        if self.pending:
            self.settle()
        lost = self._lost
        self.sent.detect_losses(now, self.loss_delay, lost)
        if lost:
            self._on_losses(now)

    def loss_deadline(self) -> float | None:
        """When the next packet reported absent is declared lost, if any is."""
        if self.pending:
            self.settle()
        return self.sent.loss_deadline(self.loss_delay)

    def _on_losses(self, now: float) -> None:
        lost = self._lost
        estimator = self.loss
        srtt = self.rtt.srtt
        largest = self.sent.largest_acked
        stats = self._stats
        stats.packets_lost += len(lost)
        outage = self._liveness.outage(now)
        for packet in lost:
            window = srtt
            during_outage = outage is not None and outage[0] <= packet.send_time <= outage[1]
            if during_outage:
                # Packets sent into a silent path are lost together: one loss event per outage,
                # however far apart the controller's back-off spaced them (docs/PROTOCOL.md 5.4).
                assert outage is not None
                window = srtt + outage[1] - outage[0]
            if estimator.on_packet_lost(packet.seq, packet.send_time, window, largest):
                stats.loss_events += 1
                if not during_outage:
                    # An outage's loss event counts in p; the controller answers the outage itself
                    # through on_peer_silent / on_peer_resumed, not a second time here.
                    self._controller.on_loss_event(
                        now=now, srtt=srtt, loss_event_rate=estimator.loss_event_rate
                    )
        lost.clear()
        self._hint.value = -math.inf

    def _compute_loss_delay(self) -> float:
        """The loss delay as of now (:func:`loss_delay_of`); kept until the next RTT sample."""
        return loss_delay_of(self.rtt, self.sent.reorder_window_scale, self._ack_delay)
