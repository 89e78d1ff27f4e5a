"""The teleop controller's competitive mode (docs/CONTROL.md 9.9) beside a flow that keeps the buffer
full whatever happens, in virtual time (tdtp.sim: no clock, no machine load)."""

from __future__ import annotations

import pytest

from tdtp.config import ConnectionConfig
from tdtp.control.competition import LOSS_DECREASE, OVERFLOW_DECREASE
from tdtp.control.teleop import LIMIT_COMPETING, TeleopController
from tdtp.sim.endpoints import TdtpSession
from tdtp.sim.engine import Network, Packet
from tdtp.sim.scenarios.dumbbell import build_dumbbell

SEGMENT = 1500
ACK = 40


class LossAgnosticWindow:
    """What BBR v1 does in a buffer shallower than the window it allows itself (the kernel's bbr kept
    a 1 Mbit/s tbf's buffer full beside tdtp): ``window`` full-size segments in flight, each
    acknowledged or lost segment replaced by a new one (a loss noticed ``notice`` s after the drop),
    whatever the loss rate. It keeps a standing queue of its own as long as it runs."""

    def __init__(
        self, net: Network, src: str, dst: str, port: int, window: int, notice: float = 0.1
    ) -> None:
        self._net = net
        self._src = src
        self._dst = dst
        self._port = port
        self._window = window
        self._notice = notice
        self._stop = float("inf")
        self.delivered = 0
        net.node(src).bind(port, self)
        net.node(dst).bind(port, self)

    def run(self, start: float, stop: float) -> None:
        self._stop = stop
        for _ in range(self._window):
            self._net.sim.call_at(start, self._send)

    def _send(self) -> None:
        now = self._net.sim.now
        if now < self._stop:
            packet = Packet(
                self._src, self._port, self._dst, self._port, SEGMENT, "data", now, self
            )
            self._net.node(self._src).send(packet, now)

    def receive(self, packet: Packet, now: float) -> None:
        if packet.payload == "data":
            self.delivered += packet.size
            ack = Packet(self._dst, self._port, self._src, self._port, ACK, "ack", now)
            self._net.node(self._dst).send(ack, now)
        else:
            self._send()

    def on_drop(self, packet: Packet, now: float) -> None:
        self._net.sim.call_at(now + self._notice, self._send)


def test_a_queue_that_outlives_the_base_window_keeps_the_flow_competing() -> None:
    # 1 Mbit/s, 100 ms of buffer counted in bytes (the kernel check's tbf), and a competitor that
    # keeps it full from 1 s to 25 s. The standing queue lasts longer than base_window (10 s):
    # before the base was held while competing, it became the base after ~11 s, read as no queue,
    # and the next check took it for the flow's own (back to the delay mode, then cut to a trickle
    # by a queue it could no longer see for what it was; on the kernel beside bbr: 12 s at 2-6 % of
    # the link, the median share 27 %).
    net = Network(seed=1)
    build_dumbbell(net, ["M", "X"], ["S", "Y"], "rate 1mbit delay 5ms", byte_limit=12500)
    session = TdtpSession.create(net, "M", "S", ConnectionConfig(controller="teleop"))
    competitor = LossAgnosticWindow(net, "X", "Y", 5001, window=13)
    competitor.run(start=1.0, stop=25.0)
    controller = session.master.conn.controller
    assert isinstance(controller, TeleopController)
    limits: dict[float, str] = {}
    queues: dict[float, float] = {}
    for tenth in range(30, 400, 5):
        now = tenth / 10.0
        net.run(until=now)
        limits[now] = controller.rate_limit
        queues[now] = controller.queue_delay
    competing = [t for t, limit in limits.items() if limit == LIMIT_COMPETING]
    assert competing and competing[0] <= 5.0  # it finds the competitor within seconds
    # ...and competes as long as the competitor runs, the queue read as the competitor's.
    assert all(limits[t] == LIMIT_COMPETING for t in limits if competing[0] <= t < 25.0)
    assert min(q for t, q in queues.items() if 15.0 <= t < 25.0) > 0.05
    # The competitor gone, the flow's own queue empties at the next check: back to low delay.
    assert all(limits[t] != LIMIT_COMPETING for t in limits if t >= 37.0)
    assert max(q for t, q in queues.items() if t >= 37.0) < 0.02


def test_competing_a_loss_event_costs_less_than_an_overflow() -> None:
    # Beside a competitor that ignores loss, losses of the flow's own come every round trip; a
    # TCP-sized cut for each handed the kernel's bbr the link (33 %, 42 % with the lighter cut).
    net = Network(seed=1)
    build_dumbbell(net, ["M", "X"], ["S", "Y"], "rate 1mbit delay 5ms", byte_limit=12500)
    session = TdtpSession.create(net, "M", "S", ConnectionConfig(controller="teleop"))
    LossAgnosticWindow(net, "X", "Y", 5001, window=13).run(start=1.0, stop=25.0)
    controller = session.master.conn.controller
    assert isinstance(controller, TeleopController)
    net.run(until=8.0)
    assert controller.rate_limit == LIMIT_COMPETING
    cuts = []
    for ms in range(8001, 20000):
        rate, losses = controller.rate, controller.loss_decrease_count
        net.run(until=ms / 1000.0)
        if controller.loss_decrease_count == losses + 1:
            cuts.append(controller.rate / rate)
    assert len(cuts) > 10
    # Each cut is the lighter one, not CUBIC's 0.7; an overflow still costs more.
    assert all(c == pytest.approx(LOSS_DECREASE, abs=0.02) and c > 0.8 for c in cuts), cuts
    assert OVERFLOW_DECREASE < 0.7 < LOSS_DECREASE
