"""The teleop controller's start-up: a window on what is in flight until the path has spoken (docs/CONTROL.md 9.10).

Before the first acknowledgement a sender knows nothing of the path, and a 1 kHz loop that sends at
its full rate from the first packet fills a slow bottleneck's queue for as long as the first
feedback takes, which that very queue, and the one the peer fills the same way on the way back,
delay further: behind `delay 20ms rate 300kbit limit 3000` both ends had ~100 samples (0.3 s)
queued before either heard anything. So the start counts packets, as TCP's slow start does:

* at most ``packets`` (the controller's ``start_window``) are in flight before anything is
  acknowledged, and each packet acknowledged lets two more go: the window doubles per round trip;
* it ends at the first sign of a queue (the one-way delays above the target, or any decrease the
  controller makes), or once the application no longer fills it (the window is twice what is in
  flight: the loop runs at its own rate), and hands over to the controller's own rules.

Packets lost are never acknowledged and keep their place in the count: the bound stays an upper
bound, and a loss only slows the window's growth (with half the packets lost it stops growing, and
the sender goes at what the acknowledgements clock out, plus the controller's probe every 50 ms).
An acknowledgement names only packets we sent (the connection drops the others), so a forged one can
end the start early, which is where the controller was without it, never widen it beyond that.
"""

from __future__ import annotations

__all__ = ["StartWindow"]


class StartWindow:
    """Packets sent and acknowledged since the start, and whether the start is still under way."""

    __slots__ = ("acked", "active", "packets", "sent")

    def __init__(self, packets: int) -> None:
        self.packets = packets
        """The window before any acknowledgement."""
        self.active = packets > 0
        """The start is under way (``False`` for good once it ended)."""
        self.sent = 0
        self.acked = 0

    def full(self) -> bool:
        """What is in flight fills the window (it holds the sender)."""
        return self.active and self.sent - self.acked >= self.packets + self.acked

    def on_sent(self) -> bool:
        """A packet left; returns whether the window is now full."""
        self.sent += 1
        return self.full()

    def on_acked(self, acked: int) -> None:
        """``acked`` more packets reached the peer. Ends the start once the window has grown to
        twice what is in flight (the application, not the window, sets the pace)."""
        if not self.active or acked <= 0:
            return
        self.acked = done = self.acked + acked
        if done >= self.packets and 2 * (self.sent - done) <= self.packets + done:
            self.active = False

    def end(self) -> None:
        self.active = False
