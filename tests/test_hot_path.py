"""The per-packet shortcuts the asyncio endpoint takes: ``timer_hint`` instead of ``get_timer()``
after every input, and ``send_direct`` instead of ``send`` + ``datagrams_to_send``. Both must change
nothing a peer or the application can see: the same datagrams, byte for byte, the same counters, and
never a deadline missed."""

from __future__ import annotations

import heapq
import math
import random

import pytest

from tdtp import Connection, ConnectionConfig, PresharedKey, Role, State
from tdtp.control import registry
from tdtp.control.fixed import FixedConfig
from tdtp.control.registry import register_controller
from tdtp.control.trinomial import TrinomialConfig, TrinomialController

MASTER, SLAVE = ("192.0.2.1", 40001), ("192.0.2.2", 40002)
KEY = PresharedKey(bytes(range(32)), "hot-path")


class Side:
    """One connection driven like tdtp.aio.Endpoint: a single timer re-armed only for an earlier
    deadline, and only when ``timer_hint`` says one may exist. Every input also checks the hint
    against the truth (a fresh ``get_timer()``)."""

    def __init__(self, conn: Connection, addr: tuple[str, int], *, direct: bool) -> None:
        self.conn = conn
        self.addr = addr
        self.direct = direct
        self.armed = math.inf
        self.sent: list[bytes] = []
        self.missed = 0

    def transmit(self, datagram: bytes, addr: object) -> None:
        assert addr is None if self.conn.role is Role.MASTER else addr == self.conn.peer
        self.sent.append(datagram)

    def after_input(self, now: float) -> None:
        conn = self.conn
        self.sent.extend(d for d, _ in conn.datagrams_to_send(now=now))
        hint = conn.timer_hint
        truth = conn.get_timer()  # what the endpoint would not ask for unless the hint says so
        truth = math.inf if truth is None else truth
        if truth < self.armed:
            if not hint < self.armed:
                self.missed += 1
            self.armed = truth

    def offer(self, payload: bytes, now: float) -> None:
        connected = self.conn.role is Role.MASTER
        if self.direct and self.conn.send_direct(
            payload, self.transmit, connected=connected, now=now
        ):
            # Nothing else was due: the endpoint skips datagrams_to_send unless the hint says so.
            assert self.conn.datagrams_to_send(now=now) == []
        elif not self.direct:
            self.conn.send(payload, now=now)
        self.after_input(now)

    def fire_if_due(self, now: float) -> None:
        if now >= self.armed:
            self.armed = math.inf
            self.conn.handle_timer(now=now)
            self.after_input(now)


def _run(
    direct: bool, config: ConnectionConfig, *, keyed: bool, seed: int, tick: float = 0.001
) -> dict[str, object]:
    """Both sides offer a sample on two ticks of three (1 kHz ticks unless told) for 2 s over a path
    that loses, reorders and goes silent once."""
    rng = random.Random(seed)
    master = Side(
        Connection(config, role=Role.MASTER, rng=random.Random(1), key=KEY if keyed else None),
        MASTER,
        direct=direct,
    )
    slave = Side(
        Connection(config, role=Role.SLAVE, rng=random.Random(2), keys=[KEY] if keyed else None),
        SLAVE,
        direct=direct,
    )
    flight: list[tuple[float, int, bytes, bool]] = []
    order = 0
    now = 0.0
    master.conn.connect(SLAVE, now=now)
    master.after_input(now)
    slave.after_input(now)
    ticks = 0
    while now < 2.0:
        # Put what each side sent on the wire: 2 % lost, some delayed past later packets, and
        # nothing at all between 0.8 s and 1.0 s (an outage the watchdog sees).
        for side, to_slave in ((master, True), (slave, False)):
            for datagram in side.sent:
                order += 1
                if rng.random() < 0.02 or 0.8 <= now < 1.0:
                    continue
                delay = 0.005 + (0.004 if rng.random() < 0.05 else 0.0)
                heapq.heappush(flight, (now + delay, order, datagram, to_slave))
            side.sent.clear()
        next_tick = ticks * tick
        upcoming = min(next_tick, flight[0][0] if flight else math.inf, master.armed, slave.armed)
        now = max(now, upcoming)
        while flight and flight[0][0] <= now:
            _, _, datagram, to_slave = heapq.heappop(flight)
            target, source = (slave, master) if to_slave else (master, slave)
            target.conn.receive_datagram(datagram, source.addr, now=now)
            while target.conn.next_event() is not None:
                pass
            target.after_input(now)
        for side in (master, slave):
            side.fire_if_due(now)
        if now >= next_tick:
            ticks += 1
            for side in (master, slave):
                if side.conn.state is State.ESTABLISHED and ticks % 3:
                    side.offer(ticks.to_bytes(4, "big") + bytes(60), now)
    return {
        "missed": master.missed + slave.missed,
        "master": master.conn.stats.as_dict(),
        "slave": slave.conn.stats.as_dict(),
        "master_state": master.conn.state,
        "slave_state": slave.conn.state,
    }


CONFIGS = {
    "trinomial": ConnectionConfig(),
    "tfrc": ConnectionConfig(controller="tfrc"),
    "unpaced": ConnectionConfig(controller="fixed", controller_config=FixedConfig(math.inf)),
    "paced": ConnectionConfig(controller="fixed", controller_config=FixedConfig(400.0)),
}


@pytest.mark.parametrize("keyed", [False, True])
@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_the_hint_never_misses_a_deadline_and_send_direct_changes_nothing(
    name: str, keyed: bool
) -> None:
    plain = _run(False, CONFIGS[name], keyed=keyed, seed=7)
    direct = _run(True, CONFIGS[name], keyed=keyed, seed=7)
    assert plain["missed"] == direct["missed"] == 0
    assert plain["master_state"] is plain["slave_state"] is State.ESTABLISHED
    # The same session on the wire and in every counter, whichever way the samples were sent.
    assert direct == plain
    master = plain["master"]
    assert isinstance(master, dict)
    assert master["packets_lost"] > 0 and master["peer_silences"] == 1  # the path was exercised


class EagerTrinomial(TrinomialController):
    """Trinomial with every increase interval's end timed, as before ends were settled lazily."""

    def get_timer(self) -> float | None:
        waiting = self.sample_waiting
        self.sample_waiting = True
        try:
            return super().get_timer()
        finally:
            self.sample_waiting = waiting


@pytest.mark.parametrize(("tick", "seed"), [(0.001, 3), (1 / 3000, 3), (1 / 2400, 2)])
def test_lazy_interval_ends_give_the_session_eager_ones_give(
    tick: float, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(registry, "_registry", dict(registry._registry))  # registered for this test
    register_controller("trinomial-eager", EagerTrinomial, TrinomialConfig)
    # 667 to 2000 samples/s offered against an allowance near 2000/s. A sample that arrives after
    # an interval end nobody timed must find it settled and leave when the eager timer would have
    # let it, not a timer expiry later and counted as paced (the last case tells the two apart).
    lazy = _run(True, ConnectionConfig(controller="trinomial"), keyed=False, seed=seed, tick=tick)
    eager = _run(
        True, ConnectionConfig(controller="trinomial-eager"), keyed=False, seed=seed, tick=tick
    )
    assert lazy == eager


def test_send_direct_reports_a_socket_error_and_carries_on() -> None:
    config = CONFIGS["unpaced"]
    master = Connection(config, role=Role.MASTER, rng=random.Random(1))
    slave = Connection(config, role=Role.SLAVE, rng=random.Random(2))
    master.connect(SLAVE, now=0.0)
    for _ in range(3):
        for datagram, _addr in master.datagrams_to_send(now=0.0):
            slave.receive_datagram(datagram, MASTER, now=0.0)
        for datagram, _addr in slave.datagrams_to_send(now=0.0):
            master.receive_datagram(datagram, SLAVE, now=0.0)
    assert master.state is State.ESTABLISHED

    def refuse(datagram: bytes, addr: object) -> None:
        raise OSError("no buffer space")

    assert master.send_direct(b"x" * 10, refuse, connected=True, now=0.001)
    assert master.transmit_errors == 1
    assert master.stats.sent.data_packets == 1  # sent, as far as the protocol knows: then lost
