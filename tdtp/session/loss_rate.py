"""Loss-event rate p, computed the way RFC 5348 (TFRC) section 5 does, from the sender's loss events.

A loss interval is the number of packets from the first packet of one loss event to the first packet of
the next. p is 1 / (weighted mean of the last eight intervals), weights 1, 1, 1, 1, 0.8, 0.6, 0.4, 0.2,
where the still-open interval since the last event counts only when it would lower p (RFC 5348 5.4).
"""

from __future__ import annotations

from collections import deque

LOSS_INTERVAL_WEIGHTS = (1.0, 1.0, 1.0, 1.0, 0.8, 0.6, 0.4, 0.2)
_N = len(LOSS_INTERVAL_WEIGHTS)


class LossIntervalEstimator:
    """RFC 5348 loss intervals. The packets from ``first_seq`` to the first loss form the first
    interval (RFC 5348 synthesises that one from the receive rate; counting it is the plain version)."""

    __slots__ = ("_event_start_seq", "_event_start_time", "_intervals", "loss_event_rate")

    def __init__(self, first_seq: int) -> None:
        self._intervals: deque[int] = deque(maxlen=_N)  # newest first
        self._event_start_seq = first_seq
        self._event_start_time: float | None = None
        self.loss_event_rate = 0.0

    def on_packet_lost(self, seq: int, send_time: float, srtt: float, highest_acked: int) -> bool:
        """Account one lost packet; returns True when it starts a new loss event.

        A loss belongs to the current event when it was sent within one ``srtt`` after the packet that
        started the event (RFC 5348 5.2, with the sender's exact send times instead of the receiver's
        interpolated ones). Losses are reported in sequence order, so send times never go backwards.
        """
        start = self._event_start_time
        if start is not None and send_time <= start + srtt:
            return False
        self._event_start_time = send_time
        self.on_loss_event(seq, highest_acked)
        return True

    def on_loss_event(self, first_lost_seq: int, highest_acked: int) -> None:
        """A loss event began at ``first_lost_seq``; closes the open interval and recomputes p."""
        self._intervals.appendleft(max(1, first_lost_seq - self._event_start_seq))
        self._event_start_seq = first_lost_seq
        self.update(highest_acked)

    def update(self, highest_acked: int) -> float:
        """Recompute p with the open interval running up to ``highest_acked``; returns p."""
        intervals = self._intervals
        if not intervals:
            return 0.0
        open_interval = max(1, highest_acked - self._event_start_seq + 1)
        total_with_open = open_interval * LOSS_INTERVAL_WEIGHTS[0]
        weight_with_open = LOSS_INTERVAL_WEIGHTS[0]
        total_closed = 0.0
        weight_closed = 0.0
        for i, interval in enumerate(intervals):
            if i + 1 < _N:
                total_with_open += interval * LOSS_INTERVAL_WEIGHTS[i + 1]
                weight_with_open += LOSS_INTERVAL_WEIGHTS[i + 1]
            total_closed += interval * LOSS_INTERVAL_WEIGHTS[i]
            weight_closed += LOSS_INTERVAL_WEIGHTS[i]
        mean = max(total_with_open / weight_with_open, total_closed / weight_closed)
        self.loss_event_rate = 1.0 / mean
        return self.loss_event_rate
