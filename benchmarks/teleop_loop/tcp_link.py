"""An impaired TCP path for the TCP transport: a relay that carries a byte stream as segments through
the same emulated netem link the datagram transports cross.

``tdtp netem-relay`` relays datagrams; a TCP connection through a lossy path behaves differently, and
this machine's kernel has no ``sch_netem`` to impair real segments. So the relay below accepts the
master's connection, opens one to the slave, and carries each direction as TCP would over the link:

* what the sender has written is cut into segments of at most one MSS (a backlog coalesces, as it
  does in a real socket) and each segment goes through a :class:`~tdtp.netem.NetemLink` with the
  profile's spec: delay, jitter, loss, rate and queue limit apply per segment;
* a lost segment is sent again after the time fast retransmit takes (three later segments, then the
  duplicate ACKs' trip back: 3 ms + the smoothed RTT), and a lost retransmission after an RTO
  (200 ms, Linux's minimum, doubling each time);
* the receiver gets the bytes in order only: whatever arrives after a hole waits for it (head-of-line
  blocking), and nothing is ever dropped for being stale;
* the sender never puts more segments in flight than the link's queue holds (an idealised congestion
  control that fills a bottleneck without overflowing it); beyond that the backlog waits at the
  sender, as it would in the socket's send buffer.

What it leaves out: ACK packets and their loss (the return path is only used for the RTT estimate),
slow start and window reductions after loss. Both would make TCP slower, not faster, so its figures
here are a lower bound on what real TCP would suffer.
"""

from __future__ import annotations

import asyncio
import heapq
import time
from dataclasses import dataclass
from typing import Protocol

from tdtp.netem import NetemLink, parse_netem

MSS = 1448
FIRST_RTO = 0.2
FAST_RETRANSMIT_SEGMENTS_S = 0.003


class Writer(Protocol):
    def write(self, data: bytes) -> None: ...


@dataclass
class PathStats:
    segments: int = 0
    """Segments put on the link, retransmissions included."""
    retransmissions: int = 0
    bytes_delivered: int = 0


class TcpPath:
    """One direction of the relayed connection, driven by the event loop's callbacks: bytes arriving
    and the link's next delivery or retransmission time (no task of its own, no polling)."""

    def __init__(self, spec: str, seed: int) -> None:
        parsed = parse_netem(spec)
        self.link = NetemLink(parsed, seed=seed)
        self._limit = parsed.limit
        self.stats = PathStats()
        self.one_way = 0.0
        """Smoothed one-way delay of delivered segments (s)."""
        self.reverse: TcpPath | None = None
        self._backlog = bytearray()
        self._next_seq = 0
        self._retransmit: list[tuple[float, int, int, bytes]] = []  # (due, seq, attempt, data)
        self._arrived: dict[int, bytes] = {}
        self._expected = 0
        self._timer: asyncio.TimerHandle | None = None
        self._writer: Writer | None = None

    def srtt(self) -> float:
        back = self.reverse.one_way if self.reverse is not None else self.one_way
        return self.one_way + back

    async def run(self, reader: asyncio.StreamReader, writer: Writer) -> None:
        """Carry ``reader``'s bytes to ``writer`` until the reader's end closes."""
        self._writer = writer
        try:
            while chunk := await reader.read(65536):
                self._backlog += chunk
                self._service()
        except ConnectionError:
            pass  # an end closed abruptly: the run is over
        finally:
            if self._timer is not None:
                self._timer.cancel()

    def _put(self, seq: int, data: bytes, attempt: int, now: float) -> None:
        stats = self.link.stats
        lost_before = stats.lost + stats.queue_dropped
        self.link.send(data, now, (seq, now))
        self.stats.segments += 1
        if stats.lost + stats.queue_dropped > lost_before:
            wait = (
                FAST_RETRANSMIT_SEGMENTS_S + self.srtt()
                if attempt == 0
                else FIRST_RTO * 2 ** (attempt - 1)
            )
            heapq.heappush(self._retransmit, (now + wait, seq, attempt + 1, data))

    def _service(self) -> None:
        link, writer = self.link, self._writer
        now = time.monotonic()  # the event loop's clock too
        while self._retransmit and self._retransmit[0][0] <= now:
            _, seq, attempt, data = heapq.heappop(self._retransmit)
            self.stats.retransmissions += 1
            self._put(seq, data, attempt, now)
        while self._backlog and link.in_flight < self._limit:
            data = bytes(self._backlog[:MSS])
            del self._backlog[:MSS]
            self._put(self._next_seq, data, 0, now)
            self._next_seq += 1
        for data, tag in link.deliver(now):
            seq, sent = tag  # type: ignore[misc]
            self.one_way += ((now - sent) - self.one_way) / 8
            self._arrived[seq] = data
        while self._expected in self._arrived:
            data = self._arrived.pop(self._expected)
            self._expected += 1
            self.stats.bytes_delivered += len(data)
            if writer is not None:
                writer.write(data)
        deadlines = [t for t in (link.next_delivery(),) if t is not None]
        if self._retransmit:
            deadlines.append(self._retransmit[0][0])
        if self._backlog and link.in_flight >= self._limit:
            deadlines.append(now + 0.0005)  # the queue drains with time: look again soon
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if deadlines:
            self._timer = asyncio.get_running_loop().call_at(min(deadlines), self._service)


def paths(spec: str, seed: int) -> tuple[TcpPath, TcpPath]:
    """Both directions (master to slave, slave to master), each knowing the other for its RTT."""
    to_slave, to_master = TcpPath(spec, seed), TcpPath(spec, seed + 1)
    to_slave.reverse, to_master.reverse = to_master, to_slave
    return to_slave, to_master


async def serve(
    forward_port: int, both: tuple[TcpPath, TcpPath], ready: asyncio.Future[int]
) -> None:
    """Relay one connection to ``forward_port``; ``ready`` gets the listening port."""
    to_slave, to_master = both
    done: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    async def accepted(m_reader: asyncio.StreamReader, m_writer: asyncio.StreamWriter) -> None:
        s_reader, s_writer = await asyncio.open_connection("127.0.0.1", forward_port)
        try:
            await asyncio.gather(
                to_slave.run(m_reader, s_writer), to_master.run(s_reader, m_writer)
            )
        finally:
            s_writer.close()
            m_writer.close()
            if not done.done():
                done.set_result(None)

    server = await asyncio.start_server(accepted, "127.0.0.1", 0)
    ready.set_result(server.sockets[0].getsockname()[1])
    async with server:
        await done
