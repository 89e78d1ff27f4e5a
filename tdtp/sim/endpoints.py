"""Applications on simulated hosts: the real TDTP :class:`~tdtp.session.connection.Connection` at both ends of a
teleoperation session, and a constant-rate UDP source.

:class:`TdtpEndpoint` is the simulator's I/O shell around the unchanged sans-IO connection, doing what
the asyncio endpoint does on real sockets: it feeds every arriving datagram in, serves
``get_timer()`` with a :class:`~tdtp.sim.engine.Timer`, offers a sample every ``1 / sample_rate``
seconds, and flushes ``datagrams_to_send()`` after every input. Each datagram becomes a
:class:`~tdtp.sim.engine.Packet` of ``len(datagram) + ip_overhead`` bytes on the wire: 20 for the
paper's native encapsulation (TDTP right on IPv4), 28 for TDTP over UDP.

A sample's payload starts with its generation time (8 bytes) and its index (4 bytes), zero padded
to ``payload_size``: the receiving side reads the time back to measure the sample's age.
"""

from __future__ import annotations

import math
import random
import struct
from collections import deque
from dataclasses import dataclass

from tdtp.config import ConnectionConfig, Role
from tdtp.errors import InvalidArgumentError
from tdtp.session.connection import Connection
from tdtp.session.events import ConnectionClosed, ConnectionEstablished, DataReceived
from tdtp.session.state import State
from tdtp.sim.engine import Network, Node, Packet, Timer
from tdtp.sim.metrics import FlowRecorder

__all__ = [
    "IP_HEADER",
    "UDP_HEADER",
    "CbrSource",
    "PacketSink",
    "TdtpEndpoint",
    "TdtpSession",
]

IP_HEADER = 20
UDP_HEADER = 8
_STAMP = struct.Struct(">dI")
_DATA, _ACK = 0, 1


class TdtpEndpoint:
    """One side of a TDTP session on a simulated host.

    ``out_data`` records the data packets this side sends (and their drops); ``in_data`` the samples
    delivered to this side. ``out_other`` (optional) records its ACK and control packets.

    ``send_jitter`` models a host's send path that is not cycle-exact: each datagram enters the
    network a uniform random time in ``[0, send_jitter)`` after the connection released it, never
    overtaking an earlier one. Without it, perfectly periodic senders and a link serving equal packets
    in equal times lock into phase at a DropTail queue: one flow finds a free slot every time and
    another never does (Floyd and Jacobson's "phase effects", 1992; ns-2 offers ``overhead_`` for the
    same reason). A packet's one-way delay is counted from its entry into the network; a sample's age
    from its generation, so it includes this wait.
    """

    fast_ticks = True
    """Skip the flush after a sample the pacer holds (see :meth:`_tick`); ``False`` flushes after
    every sample, for tests that check both give the same run."""

    def __init__(
        self,
        net: Network,
        host: Node,
        port: int,
        conn: Connection,
        *,
        sample_rate: float,
        payload_size: int,
        ip_overhead: int,
        out_data: FlowRecorder,
        in_data: FlowRecorder,
        out_other: FlowRecorder | None = None,
        app_phase: float = 0.0,
        app_stop: float = float("inf"),
        send_jitter: float = 0.0,
        rng: random.Random | None = None,
    ) -> None:
        if payload_size < _STAMP.size:
            raise InvalidArgumentError(
                f"payload_size must be at least {_STAMP.size} bytes (the time stamp)"
            )
        self.net = net
        self.sim = net.sim
        self.host = host
        self.port = port
        self.conn = conn
        self.sample_rate = sample_rate
        self.payload_size = payload_size
        self.ip_overhead = ip_overhead
        self.out_data = out_data
        self.in_data = in_data
        self.out_other = out_other
        self.app_phase = app_phase
        self.app_stop = app_stop
        self.send_jitter = send_jitter
        self._rng = rng if rng is not None else random.Random(0)
        self._outbox: deque[tuple[float, Packet]] = deque()
        self._last_out = -math.inf
        self._padding = bytes(payload_size - _STAMP.size)
        self._timer = Timer(self.sim, self._on_timer)
        self._index = 0
        self._ticking = False
        self._same_instant = 0
        self._last_timer = -1.0
        self.established_at: float | None = None
        self.closed: ConnectionClosed | None = None
        self.closed_at: float | None = None
        self.ack_packets = 0
        self.control_packets = 0
        self.samples_offered = 0
        host.bind(port, self)

    @property
    def address(self) -> tuple[str, int]:
        """This end's (node name, port) in the simulated network."""
        return (self.host.name, self.port)

    # -- inputs -----------------------------------------------------------------------------------

    def connect(self, peer: tuple[str, int], now: float) -> None:
        """Master: open towards ``peer`` at ``now``."""
        self.conn.connect(peer, now=now)
        self._after_input(now)

    def receive(self, packet: Packet, now: float) -> None:
        """A packet arrived at ``now``: fed to the connection, its events handled, its answers sent."""
        conn = self.conn
        conn.receive_datagram(packet.payload, (packet.src, packet.sport), now=now)  # type: ignore[arg-type]
        while (event := conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                created = _STAMP.unpack_from(event.payload)[0]
                self.in_data.on_delivered(
                    now, packet.sent_at, len(event.payload), packet.size, now - created
                )
            else:
                self._on_event(event, now)
        self._after_input(now)

    def _on_timer(self, now: float) -> None:
        conn = self.conn
        deadline = conn.get_timer()
        if deadline is not None and deadline <= now:
            conn.handle_timer(now=now)
            while (event := conn.next_event()) is not None:
                if not isinstance(event, DataReceived):
                    self._on_event(event, now)
        self._after_input(now)

    def _tick(self) -> None:
        now = self.sim.now
        conn = self.conn
        if now >= self.app_stop or conn.state is not State.ESTABLISHED:
            self._ticking = False
            return
        index = self._index
        self._index = index + 1
        self.samples_offered += 1
        conn.send(_STAMP.pack(now, index & 0xFFFFFFFF) + self._padding, now=now)
        hint = conn.timer_hint
        if self.fast_ticks and conn.controller.next_send_time() > now and hint > now:
            # The pacer holds the sample, so nothing can leave now, and the connection's timer
            # hint bounds every deadline the sample moved (the pacer's, and the controller's: a
            # waiting sample makes trinomial time its interval end). The timer already stands at
            # get_timer() from the last input, so this is what _after_input would do, at a fraction
            # of its cost: most samples of a flow held back by congestion end here.
            deadline = self._timer.deadline
            if deadline is None or hint < deadline:
                self._timer.set(hint)
        else:
            self._after_input(now)
        self.sim.call_at(self._tick_time(index + 1), self._tick)

    def _tick_time(self, index: int) -> float:
        assert self.established_at is not None
        return self.established_at + self.app_phase + index / self.sample_rate

    def _on_event(self, event: object, now: float) -> None:
        if isinstance(event, ConnectionEstablished):
            self.established_at = now
            if self.sample_rate > 0 and not self._ticking:
                self._ticking = True
                self.sim.call_at(self._tick_time(0), self._tick)
        elif isinstance(event, ConnectionClosed):
            self.closed = event
            self.closed_at = now

    # -- outputs ----------------------------------------------------------------------------------

    def _after_input(self, now: float) -> None:
        """Flush whatever the connection wants to send, then re-arm its timer."""
        conn = self.conn
        host = self.host
        name, port, overhead = host.name, self.port, self.ip_overhead
        for datagram, addr in conn.datagrams_to_send(now=now):
            size = len(datagram) + overhead
            kind = datagram[0] >> 6
            recorder: FlowRecorder | None
            if kind == _DATA:
                recorder = self.out_data
            else:
                recorder = self.out_other
                if kind == _ACK:
                    self.ack_packets += 1
                else:
                    self.control_packets += 1
            if self.send_jitter:
                # The host's send path: each datagram leaves up to send_jitter late, in order.
                leave = max(self._last_out, now + self._rng.random() * self.send_jitter)
                self._last_out = leave
                pkt = Packet(name, port, addr[0], addr[1], size, datagram, leave, recorder)
                outbox = self._outbox
                outbox.append((leave, pkt))
                if len(outbox) == 1:
                    self.sim.call_at(leave, self._leave)
                continue
            if recorder is not None:
                recorder.on_sent(now, size)
            host.send(Packet(name, port, addr[0], addr[1], size, datagram, now, recorder), now)
        deadline = conn.get_timer()
        if deadline is None:
            self._timer.cancel()
            return
        if deadline <= now:
            # Due already: serve it in a new event at the same instant. A deadline that stays due
            # after being served would spin here forever; catch that instead of hanging.
            if now == self._last_timer:
                self._same_instant += 1
                if self._same_instant > 10_000:
                    raise RuntimeError(
                        f"{self.host.name}: the connection's timer stays due at t={now}"
                    )
            else:
                self._same_instant = 0
                self._last_timer = now
            deadline = now
        self._timer.set(deadline)

    def _leave(self) -> None:
        """Datagrams whose (jittered) departure from the host has come."""
        now = self.sim.now
        outbox = self._outbox
        host = self.host
        while outbox and outbox[0][0] <= now:
            pkt = outbox.popleft()[1]
            owner = pkt.owner
            if isinstance(owner, FlowRecorder):
                owner.on_sent(now, pkt.size)
            host.send(pkt, now)
        if outbox:
            self.sim.call_at(outbox[0][0], self._leave)


@dataclass
class TdtpSession:
    """A master and a slave, each on its host, and the recorders of both directions."""

    master: TdtpEndpoint
    slave: TdtpEndpoint
    ms: FlowRecorder
    """Master to slave data."""
    sm: FlowRecorder
    """Slave to master data."""
    ms_other: FlowRecorder
    """ACK and control packets the master sends (they share the master-to-slave path)."""
    sm_other: FlowRecorder

    @classmethod
    def create(
        cls,
        net: Network,
        master_host: str,
        slave_host: str,
        config: ConnectionConfig,
        *,
        name: str = "tdtp",
        port: int = 7000,
        sample_rate: float = 1000.0,
        payload_size: int = 100,
        ip_overhead: int = IP_HEADER,
        start: float = 0.0,
        stop: float = float("inf"),
        bin_width: float = 0.5,
        duration: float = 100.0,
        seed: int = 0,
        send_jitter: float = 0.0,
    ) -> TdtpSession:
        """Set up both ends; the master opens at ``start`` and both sample until ``stop``.

        ``send_jitter`` > 0 makes every datagram leave its host a uniform random time in
        ``[0, send_jitter)`` late (in order): see :class:`TdtpEndpoint`.
        """
        rng = random.Random(seed)
        ms = FlowRecorder(f"{name} M->S", bin_width=bin_width, duration=duration)
        sm = FlowRecorder(f"{name} S->M", bin_width=bin_width, duration=duration)
        ms_other = FlowRecorder(f"{name} M->S acks", bin_width=bin_width, duration=duration)
        sm_other = FlowRecorder(f"{name} S->M acks", bin_width=bin_width, duration=duration)
        master = TdtpEndpoint(
            net,
            net.node(master_host),
            port,
            Connection(config, role=Role.MASTER, rng=random.Random(rng.getrandbits(64))),
            out_data=ms,
            in_data=sm,
            out_other=ms_other,
            sample_rate=sample_rate,
            payload_size=payload_size,
            ip_overhead=ip_overhead,
            app_phase=0.0,
            app_stop=stop,
            send_jitter=send_jitter,
            rng=random.Random(rng.getrandbits(64)),
        )
        slave = TdtpEndpoint(
            net,
            net.node(slave_host),
            port,
            Connection(config, role=Role.SLAVE, rng=random.Random(rng.getrandbits(64))),
            out_data=sm,
            in_data=ms,
            out_other=sm_other,
            sample_rate=sample_rate,
            payload_size=payload_size,
            ip_overhead=ip_overhead,
            app_phase=rng.random() / sample_rate if sample_rate > 0 else 0.0,
            app_stop=stop,
            send_jitter=send_jitter,
            rng=random.Random(rng.getrandbits(64)),
        )
        net.sim.call_at(start, master.connect, slave.address, start)
        return cls(master, slave, ms, sm, ms_other, sm_other)


class PacketSink:
    """Counts what arrives on a port into a :class:`FlowRecorder` (``app_bytes`` = wire bytes minus
    ``overhead``)."""

    def __init__(self, host: Node, port: int, recorder: FlowRecorder, overhead: int) -> None:
        self.recorder = recorder
        self.overhead = overhead
        host.bind(port, self)

    def receive(self, packet: Packet, now: float) -> None:
        self.recorder.on_delivered(now, packet.sent_at, packet.size - self.overhead, packet.size)


class CbrSource:
    """Constant bit rate over UDP: ``size``-byte IP packets every ``size * 8 / rate_bps`` seconds,
    while switched on (``periods`` of ``(start, stop)``). Unresponsive, like ns-2's CBR over UDP."""

    def __init__(
        self,
        net: Network,
        src: str,
        dst: str,
        *,
        rate_bps: float,
        size: int = 1000,
        port: int = 9000,
        periods: tuple[tuple[float, float], ...] = ((0.0, float("inf")),),
        bin_width: float = 0.5,
        duration: float = 100.0,
        name: str = "cbr",
    ) -> None:
        self.net = net
        self.sim = net.sim
        self.host = net.node(src)
        self.dst = dst
        self.port = port
        self.size = size
        self.interval = size * 8 / rate_bps
        self.recorder = FlowRecorder(name, bin_width=bin_width, duration=duration)
        self.sink = PacketSink(net.node(dst), port, self.recorder, IP_HEADER + UDP_HEADER)
        for start, stop in periods:
            self.sim.call_at(start, self._send, stop)

    def _send(self, stop: float) -> None:
        now = self.sim.now
        if now >= stop:
            return
        self.recorder.on_sent(now, self.size)
        self.host.send(
            Packet(
                self.host.name, self.port, self.dst, self.port, self.size, None, now, self.recorder
            ),
            now,
        )
        self.sim.call_at(now + self.interval, self._send, stop)
