"""A master and a slave Connection joined by several paths in fake time (multipath sessions).

Path ``i`` runs from the master's local socket ``i`` (address ``192.0.2.1:40001+i``) to the slave's one
socket (``192.0.2.2:40002``), with a :class:`~tests.pair.Direction` each way: delay, loss by index or
content, a link that can be cut (``up = False``) and restored. A path whose id differs from its socket
number is possible (the master opens the paths in socket order, so path ``i`` is socket ``i`` here).
Time jumps from event to event, as in ``tests/pair.py``.
"""

from __future__ import annotations

import heapq
import random
from dataclasses import dataclass, field

from tdtp import Connection, ConnectionConfig, DataReceived, Event, Role, State
from tdtp.protection.keys import KeyInput, KeysInput

from pair import Direction, FakeTime

SLAVE_ADDR = ("192.0.2.2", 40002)

Addr = tuple[str, int]


def master_addr(local: int) -> Addr:
    return ("192.0.2.1", 40001 + local)


@dataclass
class PathLink:
    """One path's two directions (master to slave, slave to master) and whether it is up."""

    ms: Direction = field(default_factory=Direction)
    sm: Direction = field(default_factory=Direction)
    up: bool = True
    carried_ms: int = 0
    carried_sm: int = 0


@dataclass
class Side:
    conn: Connection
    rate: float = 0.0
    size: int = 100
    next_sample: float = 0.0
    offered: int = 0
    received: list[DataReceived] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    sent_at: dict[int, float] = field(default_factory=dict)
    """Our sample number (its first 4 bytes) -> when it was offered."""
    latency: list[float] = field(default_factory=list)
    """One-way latency of every sample delivered to this side (fake time is one clock)."""


class MultipathPair(FakeTime):
    def __init__(
        self,
        links: list[PathLink],
        master_config: ConnectionConfig | None = None,
        slave_config: ConnectionConfig | None = None,
        *,
        seed: int = 1,
        master_key: KeyInput | None = None,
        slave_keys: KeysInput | None = None,
    ) -> None:
        self.now = 0.0
        self.links = links
        self.master = Side(
            Connection(master_config, role=Role.MASTER, rng=random.Random(seed), key=master_key)
        )
        self.slave = Side(
            Connection(slave_config, role=Role.SLAVE, rng=random.Random(seed + 1), keys=slave_keys)
        )
        # (time, order, data, to_slave, local socket of the master, source, destination)
        self._in_flight: list[tuple[float, int, bytes, bool, int, Addr, Addr]] = []
        self._order = 0
        self.injected: list[tuple[float, bytes, bool, int, Addr]] = []
        self.alias: dict[Addr, int] = {}
        """Further addresses of the master's sockets (a NAT rebinding): address -> socket."""

    # ----------------------------------------------------------------- driving

    def open(self, timeout: float = 2.0) -> None:
        """Open the session on path 0, then the master opens the other paths."""
        self.master.conn.connect(SLAVE_ADDR, now=self.now)
        self._flush(self.master)
        self.run_until(self.now + timeout, stop=lambda: self.established)
        assert self.established, "the session did not open"
        paths = self.master.conn.multipath
        assert paths is not None
        for local in range(1, len(self.links)):
            paths.open_path(local, SLAVE_ADDR, self.now)
        self._flush(self.master)

    @property
    def established(self) -> bool:
        return (
            self.master.conn.state is State.ESTABLISHED
            and self.slave.conn.state is State.ESTABLISHED
        )

    def start_samples(self, master_rate: float, slave_rate: float, size: int = 100) -> None:
        for side, rate in ((self.master, master_rate), (self.slave, slave_rate)):
            side.rate = rate
            side.size = size
            side.next_sample = self.now

    def _next_time(self) -> float | None:
        times = []
        if self._in_flight:
            times.append(self._in_flight[0][0])
        for side in (self.master, self.slave):
            timer = side.conn.get_timer()
            if timer is not None:
                times.append(timer)
            if side.rate > 0:
                times.append(side.next_sample)
        return min(times) if times else None

    def _step(self) -> None:
        now = self.now
        while self._in_flight and self._in_flight[0][0] <= now:
            _, _, data, to_slave, local, src, _dst = heapq.heappop(self._in_flight)
            self._deliver(data, to_slave, local, src)
        for side in (self.master, self.slave):
            conn = side.conn
            timer = conn.get_timer()
            if timer is not None and timer <= now:
                conn.handle_timer(now=now)
                self._drain(side)
            if side.rate > 0 and side.next_sample <= now:
                side.next_sample += 1.0 / side.rate
                if conn.state is State.ESTABLISHED:
                    side.offered += 1
                    side.sent_at[side.offered] = now
                    stamp = side.offered.to_bytes(4, "big")
                    conn.send(stamp + bytes(side.size - 4), now=now)
            self._flush(side)

    def _deliver(self, data: bytes, to_slave: bool, local: int, src: Addr) -> None:
        target = self.slave if to_slave else self.master
        conn = target.conn
        paths = conn.multipath
        if not to_slave and paths is not None:
            paths.rx_local = local
        conn.receive_datagram(data, src, now=self.now)
        if not to_slave and paths is not None:
            paths.rx_local = 0
        self._drain(target)
        self._flush(target)

    def inject(
        self, data: bytes, *, to_slave: bool, local: int = 0, source: Addr | None = None
    ) -> None:
        """Hand a crafted datagram to one side now (an attacker's, or a replay)."""
        if source is None:
            source = master_addr(local) if to_slave else SLAVE_ADDR
        self.injected.append((self.now, data, to_slave, local, source))
        self._deliver(data, to_slave, local, source)

    def _drain(self, side: Side) -> None:
        peer = self.slave if side is self.master else self.master
        while (event := side.conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                side.received.append(event)
                number = int.from_bytes(event.payload[:4], "big")
                sent = peer.sent_at.get(number)
                if sent is not None:
                    side.latency.append(self.now - sent)
            else:
                side.events.append(event)

    def _flush(self, side: Side) -> None:
        conn = side.conn
        to_slave = side is self.master
        for data, addr in conn.datagrams_to_send(now=self.now):
            if to_slave:
                self._send(data, True, 0, master_addr(0), addr)
            else:
                local = self.alias.get((addr[0], addr[1]), int(addr[1]) - 40001)
                self._send(data, False, local, SLAVE_ADDR, addr)
        paths = conn.multipath
        if paths is not None and paths.routed:
            routed, paths.routed = paths.routed, []
            for data, remote, local in routed:
                assert to_slave, "only the master has several local sockets here"
                self._send(data, True, local, master_addr(local), remote)

    def _send(self, data: bytes, to_slave: bool, local: int, src: Addr, dst: Addr) -> None:
        if not 0 <= local < len(self.links):
            return
        link = self.links[local]
        direction = link.ms if to_slave else link.sm
        if not link.up:
            direction.datagrams += 1
            direction.dropped += 1
            return
        admitted = direction.admit(data)
        if admitted is None:
            return
        if to_slave:
            link.carried_ms += 1
        else:
            link.carried_sm += 1
        delay, arriving = admitted
        self._order += 1
        heapq.heappush(
            self._in_flight, (self.now + delay, self._order, arriving, to_slave, local, src, dst)
        )
