"""The reliable control channel (section 5.10): numbering, cumulative acknowledgements,
retransmission with back-off, the receive bound, giving up."""

from __future__ import annotations

from dataclasses import dataclass

from .bucket import TokenBucket
from .config import Config
from .wire import expand


class ControlError(Exception):
    pass


@dataclass
class Outgoing:
    number: int
    data: bytes
    offered_at: float
    last_tx: float | None = None


def first_number(isn: int) -> int:
    """0xF000 | ISN: within 4096 messages of the 16-bit wrap (section 5.10)."""
    return 0xF000 | isn


class ControlChannel:
    def __init__(self, cfg: Config, my_isn: int, peer_isn: int, now: float) -> None:
        self.cfg = cfg
        self.next_number = first_number(my_isn)
        self.unacked: list[Outgoing] = []
        self.oldest_unacked = self.next_number  # U
        self.sent_end = self.next_number  # S: one past the highest number transmitted
        self.expected = first_number(peer_isn)  # E
        self.held: dict[int, bytes] = {}
        self.unread = 0
        self.rate = TokenBucket(cfg.control_max_rate, cfg.control_burst, now)
        self.backoff = 0
        self.probing = False
        self.failed = False
        self.owe_ack = False
        self.expired: list[Outgoing] = []

    # -- sender --
    def send(self, data: bytes, now: float) -> None:
        if not data or len(data) > self.cfg.control_max_message:
            raise ControlError("message size")
        if self.failed:
            raise ControlError("channel failed")
        if len(self.unacked) >= self.cfg.control_window:
            raise ControlError("control queue full")
        self.unacked.append(Outgoing(self.next_number, data, now))
        self.next_number += 1

    def on_ack(self, ack16: int) -> bool:
        """Sender rule 3; False for an optimistic acknowledgement (receiver rule 2)."""
        a = expand(ack16, self.oldest_unacked, 16)
        if a > self.sent_end:
            return False
        if a > self.oldest_unacked:
            self.unacked = [m for m in self.unacked if m.number >= a]
            self.oldest_unacked = a
            self.backoff = 0
            self.probing = False
        return True

    def interval(self, loss_delay: float) -> float:
        """The loss delay in force, doubled per timeout in a row, up to 1 s (or the loss delay)."""
        return min(loss_delay * float(2**self.backoff), max(1.0, loss_delay))

    def expire(self, now: float) -> None:
        """Sender rule 5: a message unacknowledged control_timeout after it was offered is given
        up with every message after it, and the channel fails."""
        if self.unacked and now - self.unacked[0].offered_at >= self.cfg.control_timeout:
            self.expired.extend(self.unacked)
            self.unacked = []
            self.failed = True

    def due(self, now: float, loss_delay: float) -> list[Outgoing]:
        """The MESSAGEs to transmit at this instant (sender rules 2 and 4)."""
        out: list[Outgoing] = []
        if not self.unacked:
            return out
        iv = self.interval(loss_delay)
        oldest = self.unacked[0]
        if oldest.last_tx is not None and now >= oldest.last_tx + iv:
            # A timeout: probe with the oldest only until an acknowledgement advances.
            if self.rate.take(now):
                out.append(oldest)
                self.backoff += 1
                self.probing = True
            return out
        if self.probing:
            return out
        for m in self.unacked:
            if m.last_tx is None or now >= m.last_tx + iv:
                if not self.rate.take(now):
                    break
                out.append(m)
        return out

    def transmitted(self, m: Outgoing, now: float) -> None:
        m.last_tx = now
        self.sent_end = max(self.sent_end, m.number + 1)

    # -- receiver --
    def on_message(self, seq16: int, data: bytes) -> tuple[str | None, list[bytes]]:
        """Receiver rule 4: (drop reason or None, messages delivered in order). An ACK is owed
        whatever becomes of it (rule 3)."""
        self.owe_ack = True
        n = expand(seq16, self.expected, 16)
        if n < self.expected or n in self.held:
            return "duplicate", []
        if n >= self.expected + self.cfg.control_window:
            return "control_window", []
        if len(self.held) + self.unread >= self.cfg.control_window:
            return "control_backlog", []
        self.held[n] = data
        delivered: list[bytes] = []
        while self.expected in self.held:
            delivered.append(self.held.pop(self.expected))
            self.expected += 1
        return None, delivered

    @property
    def ack_field(self) -> int:
        return self.expected & 0xFFFF
