"""A slave serving several masters on one address, and the masters, in fake time.

:class:`SlaveTable` does with datagrams what ``tdtp.aio.server.Server`` does with them (one shared
:class:`~tdtp.admission.Admission`, the slot policy of :mod:`tdtp.admission.slots`, its eviction
notices, a session per master address), without sockets or a clock, so that a test can run
attacks of thousands of validated OPENs against it in a fraction of a second. :class:`Network`
moves datagrams between it and any number of master :class:`~tdtp.Connection` objects with a fixed
one-way delay; a master can be *frozen* (a GC pause, SIGSTOP: it neither runs nor reads, and what
arrives meanwhile waits for it).
"""

from __future__ import annotations

import heapq
import random
from collections.abc import Callable
from dataclasses import dataclass, field

from tdtp import CloseCause, Connection, ConnectionConfig, DataReceived, Role, State
from tdtp.admission import Admission, AdmittedOpen, Reply
from tdtp.admission.slots import EvictionNotices, SessionSlots, Verdict
from tdtp.protection.keys import KeyInput, KeyRing
from tdtp.session.events import ConnectionClosed, Event
from tdtp.wire.control import CloseReason

Addr = tuple[str, int]
SLAVE = ("192.0.2.2", 7000)


def _is_open(data: bytes) -> bool:
    return len(data) > 5 and data[0] >> 6 == 2 and data[5] == 1


@dataclass
class Session:
    """One of the slave's sessions and what its application saw."""

    conn: Connection
    master: Addr
    delivered: list[float] = field(default_factory=list)
    """When each sample arrived (``now``)."""
    closed: ConnectionClosed | None = None


class SlaveTable:
    """The slave: sessions by master address, admission, slots, eviction notices."""

    def __init__(
        self,
        config: ConnectionConfig,
        max_peers: int,
        keys: KeyRing | None = None,
        rate: float = 1000.0,
    ) -> None:
        self.config = config
        self.admission = Admission(config, keys, rng=random.Random(5))
        self.slots = SessionSlots(config, max_peers)
        self.notices = EvictionNotices(max_peers, config.idle_timeout, config.silence_timeout)
        self.sessions: dict[Addr, Session] = {}
        self.ended: list[Session] = []
        self.rate = rate
        """Samples per second the slave's application sends each established master."""
        self.refused = 0
        self._rng = random.Random(9)

    def receive(self, data: bytes, src: Addr, now: float) -> list[tuple[bytes, Addr]]:
        out: list[tuple[bytes, Addr]] = []
        session = self.sessions.get(src)
        if session is not None:
            session.conn.receive_datagram(data, src, now=now)
            self.flush(session, out, now)
            if src in self.sessions or not _is_open(data):
                return out
        if not _is_open(data):
            if self.notices.holds(src, now):
                close = self.notices.answer(src, len(data), now)
                if close is not None:
                    out.append((close, src))
                return out
            reset = self.admission.reset(data, now)
            if reset is not None:
                out.append((reset, src))
            return out
        verdict = self.admission.admit(data, src, now)
        if isinstance(verdict, Reply):
            out.append((verdict.datagram, src))
        elif isinstance(verdict, AdmittedOpen):
            self._open(verdict, src, now, out)
        return out

    def _open(
        self, admitted: AdmittedOpen, src: Addr, now: float, out: list[tuple[bytes, Addr]]
    ) -> None:
        holders = [session.conn for session in self.sessions.values()]
        placement = self.slots.place(admitted.key, src, holders, now)
        if placement.verdict is Verdict.BUSY or placement.verdict is Verdict.SHARE:
            self.refused += 1
            out.append((self.admission.reject(admitted, CloseReason.BUSY), src))
            return
        if placement.holder is not None:
            victim = next(s for s in self.sessions.values() if s.conn is placement.holder)
            close = victim.conn.evict(placement.detail, now=now)
            self.flush(victim, out, now)
            if close is not None:
                self.notices.add(victim.master, close, now)
        self.notices.forget(src)
        conn = Connection(
            self.config,
            role=Role.SLAVE,
            admission=self.admission,
            rng=random.Random(self._rng.random()),
        )
        session = Session(conn, src)
        self.sessions[src] = session
        conn.accept_open(admitted, src, now=now)
        self.flush(session, out, now)

    def flush(self, session: Session, out: list[tuple[bytes, Addr]], now: float) -> None:
        conn = session.conn
        out.extend(conn.datagrams_to_send(now=now))
        while (event := conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                session.delivered.append(now)
            elif isinstance(event, ConnectionClosed):
                session.closed = event
        if conn.state is State.CLOSED and self.sessions.get(session.master) is session:
            del self.sessions[session.master]
            self.ended.append(session)

    def all_sessions(self) -> list[Session]:
        return list(self.sessions.values()) + self.ended


@dataclass
class Master:
    """A master on the fake network: its connection, its sample rate and its freezes."""

    conn: Connection
    addr: Addr
    rate: float = 0.0
    next_tick: float = 0.0
    frozen_until: float = 0.0
    cut_until: float = 0.0
    """Until then, everything to and from this master is lost (its path is down; it runs on)."""
    events: list[Event] = field(default_factory=list)
    """Every event but the samples (counted in ``received``)."""
    received: int = 0
    closed_seen: bool = False

    @property
    def cause(self) -> CloseCause | None:
        event = self.conn.close_event
        return None if event is None else event.cause


class Network:
    """The slave and its masters, a fixed one-way ``delay`` apart, in fake time."""

    def __init__(self, slave: SlaveTable, delay: float = 0.0005) -> None:
        self.slave = slave
        self.delay = delay
        self.now = 0.0
        self.masters: dict[Addr, Master] = {}
        self._flight: list[tuple[float, int, bytes, Addr, Addr]] = []
        self._order = 0
        self._slave_ticks: float = 0.0
        self.on_master_closed: Callable[[Master], None] | None = None
        """Called once when a master's connection closes (an attacker opens its next one)."""

    def add_master(
        self,
        addr: Addr,
        *,
        rate: float = 0.0,
        key: KeyInput | None = None,
        config: ConnectionConfig | None = None,
        seed: int = 1,
    ) -> Master:
        conn = Connection(config, role=Role.MASTER, rng=random.Random(seed), key=key)
        master = Master(conn, addr, rate=rate, next_tick=self.now)
        self.masters[addr] = master
        conn.connect(SLAVE, now=self.now)
        self._flush_master(master)
        return master

    def freeze(self, master: Master, seconds: float) -> None:
        master.frozen_until = self.now + seconds

    def cut(self, master: Master, seconds: float) -> None:
        master.cut_until = self.now + seconds

    def run_until(self, end: float) -> None:
        while True:
            upcoming = self._next_time()
            if upcoming is None or upcoming > end:
                self.now = end
                return
            self.now = max(self.now, upcoming)
            self._step()

    def run_for(self, seconds: float) -> None:
        self.run_until(self.now + seconds)

    # ------------------------------------------------------------------ internals

    def _send(self, data: bytes, src: Addr, dst: Addr) -> None:
        master = self.masters.get(dst if src == SLAVE else src)
        if master is not None and master.cut_until > self.now:
            return
        self._order += 1
        heapq.heappush(self._flight, (self.now + self.delay, self._order, data, src, dst))

    def _next_time(self) -> float | None:
        times: list[float] = []
        if self._flight:
            times.append(self._flight[0][0])
        for master in self.masters.values():
            if master.conn.state is State.CLOSED:
                continue
            if master.frozen_until > self.now:
                times.append(master.frozen_until)
                continue
            timer = master.conn.get_timer()
            if timer is not None:
                times.append(timer)
            if master.rate > 0 and master.conn.state is State.ESTABLISHED:
                times.append(master.next_tick)
        for session in self.slave.sessions.values():
            timer = session.conn.get_timer()
            if timer is not None:
                times.append(timer)
        if self.slave.rate > 0 and self.slave.sessions:
            times.append(self._slave_ticks)
        return min(times) if times else None

    def _step(self) -> None:
        now = self.now
        while self._flight and self._flight[0][0] <= now:
            _, _, data, src, dst = heapq.heappop(self._flight)
            if dst == SLAVE:
                for reply, to in self.slave.receive(data, src, now):
                    self._send(reply, SLAVE, to)
                continue
            master = self.masters.get(dst)
            if master is None:
                continue
            if master.frozen_until > now:  # held by the kernel until the process runs again
                self._order += 1
                heapq.heappush(self._flight, (master.frozen_until, self._order, data, src, dst))
                continue
            master.conn.receive_datagram(data, src, now=now)
            self._flush_master(master)
        for master in list(self.masters.values()):
            if master.frozen_until > now or master.conn.state is State.CLOSED:
                continue
            timer = master.conn.get_timer()
            if timer is not None and timer <= now:
                master.conn.handle_timer(now=now)
            if master.rate > 0 and master.conn.state is State.ESTABLISHED:
                if master.next_tick < now - 0.05:
                    master.next_tick = now  # back from a freeze: the loop goes on from now
                while master.next_tick <= now:
                    master.conn.send(bytes(100), now=now)
                    master.next_tick += 1.0 / master.rate
            self._flush_master(master)
        slave = self.slave
        for session in list(slave.sessions.values()):
            conn = session.conn
            timer = conn.get_timer()
            if timer is not None and timer <= now:
                conn.handle_timer(now=now)
            out: list[tuple[bytes, Addr]] = []
            slave.flush(session, out, now)
            for reply, to in out:
                self._send(reply, SLAVE, to)
        if slave.rate > 0 and self._slave_ticks <= now:
            self._slave_ticks = now + 1.0 / slave.rate
            for session in list(slave.sessions.values()):
                if session.conn.state is State.ESTABLISHED:
                    session.conn.send(bytes(60), now=now)
                    out = []
                    slave.flush(session, out, now)
                    for reply, to in out:
                        self._send(reply, SLAVE, to)

    def _flush_master(self, master: Master) -> None:
        conn = master.conn
        for data, _ in conn.datagrams_to_send(now=self.now):
            self._send(data, master.addr, SLAVE)
        while (event := conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                master.received += 1
            else:
                master.events.append(event)
        if conn.state is State.CLOSED and not master.closed_seen:
            master.closed_seen = True
            if self.on_master_closed is not None:
                self.on_master_closed(master)
