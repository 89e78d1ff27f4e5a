"""A TCP model for cross traffic, after ns-2's ``Agent/TCP`` (Tahoe), ``Agent/TCP/Reno`` or
``Agent/TCP/Newreno`` with ``Agent/TCPSink`` and an FTP source.

Modelled, with ns-2's defaults (``tcl/lib/ns-default.tcl`` of ns-2.34/2.35, the versions of the
paper's time):

* **sequence numbers in packets**, as ns-2 counts them: every segment carries ``packetSize_`` = 1000
  bytes of data plus a 40-byte TCP/IP header (1040 bytes on the wire); the sink answers every
  segment with one 40-byte cumulative ACK (``Agent/TCPSink``: no delayed ACKs);
* **windows**: ``window_`` = 20 packets is the receiver's window, a cap on what may be outstanding
  (``min(cwnd, window_)``); ``windowInit_`` = 2; the initial ``ssthresh`` is the window;
* **slow start** (``cwnd += 1`` per ACK below ``ssthresh``) and **congestion avoidance**
  (``cwnd += 1 / cwnd`` per ACK); cwnd itself is not capped by the window, as in ns-2;
* **fast retransmit** on the 3rd duplicate ACK (``numdupacks_``), ``ssthresh = max(min(cwnd,
  window) / 2, 2)``. ``tahoe`` (ns-2's plain ``Agent/TCP``, the default agent of an ns-2 script)
  then does what ns-2's ``tahoe_action`` does: ``cwnd = 1`` and go back to the first unacknowledged
  segment, slow start from there, no fast recovery. ``reno`` and ``newreno`` enter **fast recovery**
  with window inflation; ``newreno`` stays in recovery over
  partial ACKs (RFC 6582, retransmitting the next hole each time and restarting the timer on the first
  partial ACK only, ns-2's ``newreno_changes1_``) until everything sent before the loss is acknowledged;
  ``reno`` leaves recovery on the first new ACK. No second fast retransmit for losses of a window
  already recovered: the 3rd duplicate ACK counts only once ``highest_ack > recover`` (ns-2's
  ``bug_fix_``, with its strict comparison). **Limited transmit** (RFC 3042, ns-2's
  ``singledup_`` = 1): the 1st and 2nd duplicate ACKs each release one new segment;
* **retransmission timeout** (RFC 6298, ns-2's ``rfc2988_``): RTT measured on one segment at a time
  (never a retransmitted one: Karn), on a clock ticking every ``tcpTick_`` = 10 ms;
  ``srtt``/``rttvar`` gains 1/8 and 1/4; ``RTO = max(minrto_, srtt + 4 rttvar) * backoff``, at most
  ``maxrto_`` = 60 s, first ``rtxcur_init_`` = 3 s; on expiry ``ssthresh`` halves, ``cwnd = 1``, the
  backoff doubles (up to 64) and the sender goes back to the first unacknowledged segment (go-back-N,
  as ns-2 does); a valid RTT sample resets the backoff;
* ``minrto_`` is ns-2's default since 2004, **0.2 s** (ns-2's validation suites pin the older 1 s; the
  paper does not say, and 0.2 s is what ``ns-default.tcl`` of 2.34 and 2.35 ships);
* **slow-start restart** (``slow_start_restart_``): a sender idle for an RTO restarts from
  ``windowInit_``;
* the **FTP** source is always backlogged while on; switched off it sends no new data (what is
  outstanding is still recovered) and switched on again it resumes where it stopped.

Left out: the three-way handshake and FIN (ns-2's one-way agents have none either), SACK, timestamps,
window scaling, delayed ACKs, Nagle (segments are always full), ECN, F-RTO, ``maxburst_`` (ns-2's
default 0 means no limit too), byte counting (RFC 3465), and ns-2's integer rounding of ``srtt`` and
``rttvar`` (kept here as floats of tick-quantised samples).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from tdtp.errors import InvalidArgumentError
from tdtp.sim.engine import Network, Node, Packet, Timer
from tdtp.sim.metrics import FlowRecorder

__all__ = ["TCP_VARIANTS", "TcpConfig", "TcpFlow", "TcpSender", "TcpSink"]

TCP_VARIANTS: tuple[str, ...] = ("tahoe", "reno", "newreno")


@dataclass(frozen=True, slots=True)
class TcpConfig:
    """ns-2 ``Agent/TCP`` parameters (their ns-2 names in the comments)."""

    variant: Literal["tahoe", "reno", "newreno"] = "newreno"
    """``tahoe`` (ns-2's ``Agent/TCP``), ``reno`` (``Agent/TCP/Reno``), ``newreno`` (``Agent/TCP/Newreno``)."""
    segment_size: int = 1000
    """Data bytes per segment (``packetSize_``)."""
    header_size: int = 40
    """TCP/IP header bytes (``tcpip_base_hdr_size_``)."""
    ack_size: int = 40
    """ACK packet bytes (``Agent/TCPSink packetSize_``)."""
    window: int = 20
    """Receiver window, packets (``window_``)."""
    initial_window: int = 2
    """``windowInit_``."""
    dupack_threshold: int = 3
    """``numdupacks_``."""
    limited_transmit: bool = True
    """``singledup_``."""
    tick: float = 0.01
    """RTT clock granularity, seconds (``tcpTick_``)."""
    min_rto: float = 0.2
    """``minrto_``."""
    max_rto: float = 60.0
    """``maxrto_``."""
    initial_rto: float = 3.0
    """``rtxcur_init_``."""
    max_backoff: int = 64
    slow_start_restart: bool = True
    """``slow_start_restart_``."""

    def __post_init__(self) -> None:
        if self.variant not in TCP_VARIANTS:
            raise InvalidArgumentError(
                f"variant must be one of {', '.join(TCP_VARIANTS)}, got {self.variant!r}"
            )
        for name in ("segment_size", "header_size", "ack_size", "window", "initial_window"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value > 0):
                raise InvalidArgumentError(
                    f"TcpConfig.{name} must be a positive integer, got {value!r}"
                )
        for name in ("tick", "min_rto", "max_rto", "initial_rto"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0 < value < math.inf):
                raise InvalidArgumentError(f"TcpConfig.{name} must be a positive number of seconds")

    @property
    def packet_size(self) -> int:
        """Bytes of a full segment on the wire."""
        return self.segment_size + self.header_size


@dataclass(slots=True)
class TcpCounters:
    segments_sent: int = 0
    retransmissions: int = 0
    fast_retransmits: int = 0
    timeouts: int = 0
    rtt_samples: int = 0
    rtt_sum: float = 0.0
    """Sum of the (tick-quantised) RTT samples, seconds."""
    acks_received: int = 0
    cwnd_trace: list[tuple[float, float]] = field(default_factory=list)


class TcpSender:
    """The sending agent: an always-backlogged FTP source on a NewReno/Reno sender."""

    def __init__(
        self,
        net: Network,
        host: Node,
        port: int,
        peer: tuple[str, int],
        config: TcpConfig,
        recorder: FlowRecorder,
        *,
        trace_cwnd: bool = False,
    ) -> None:
        self.sim = net.sim
        self.host = host
        self.port = port
        self.peer = peer
        self.config = config
        self.recorder = recorder
        self.trace_cwnd = trace_cwnd
        self.counters = TcpCounters()
        self._timer = Timer(self.sim, self._on_timeout)
        # Sequence state, in packets. highest_ack: every segment <= it has been acknowledged.
        self.highest_ack = -1
        self.t_seqno = 0
        """Next segment to send."""
        self.maxseq = -1
        """Highest segment sent so far."""
        self.limit = -1
        """Highest segment the application has made available (``inf`` while the source is on)."""
        self.cwnd = float(config.initial_window)
        self.ssthresh = float(config.window)
        self.dupacks = 0
        self.recover = -1
        self.in_recovery = False
        self._first_partial = False
        # RTT estimation.
        self._rtt_active = False
        self._rtt_seq = -1
        self._rtt_sent = 0.0
        self.srtt: float | None = None
        self.rttvar = 0.0
        self._rtxcur = config.initial_rto
        self.backoff = 1
        self._last_send = -math.inf
        self.active = False
        host.bind(port, self)
        self._trace()

    # -- the application --------------------------------------------------------------------

    def start(self, now: float) -> None:
        """The FTP source switches on (again): unlimited data from now."""
        if self.active:
            return
        self.active = True
        cfg = self.config
        if (
            cfg.slow_start_restart
            and self.maxseq >= 0
            and self.maxseq <= self.highest_ack
            and now - self._last_send >= self.rto()
            and self.cwnd > cfg.initial_window
        ):
            self.cwnd = float(cfg.initial_window)
            self._trace()
        self.limit = 1 << 62
        self._send_much(now)

    def stop(self, now: float) -> None:
        """The source switches off: no new segments; outstanding ones are still recovered."""
        self.active = False
        self.limit = self.maxseq

    # -- sending ------------------------------------------------------------------------------

    def window(self) -> int:
        return min(int(self.cwnd), self.config.window)

    def _send_much(self, now: float) -> None:
        top = min(self.highest_ack + self.window(), self.limit)
        while self.t_seqno <= top:
            self._output(self.t_seqno, now)
            self.t_seqno += 1

    def _output(self, seq: int, now: float) -> None:
        cfg = self.config
        counters = self.counters
        size = cfg.packet_size
        if seq > self.maxseq:
            self.maxseq = seq
            if not self._rtt_active and seq > self._rtt_seq:
                self._rtt_active = True
                self._rtt_seq = seq
                self._rtt_sent = now
        else:
            counters.retransmissions += 1
        counters.segments_sent += 1
        self.recorder.on_sent(now, size)
        self._last_send = now
        self.host.send(
            Packet(
                self.host.name, self.port, self.peer[0], self.peer[1], size, seq, now, self.recorder
            ),
            now,
        )
        if not self._timer.armed:
            self._timer.set(now + self.rto())

    # -- acknowledgements -----------------------------------------------------------------------

    def receive(self, packet: Packet, now: float) -> None:
        ackno: int = packet.payload  # type: ignore[assignment]
        self.counters.acks_received += 1
        cfg = self.config
        if ackno > self.highest_ack:
            acked = ackno - self.highest_ack
            partial = False
            if self.in_recovery:
                if ackno >= self.recover or cfg.variant == "reno":
                    self.in_recovery = False
                    self.cwnd = self.ssthresh  # deflate
                else:
                    partial = True
            else:
                self._open_cwnd()
            self.dupacks = 0
            self.highest_ack = ackno
            if self.t_seqno <= ackno:
                self.t_seqno = ackno + 1
            if self._rtt_active and ackno >= self._rtt_seq:
                self._rtt_active = False
                self.backoff = 1
                self._rtt_update(now)
            if partial:
                # NewReno: the next hole was lost too; retransmit it, deflate by what was acked.
                self._output(ackno + 1, now)
                self.cwnd = max(self.cwnd - acked + 1, 1.0)
                if self._first_partial:
                    self._first_partial = False
                    self._timer.set(now + self.rto())
            elif self.maxseq <= self.highest_ack:
                self._timer.cancel()
            else:
                self._timer.set(now + self.rto())
            self._trace()
            self._send_much(now)
            return
        if ackno < self.highest_ack or self.maxseq <= self.highest_ack:
            return  # an old ACK, or nothing outstanding
        # A duplicate ACK.
        self.dupacks += 1
        if self.in_recovery:
            self.cwnd += 1.0  # inflate: one more segment has left the network
            self._trace()
            self._send_much(now)
        elif self.dupacks == cfg.dupack_threshold and self.highest_ack > self.recover:
            # ns-2's bug_fix_: no fast retransmit until everything sent before the last one (or the
            # last timeout) is acknowledged *beyond* recover. Tahoe's go-back-N resends segments still
            # in flight; their duplicates at the sink come back as duplicate ACKs at exactly recover
            # and must not trigger another window reduction.
            self._fast_retransmit(now)
        elif self.dupacks < cfg.dupack_threshold and cfg.limited_transmit:
            seq = self.t_seqno
            if (
                seq <= self.limit
                and seq <= self.highest_ack + cfg.window
                and seq <= self.highest_ack + int(self.cwnd) + self.dupacks
            ):
                self._output(seq, now)
                self.t_seqno = seq + 1

    def _fast_retransmit(self, now: float) -> None:
        cfg = self.config
        self.counters.fast_retransmits += 1
        self.recover = self.maxseq
        self.ssthresh = float(max(self.window() // 2, 2))
        if cfg.variant == "tahoe":
            # ns-2's tahoe_action: slowdown(CLOSE_SSTHRESH_HALF | CLOSE_CWND_ONE), then
            # reset_rtx_timer(0, 0), which goes back to the first unacknowledged segment.
            self.cwnd = 1.0
            self._rtt_active = False
            self.t_seqno = self.highest_ack + 1
            self._timer.set(now + self.rto())
            self._trace()
            self._send_much(now)
            return
        self.cwnd = self.ssthresh + cfg.dupack_threshold
        self.in_recovery = True
        self._first_partial = True
        self._rtt_active = False
        self._output(self.highest_ack + 1, now)
        self._timer.set(now + self.rto())
        self._trace()
        self._send_much(now)

    def _open_cwnd(self) -> None:
        if self.cwnd < self.ssthresh:
            self.cwnd += 1.0
        else:
            self.cwnd += 1.0 / self.cwnd

    # -- timers -------------------------------------------------------------------------------

    def rto(self) -> float:
        cfg = self.config
        timeout = max(self._rtxcur, cfg.min_rto) * self.backoff
        return max(min(timeout, cfg.max_rto), 2 * cfg.tick)

    def _rtt_update(self, now: float) -> None:
        tick = self.config.tick
        ticks = max(1, math.floor(now / tick) - math.floor(self._rtt_sent / tick))
        rtt = ticks * tick
        counters = self.counters
        counters.rtt_samples += 1
        counters.rtt_sum += rtt
        if self.srtt is None:
            self.srtt = rtt
            self.rttvar = rtt / 2
        else:
            delta = rtt - self.srtt
            self.srtt += delta / 8
            self.rttvar += (abs(delta) - self.rttvar) / 4
        self._rtxcur = self.srtt + 4 * self.rttvar

    def _on_timeout(self, now: float) -> None:
        if self.maxseq <= self.highest_ack:
            return
        cfg = self.config
        self.counters.timeouts += 1
        self.ssthresh = float(max(self.window() // 2, 2))
        self.cwnd = 1.0
        self.backoff = min(self.backoff * 2, cfg.max_backoff)
        self.recover = self.maxseq
        self.in_recovery = False
        self.dupacks = 0
        self._rtt_active = False
        self.t_seqno = self.highest_ack + 1  # go back N
        self._trace()
        self._timer.set(now + self.rto())
        self._send_much(now)

    def _trace(self) -> None:
        if self.trace_cwnd:
            self.counters.cwnd_trace.append((self.sim.now, self.cwnd))

    @property
    def mean_rtt(self) -> float:
        counters = self.counters
        return counters.rtt_sum / counters.rtt_samples if counters.rtt_samples else math.nan


class TcpSink:
    """``Agent/TCPSink``: one cumulative ACK per arriving segment; out-of-order segments are kept."""

    def __init__(
        self,
        host: Node,
        port: int,
        config: TcpConfig,
        recorder: FlowRecorder,
        ack_recorder: FlowRecorder | None = None,
    ) -> None:
        self.host = host
        self.port = port
        self.config = config
        self.recorder = recorder
        self.ack_recorder = ack_recorder
        self.next_expected = 0
        self._out_of_order: set[int] = set()
        self.duplicates = 0
        host.bind(port, self)

    def receive(self, packet: Packet, now: float) -> None:
        seq: int = packet.payload  # type: ignore[assignment]
        expected = self.next_expected
        if seq == expected:
            expected += 1
            held = self._out_of_order
            while expected in held:
                held.remove(expected)
                expected += 1
            self.next_expected = expected
            self._delivered(packet, now)
        elif seq > expected and seq not in self._out_of_order:
            self._out_of_order.add(seq)
            self._delivered(packet, now)
        else:
            self.duplicates += 1
        size = self.config.ack_size
        if self.ack_recorder is not None:
            self.ack_recorder.on_sent(now, size)
        self.host.send(
            Packet(
                self.host.name,
                self.port,
                packet.src,
                packet.sport,
                size,
                self.next_expected - 1,
                now,
                self.ack_recorder,
            ),
            now,
        )

    def _delivered(self, packet: Packet, now: float) -> None:
        self.recorder.on_delivered(now, packet.sent_at, self.config.segment_size, packet.size)


class TcpFlow:
    """A bulk transfer from ``src`` to ``dst``: FTP on a TCP sender, a sink, and their recorders.

    ``periods`` are the ``(start, stop)`` intervals during which the FTP source is on.
    """

    def __init__(
        self,
        net: Network,
        src: str,
        dst: str,
        *,
        port: int,
        config: TcpConfig | None = None,
        periods: tuple[tuple[float, float], ...] = ((0.0, math.inf),),
        bin_width: float = 0.5,
        duration: float = 100.0,
        name: str = "tcp",
        trace_cwnd: bool = False,
    ) -> None:
        cfg = config if config is not None else TcpConfig()
        self.name = name
        self.config = cfg
        self.data = FlowRecorder(name, bin_width=bin_width, duration=duration)
        self.acks = FlowRecorder(f"{name} acks", bin_width=bin_width, duration=duration)
        self.sink = TcpSink(net.node(dst), port, cfg, self.data, self.acks)
        self.sender = TcpSender(
            net, net.node(src), port, (dst, port), cfg, self.data, trace_cwnd=trace_cwnd
        )
        sim = net.sim
        for start, stop in periods:
            sim.call_at(start, self._start)
            if math.isfinite(stop):
                sim.call_at(stop, self._stop)
        self._sim = sim

    def _start(self) -> None:
        self.sender.start(self._sim.now)

    def _stop(self) -> None:
        self.sender.stop(self._sim.now)
