"""A master and a slave Connection wired together in fake time, with scripted loss and reordering.

Time jumps from one thing to the next (a sample tick, a delivery, a connection timer), so simulated
minutes cost seconds. Loss and extra delay are decided by deterministic functions of each direction's
datagram index, so every test run sees exactly the same network.
"""

from __future__ import annotations

import heapq
import random
from collections.abc import Callable
from dataclasses import dataclass, field

from tdtp import Connection, ConnectionConfig, DataReceived, Event, Role
from tdtp.admission import Admission, PathMigration
from tdtp.capture.pcap import PcapWriter
from tdtp.protection.keys import KeyInput, KeysInput

MASTER_ADDR = ("192.0.2.1", 40001)
SLAVE_ADDR = ("192.0.2.2", 40002)

Addr = tuple[str, int]
DropRule = Callable[[int], bool]
DelayRule = Callable[[int], float]


def never(_: int) -> bool:
    return False


def no_extra(_: int) -> float:
    return 0.0


@dataclass
class Direction:
    """One way across the fake network."""

    delay: float = 0.010
    drop: DropRule = never
    extra_delay: DelayRule = no_extra
    datagrams: int = 0
    dropped: int = 0
    wire: list[bytes] = field(default_factory=list)
    keep_wire: bool = False
    rewrite: Callable[[int, bytes], bytes] | None = None
    """An on-path attacker: what datagram ``index`` becomes on its way (after ``wire`` saw it)."""
    drop_datagram: Callable[[bytes], bool] | None = None
    """Drop by content (e.g. a DATA packet's sequence number), besides ``drop`` by index."""

    def admit(self, datagram: bytes) -> tuple[float, bytes] | None:
        """The datagram's one-way delay and what arrives, or None if the rule drops it."""
        index = self.datagrams
        self.datagrams += 1
        if self.keep_wire:
            self.wire.append(datagram)
        if self.drop(index) or (self.drop_datagram is not None and self.drop_datagram(datagram)):
            self.dropped += 1
            return None
        if self.rewrite is not None:
            datagram = self.rewrite(index, datagram)
        return self.delay + self.extra_delay(index), datagram


@dataclass
class Endpoint:
    conn: Connection
    addr: tuple[str, int]
    rate: float = 0.0
    payload_size: int = 100
    received: list[DataReceived] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    next_sample: float = 0.0
    """The next tick of the ideal schedule (k / rate)."""
    jitter: DelayRule = no_extra
    """Lateness of tick k in seconds (a real event loop does not tick on time)."""
    offered: int = 0

    @property
    def next_tick(self) -> float:
        return self.next_sample + self.jitter(self.offered)


class FakeTime:
    """Time that jumps from one thing to the next: ``_next_time`` says when, ``_step`` does it."""

    now: float

    def _next_time(self) -> float | None:
        raise NotImplementedError

    def _step(self) -> None:
        raise NotImplementedError

    def run_for(self, duration: float) -> None:
        self.run_until(self.now + duration)

    def run_until(self, end: float, stop: Callable[[], bool] | None = None) -> None:
        same_instant = 0
        while True:
            if stop is not None and stop():
                return
            upcoming = self._next_time()
            if upcoming is None or upcoming > end:
                self.now = end
                return
            if upcoming <= self.now:
                same_instant += 1
                if same_instant > 100_000:
                    # A deadline that stays due after it was served would hang the event loop too.
                    raise AssertionError(f"livelock at t={self.now}: a deadline never moves on")
            else:
                same_instant = 0
            self.now = max(self.now, upcoming)
            self._step()


class Pair(FakeTime):
    def __init__(
        self,
        master_config: ConnectionConfig | None = None,
        slave_config: ConnectionConfig | None = None,
        *,
        ms: Direction | None = None,
        sm: Direction | None = None,
        seed: int = 1,
        master_key: KeyInput | None = None,
        slave_keys: KeysInput | None = None,
    ) -> None:
        """``master_key`` and ``slave_keys`` make a keyed pair (pass the same key to both)."""
        self.now = 0.0
        self.master = Endpoint(
            Connection(master_config, role=Role.MASTER, rng=random.Random(seed), key=master_key),
            MASTER_ADDR,
        )
        self.slave = Endpoint(
            Connection(slave_config, role=Role.SLAVE, rng=random.Random(seed + 1), keys=slave_keys),
            SLAVE_ADDR,
        )
        self.ms = ms if ms is not None else Direction()
        self.sm = sm if sm is not None else Direction()
        # (time, order, data, to_slave, source address, destination address)
        self._in_flight: list[tuple[float, int, bytes, bool, Addr, Addr]] = []
        self._order = 0
        self.capture: PcapWriter | None = None
        """Records every datagram sent (before the fake network's loss) and injected."""
        self.capture_epoch = 1_700_000_000.0
        self.addresses = (MASTER_ADDR, SLAVE_ADDR)
        """What the capture names the master and the slave (the connections use the defaults)."""
        self.migration: PathMigration | None = None
        """The slave's front for datagrams from addresses its session does not hold (path
        migration), as a server has; ``None`` (the default): they reach the connection directly."""
        self.to_dead_address = 0
        """Datagrams the slave sent to an address the master no longer has (after rebind_master)."""
        self.challenges = 0
        """PATH_CHALLENGEs the slave's front sent."""

    # ----------------------------------------------------------------- driving

    def open(self, timeout: float = 5.0) -> None:
        self.master.conn.connect(SLAVE_ADDR, now=self.now)
        self._flush(self.master)
        self.run_until(self.now + timeout, stop=lambda: self.established)

    @property
    def established(self) -> bool:
        from tdtp import State

        return self.master.conn.state is State.ESTABLISHED and (
            self.slave.conn.state is State.ESTABLISHED
        )

    def start_samples(
        self,
        master_rate: float,
        slave_rate: float,
        size: int = 100,
        jitter: DelayRule = no_extra,
    ) -> None:
        """Both applications offer ``size``-byte samples at fixed rates from now on (0 = silent),
        tick k late by ``jitter(k)`` seconds."""
        for endpoint, rate in ((self.master, master_rate), (self.slave, slave_rate)):
            endpoint.rate = rate
            endpoint.payload_size = size
            endpoint.next_sample = self.now
            endpoint.jitter = jitter

    def drain(self, duration: float = 0.2) -> None:
        """Stop both applications and let what is in flight arrive and be acknowledged."""
        self.master.rate = self.slave.rate = 0.0
        self.run_for(duration)

    def _next_time(self) -> float | None:
        times = []
        if self._in_flight:
            times.append(self._in_flight[0][0])
        for endpoint in (self.master, self.slave):
            timer = endpoint.conn.get_timer()
            if timer is not None:
                times.append(timer)
            if endpoint.rate > 0:
                times.append(endpoint.next_tick)
        return min(times) if times else None

    def _step(self) -> None:
        now = self.now
        while self._in_flight and self._in_flight[0][0] <= now:
            _, _, data, to_slave, src, dst = heapq.heappop(self._in_flight)
            target = self.slave if to_slave else self.master
            if dst != target.addr:
                self.to_dead_address += 1
                continue
            peer = target.conn.peer
            if to_slave and self.migration is not None and peer is not None and src != peer:
                outcome = self.migration.on_unattached(data, src, now, [target.conn])
                if isinstance(outcome, bytes):
                    self.challenges += 1
                    self._send(outcome, to_slave=False, src=SLAVE_ADDR, dst=src)
                    continue
                if outcome is None:
                    continue
            else:
                target.conn.receive_datagram(data, src, now=now)
            self._drain(target)
            self._flush(target)
        for endpoint in (self.master, self.slave):
            timer = endpoint.conn.get_timer()
            if timer is not None and timer <= now:
                endpoint.conn.handle_timer(now=now)
                self._drain(endpoint)
            if endpoint.rate > 0 and endpoint.next_tick <= now:
                endpoint.next_sample += 1.0 / endpoint.rate
                from tdtp import State

                if endpoint.conn.state is State.ESTABLISHED:
                    endpoint.offered += 1
                    stamp = endpoint.offered.to_bytes(4, "big")
                    endpoint.conn.send(stamp + bytes(endpoint.payload_size - 4), now=now)
            self._flush(endpoint)

    def _drain(self, endpoint: Endpoint) -> None:
        while (event := endpoint.conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                endpoint.received.append(event)
            else:
                endpoint.events.append(event)

    def rebind_master(self, addr: Addr) -> None:
        """A NAT rebinding: from now on the master's datagrams come from ``addr``, and what the
        slave sends to the old address is lost. Installs the slave's path-migration front (as a
        server has) if there is none."""
        self.master.addr = addr
        if self.migration is None:
            self.migration = Admission(self.slave.conn.config, rng=random.Random(7)).paths

    def _flush(self, endpoint: Endpoint) -> None:
        to_slave = endpoint is self.master
        for data, addr in endpoint.conn.datagrams_to_send(now=self.now):
            self._send(data, to_slave=to_slave, src=endpoint.addr, dst=addr)

    def _send(self, data: bytes, *, to_slave: bool, src: Addr, dst: Addr) -> None:
        direction = self.ms if to_slave else self.sm
        if self.capture is not None:
            source, target = self.addresses if to_slave else self.addresses[::-1]
            self.capture.write_udp(source, target, data, self.capture_epoch + self.now)
        admitted = direction.admit(data)
        if admitted is not None:
            delay, arriving = admitted
            self._order += 1
            heapq.heappush(
                self._in_flight,
                (self.now + delay, self._order, arriving, to_slave, src, dst),
            )

    def inject(self, data: bytes, *, to_slave: bool, source: tuple[str, int]) -> None:
        """Hand a crafted datagram to one side now, as if it came from ``source``."""
        target = self.slave if to_slave else self.master
        if self.capture is not None:
            alias = {MASTER_ADDR: self.addresses[0], SLAVE_ADDR: self.addresses[1]}
            destination = self.addresses[1] if to_slave else self.addresses[0]
            self.capture.write_udp(
                alias.get(source, source), destination, data, self.capture_epoch + self.now
            )
        target.conn.receive_datagram(data, source, now=self.now)
        self._drain(target)
        self._flush(target)
