"""How many concurrent 1 kHz bidirectional sessions does one tdtp slave process serve on uvloop?

Usage: ``python benchmarks/scale.py [--seconds 2] [--repeat 2] [--ramp 2,5,10,15,20,30,50,100]
[--controller trinomial|tfrc|fixed] [--workers 1,2] [--pure] [--serve callback|task] [--spin S]
[--slave tdtp,raw-uvloop,c] [--json]``

Method. Two processes on loopback, each pinned to its own CPU (on 2 cores the slave has one to itself):

- the **slave**: ``tdtp.listen`` on uvloop, default connection config (trinomial flow control,
  piggybacked ACKs). Each accepted master is served as an application would: an ``on_data`` callback
  takes the master's samples, and a ``tdtp.Ticker(1000)`` sends one 100-byte sample per tick with
  ``ep.send`` (without ``start=``, so every session's ticker joins the loop's 1 kHz tick group: one
  wake-up per period for all of them). ``--serve callback`` (the default) gives each session a tick
  callback (``Ticker.call_each``), which the group's wake-up calls directly, one after the other;
  ``--serve task`` gives each its own task iterating ``async for index in ticker`` (as
  ``examples/slave.py``), which costs a future, a task step and an async generator step per session
  per tick (1.5-3 us of CPU per session-tick more on this VM, of the 25-35 us a session costs per
  ms: benchmarks/HISTORY.md, "Why the slave's ticks are late").
- the **masters**: N ``tdtp.connect`` endpoints in one process on uvloop; one shared 1 kHz ticker sends a
  100-byte sample to every endpoint per tick (one wake-up per period for all N, to keep the load
  generator cheap), and an ``on_data`` callback per endpoint takes the slave's samples.

Every payload carries its send time (``time.monotonic``, one system-wide clock for both processes). Once
all N sessions are up the coordinator opens the window, 0.5 s later, for every process at once: each
measures ``--seconds`` from then.

**Workers.** ``--workers W`` runs W slave processes, each with its own ``tdtp.listen(..., port,
reuse_port=True)`` on the same port (the recipe of the README's "Sessions at scale"): the kernel
spreads the masters over them by their addresses (not evenly: the table gives the split), and each
serves every master it is given. Slave i is pinned to CPU 1 + i, modulo the CPUs, the masters to CPU 0;
so on a 2-core machine ``--workers 2`` puts the second slave on the masters' core, and the figure then
measures the sharing as much as the slaves. The step's slave figures are the workers' together (late
ticks and samples received summed; CPU and tick lateness p99 the busiest worker's). ``--workers 1,2``
runs a ramp for each.

``--pure`` runs every process on tdtp's pure-Python build (``TDTP_PURE_PYTHON=1``).

``--spin S`` gives the slave's and the masters' tickers ``Ticker(spin=S)``: the tick group's timer
goes off S seconds before each deadline and the rest is waited on the CPU. Why: this VM's idle
virtual CPUs are resumed late by the host (the kernel runs ``cpuidle_haltpoll`` with
``guest_halt_poll_ns=0``: a CPU with nothing to do halts at once). A bare 1 kHz ``timerfd`` loop on
an idle machine wakes more than 1 ms late 2-7 % of the time (p99 1.8-3.9 ms), 0.3-0.5 % when the CPU
is kept from idling, so a slave whose core idles between ticks is late on that share of its ticks
whatever it does, at 10 sessions as at 50 (benchmarks/HISTORY.md, "Why the slave's ticks are late").
Under contention spinning backfires (the busy-waiting process loses its time slice), hence not the
default. The spin is CPU the
slave burns on purpose: the slave's CPU column includes it, the column beside it says how much it
was (``TickGroup.spun``, the spinning thread's CPU time, as the baselines count theirs: its wall time
would also count a neighbour's turns on the core), and the CPU per session row leaves it out (busy
CPU only).

**Late**, the figure judged: a slave sample is late when the slave's ``Ticker`` hands it to ``ep.send``
more than one period (1 ms) after its deadline, or when the ticker skipped its tick altogether (a stall
longer than 10 periods). On the batched datagram layer the samples of one wake-up leave together, with
one ``sendmmsg`` once the last session's callback (or task) has run, so the first sessions' samples
leave later than they were handed over: by the time the rest of that wake-up took. The measure is
therefore generous to the first sessions of a wake-up by at most one wake-up's work (which the last
session's lateness includes, and the S->M arrival column, stamped before ``ep.send``, sees in full). This is what the slave process controls: whether it keeps every session's 1 kHz
schedule while also taking in N x 1000 samples/s. It does not depend on the masters' process or on the
path, so a busy load generator cannot make the slave look late. A step **passes** when at most 1 % of the
slave's samples in the window are late and the load was really offered: the slave received at least 99 %
of the N x 1000 samples/s the masters were meant to send. A step whose slave kept up but received
less than that is *master-limited*: the masters' process could not offer the load, and the ramp stops
there. A step that fails while other processes on the machine used more than 20 % of a core is
*contended* (inconclusive) and run again, at most twice. The masters' own ticker lateness is reported
beside it.

Reported per step: slave late %, p99 tick lateness, slave CPU % of its core (``getrusage``), samples/s
received by the slave, for information the one-way lateness of samples at arrival (arrival - send
time > 1 ms) in each direction, and how much CPU other tenants of the machine used meanwhile (the CPU
time of every other process, from ``/proc/[pid]/stat``, over the step, % of one core): on a shared
machine a step can fail because a neighbour took the slave's core, and this column says so. The ramp
stops after the first step that does not pass; a later ramp starts from the largest step at most half
of what the one before passed. The figure is the largest N that passed, median over ``--repeat``
ramps; the row says where and why each ramp stopped, with the figures of that step.

**Baselines** (``--slave tdtp,raw-uvloop,c``; default ``tdtp`` alone). How many sessions would one
slave process serve on this machine if it were not tdtp? Each baseline slave is ramped as tdtp's is,
in the same run, interleaved with it repetition by repetition (tdtp's ramp, then each baseline's):
same steps, window, pinning (slave on CPU 1, masters on CPU 0), ``--spin``, measure of late,
verdicts and contended rule. Rows: each baseline's sessions and busy CPU per session-ms, and tdtp's
figures against each (ratios paired by ramp), beside tdtp's own rows, which are unchanged.

- ``raw-uvloop``, what a careful hand-written Python slave on uvloop would be: one
  ``DatagramProtocol`` socket; a peer's first datagram (its hello) makes it a session, whose only
  state is its address (and a count of its samples); one tick source for all sessions, a periodic
  ``timerfd`` (absolute first expiry, then every period, re-armed by the kernel: one ``read`` per
  tick) watched with ``loop.add_reader``. Not ``loop.call_at`` on an absolute schedule: on uvloop
  that is libuv's millisecond timer against a clock cached per loop iteration, whose own error is
  a large part of the 1 ms that "late" allows (benchmarks/HISTORY.md, pacing: naive ``call_at`` on
  uvloop deviates by 596 us at p99 against the ``timerfd``'s 108, and fired early in 46 % of
  periods), so the baseline would be late by its timer's rounding, not by the machine.
  Each tick due (the ``Ticker``'s catch-up rule: a stall of more than 10 periods skips to the tick
  due now, the skipped ones counted late), for each session: a clock read, the tick's lateness
  recorded as tdtp's slave records a tick callback's, and a 100-byte sample stamped with that time
  sent with ``transport.sendto`` (uvloop writes it at once: one system call per sample, where tdtp
  sends a wake-up's samples with one ``sendmmsg``; each sample is therefore on its way before the
  next session's lateness is read, a measure a little stricter than tdtp's). Its samples received
  are counted as tdtp's slave counts ``on_data``'s.
- ``c``: the same slave in C with no Python (``scale_c.py``: ``epoll``, ``recvmmsg`` in batches of
  64, the tick's samples in one ``sendmmsg``), compiled with the system's ``cc`` at run time: the
  machine's limit, what its kernel and its late wake-ups leave for any program.

A baseline slave does not speak TDTP, so its masters are **raw masters**: one uvloop UDP socket per
session, its hello repeated every 50 ms until the slave's first sample answers, then one shared 1 kHz
tick source (the same periodic ``timerfd``) sending the same 100-byte payload, stamped as tdtp's
masters stamp it, to every socket with ``sendto``. tdtp's slave keeps its tdtp masters (so its rows
measure what they did before). Both slaves are offered N x 1000 samples/s of 100 bytes each way (tdtp
adds its 5-byte header, its ACKs riding on the samples); the raw masters cost less CPU than
tdtp's, which only helps a baseline pass the "load really offered" check, never its measure of late,
which is the slave's own ticks.

Targets (issue 23, raising issue 12's 50): >= 100 sessions in one slave process, masters in another; the pure-Python build no
fewer than the whole library served before the compiled core (8, the suite's run of 2026-11-21).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import resource
import struct
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat
from scale_c import c_slave_worker, compile_slave

from tdtp import ConnectionClosedError, ConnectionConfig, DataReceived, Endpoint, Ticker, TickHandle
from tdtp.aio.api import connect, listen
from tdtp.aio.loop_timers import tick_group
from tdtp.aio.timer import monotonic
from tdtp.control.fixed import FixedConfig

TARGET_SESSIONS = 100
PURE_BEFORE = 8
"""Sessions one slave served in the suite's run of 2026-11-21, before the compiled core."""
DEFAULT_RAMP = "2,5,10,15,20,25,30,40,50,60,80,100,120,150"
CONTENDED_RETRIES = 2
"""Reruns of a step that failed while other processes used > common.CONTENDED_PERCENT of a core."""
RATE = 1000.0
PERIOD = 1.0 / RATE
LATE = PERIOD  # more than one period behind
MAX_LATE_FRACTION = 0.01
DEFAULT_SPIN = 0.0
BASELINES = {"raw-uvloop": "raw uvloop baseline", "c": "C baseline (no Python)"}
"""The baseline slaves (``--slave``), by name: their rows' label."""
MAX_CATCH_UP = 10
"""``tdtp.Ticker``'s default ``max_catch_up``: a longer stall skips ticks (counted late)."""
QUANTILES = (0.5, 0.9, 0.99, 0.999)
MIN_OFFERED_FRACTION = 0.99
WARMUP = 0.5
PAYLOAD_SIZE = 100
_STAMP = struct.Struct("!dQ")
_PADDING = bytes(PAYLOAD_SIZE - _STAMP.size)


def session_config(controller: str) -> ConnectionConfig:
    """The slave's and masters' config: the default, or another controller (``fixed`` = unpaced)."""
    if controller == "fixed":
        return ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))
    return ConnectionConfig(controller=controller)


def _raise_fd_limit() -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < hard:
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))


@dataclass
class Window:
    """The measurement window, once every session is up."""

    start: float = math.inf
    end: float = math.inf
    cpu: list[float] = field(default_factory=list)
    spun: list[float] = field(default_factory=list)
    """The slave's tick group's busy-wait (``Ticker(spin=)``) at the window's ends, seconds."""

    def covers(self, t: float) -> bool:
        return self.start <= t < self.end


@dataclass
class Arrivals:
    """Samples received in the window, and how many arrived more than one period after they left."""

    window: Window
    count: int = 0
    late: int = 0

    def on_data(self, sample: DataReceived) -> None:
        now = sample.received_at
        if self.window.covers(now):
            self.count += 1
            if now - _STAMP.unpack_from(sample.payload)[0] > LATE:
                self.late += 1

    def record(self, payload: bytes, now: float) -> None:
        """The same for a raw datagram received at ``now``."""
        if self.window.covers(now):
            self.count += 1
            if now - _STAMP.unpack_from(payload)[0] > LATE:
                self.late += 1


@dataclass
class Ticks:
    """A ticker's deadlines in the window: how many, how many late or skipped, their lateness."""

    total: int = 0
    late: int = 0
    skipped: int = 0
    lateness: list[float] = field(default_factory=list)
    late_at: list[float] = field(default_factory=list)
    """When late ticks were due, seconds into the window (the first 100)."""


class Inbox:
    """The coordinator's messages, read from the pipe without blocking the loop."""

    def __init__(self, conn: Any) -> None:
        self.conn = conn
        self.messages: Json = {}

    def poll(self) -> Json:
        while self.conn.poll():
            self.messages.update(self.conn.recv())
        return self.messages

    async def wait_for(self, key: str) -> Any:
        while key not in self.poll():
            await asyncio.sleep(0.01)
        return self.messages[key]


async def _measure(
    window: Window, inbox: Inbox, seconds: float, spun: Callable[[], float] = lambda: 0.0
) -> None:
    """The window the coordinator sets once every session is up (one for every process: the
    monotonic clock is the machine's), and this process's CPU time over it."""
    window.start = await inbox.wait_for("start")
    window.end = window.start + seconds
    await asyncio.sleep(max(0.0, window.start - monotonic()))
    window.cpu.append(common.cpu_seconds())
    window.spun.append(spun())
    await asyncio.sleep(max(0.0, window.end - monotonic()))
    window.cpu.append(common.cpu_seconds())
    window.spun.append(spun())
    await asyncio.sleep(0.05)  # let the last ticks of the window be recorded


def _payload(index: int) -> bytes:
    return _STAMP.pack(monotonic(), index) + _PADDING


def _record_tick(ticks: Ticks, window: Window, deadline: float, now: float, gap: int) -> None:
    if not window.covers(deadline):
        return
    ticks.total += 1 + gap
    ticks.skipped += gap
    ticks.late += gap
    lateness = now - deadline
    ticks.lateness.append(lateness)
    if lateness > LATE or gap:
        ticks.late += lateness > LATE
        if len(ticks.late_at) < 100:
            ticks.late_at.append(round(deadline - window.start, 4))


def _window_report(ticks: Ticks, window: Window, arrivals: Arrivals) -> Json:
    """What every process of a step reports of its window, slave or masters, tdtp or raw: its
    ticks and their lateness, its CPU (and spin), the samples it received and how late they came."""
    span = window.end - window.start
    return {
        "ticks": ticks.total,
        "late": ticks.late,
        "skipped": ticks.skipped,
        "late_fraction": ticks.late / ticks.total if ticks.total else math.nan,
        "tick_lateness_p99_us": 1e6 * common.percentile(sorted(ticks.lateness), 0.99),
        "tick_lateness_us": _quantiles_us(ticks.lateness),
        "late_at": ticks.late_at,
        "cpu_percent": 100.0 * (window.cpu[1] - window.cpu[0]) / span,
        "spin_percent": 100.0 * (window.spun[1] - window.spun[0]) / span,
        "received": arrivals.count,
        "received_rate": arrivals.count / span,
        "arrival_late": arrivals.late,
        "arrival_late_fraction": arrivals.late / arrivals.count if arrivals.count else math.nan,
    }


def _quantiles_us(values: list[float]) -> Json:
    """The lateness distribution of a step: p50, p90, p99, p99.9 and max, in us."""
    ordered = sorted(values)
    quantiles = {f"p{q * 100:g}": 1e6 * common.percentile(ordered, q) for q in QUANTILES}
    return {**quantiles, "max": 1e6 * ordered[-1] if ordered else math.nan}


# ---------------------------------------------------------------------------- slave


async def _serve(
    ep: Endpoint, window: Window, ticks: Ticks, arrivals: Arrivals, spin: float
) -> None:
    ep.set_data_callback(arrivals.on_data)
    last = -1
    ticker = Ticker(RATE, spin=spin)  # the loop's tick group for 1 kHz, one wake-up for all
    with contextlib.suppress(ConnectionClosedError):
        async for index in ticker:
            now = monotonic()
            _record_tick(ticks, window, ticker.deadline, now, max(0, index - last - 1))
            last = index
            if ep.is_closed or now > window.end + 0.2:
                return
            ep.send(_payload(index))


def _serve_each_tick(
    ep: Endpoint, window: Window, ticks: Ticks, arrivals: Arrivals, spin: float
) -> TickHandle:
    """The same session on a tick callback (``Ticker.call_each``): the loop's tick group calls it
    in its wake-up, one call per session, no task step."""
    ep.set_data_callback(arrivals.on_data)
    last = -1
    ticker = Ticker(RATE, spin=spin)

    def on_tick(index: int) -> None:
        # As lean as the raw baselines' tick (no context manager per call): what is measured is
        # the library's cost per session, not this harness's.
        nonlocal last
        now = monotonic()
        _record_tick(ticks, window, ticker.deadline, now, max(0, index - last - 1))
        last = index
        if ep.is_closed or now > window.end + 0.2:
            handle.cancel()
            return
        try:
            ep.send(_STAMP.pack(now, index) + _PADDING)
        except ConnectionClosedError:
            handle.cancel()  # the session is over: nothing more to tick for

    handle = ticker.call_each(on_tick)
    return handle


async def _slave(
    control: Any,
    sessions: int,
    seconds: float,
    controller: str,
    port: int,
    reuse_port: bool,
    serve: str = "callback",
    spin: float = 0.0,
) -> Json:
    window = Window()
    ticks = Ticks()
    arrivals = Arrivals(window)
    inbox = Inbox(control)
    config = session_config(controller)
    server = await listen(
        "127.0.0.1",
        port,
        max_peers=sessions + 8,
        backlog=sessions + 8,
        config=config,
        reuse_port=reuse_port,
    )
    control.send({"port": server.port})
    tasks: list[asyncio.Task[None]] = []
    handles: list[TickHandle] = []

    async def accept() -> None:
        # With several slave processes on the port, this one cannot know how many of the masters
        # the kernel gives it: it serves every one that comes.
        while True:
            ep = await server.accept()
            if serve == "callback":
                handles.append(_serve_each_tick(ep, window, ticks, arrivals, spin))
            else:
                tasks.append(asyncio.create_task(_serve(ep, window, ticks, arrivals, spin)))

    def spun() -> float:
        group = tick_group(asyncio.get_running_loop(), RATE, "auto", spin)
        return group.spun

    acceptor = asyncio.create_task(accept())
    await _measure(window, inbox, seconds, spun)
    stats = [ep.stats for ep in server.endpoints]
    report = {
        "sessions": len(tasks) + len(handles),
        **_window_report(ticks, window, arrivals),
        "superseded": sum(s.samples_superseded for s in stats),
        "lost": sum(s.packets_lost for s in stats),
        "ack_packets_sent": sum(s.sent.ack_packets for s in stats),
        "build": common.tdtp_build(),
    }
    control.send({"window": report})
    await inbox.wait_for("stop")
    acceptor.cancel()
    for handle in handles:
        handle.cancel()
    for task in tasks:
        task.cancel()
    await asyncio.gather(acceptor, *tasks, return_exceptions=True)
    await server.close()
    return report


def slave_worker(
    conn: Any,
    *,
    sessions: int,
    seconds: float,
    controller: str,
    cpu_slot: int,
    port: int = 0,
    reuse_port: bool = False,
    serve: str = "callback",
    spin: float = 0.0,
) -> None:
    common.pin_to_cpu(cpu_slot)
    _raise_fd_limit()
    common.run_in_loop(
        "uvloop",
        lambda: _slave(conn, sessions, seconds, controller, port, reuse_port, serve, spin),
    )
    conn.send({"final": True})


# ---------------------------------------------------------------------------- masters


async def _masters(
    control: Any, port: int, sessions: int, seconds: float, controller: str, spin: float
) -> Json:
    window = Window()
    arrivals = Arrivals(window)
    ticks = Ticks()
    inbox = Inbox(control)
    config = session_config(controller)
    endpoints = [
        await connect("127.0.0.1", port, config=config, on_data=arrivals.on_data)
        for _ in range(sessions)
    ]
    control.send({"connected": True})
    measure = asyncio.create_task(_measure(window, inbox, seconds))
    start = monotonic()
    last = -1
    async for index in Ticker(RATE, start=start, spin=spin):
        now = monotonic()
        _record_tick(ticks, window, start + index * PERIOD, now, index - last - 1)
        last = index
        payload = _payload(index)
        for ep in endpoints:
            try:
                ep.send(payload)
            except ConnectionClosedError:
                continue  # that session is over; the others go on
        if measure.done() and "stop" in inbox.poll():
            break
    report = {
        **_window_report(ticks, window, arrivals),
        "build": common.tdtp_build(),
    }
    for ep in endpoints:
        await ep.close()
    return report


def masters_worker(
    conn: Any,
    *,
    port: int,
    sessions: int,
    seconds: float,
    controller: str,
    cpu_slot: int,
    spin: float = 0.0,
) -> None:
    common.pin_to_cpu(cpu_slot)
    _raise_fd_limit()
    report = common.run_in_loop(
        "uvloop", lambda: _masters(conn, port, sessions, seconds, controller, spin)
    )
    conn.send({"final": report})


# ---------------------------------------------------------------------------- raw uvloop baseline


class RawSchedule:
    """The 1 kHz schedule of the raw baseline, with the Ticker's catch-up rule: deadlines
    ``anchor + k * PERIOD``; a wake-up serves every tick due by then, one after the other, unless it
    is more than ``MAX_CATCH_UP`` periods behind, in which case it skips to the tick due now and
    counts the ticks jumped over (``gap``), as ``tdtp.Ticker`` does (its ``max_catch_up``)."""

    def __init__(self, anchor: float, first_tick: int = 0) -> None:
        self.anchor = anchor
        self.next_tick = first_tick

    def deadline(self, tick: int) -> float:
        return self.anchor + tick * PERIOD

    def due(self, now: float) -> list[tuple[int, float, int]]:
        """The ticks to serve at ``now``, in order: (tick, its deadline, ticks skipped before it)."""
        served: list[tuple[int, float, int]] = []
        while True:
            tick = self.next_tick
            deadline = self.deadline(tick)
            if deadline > now:
                return served
            gap = 0
            behind = int((now - deadline) * RATE)
            if behind > MAX_CATCH_UP:
                gap = behind
                tick += behind
                deadline = self.deadline(tick)
            served.append((tick, deadline, gap))
            self.next_tick = tick + 1


class PeriodicTimerfd:
    """A periodic ``timerfd`` on ``CLOCK_MONOTONIC``: first expiry at an absolute time, then every
    period, re-armed by the kernel (no system call per tick but the ``read`` that clears it).
    Through ``ctypes`` on libc (``os.timerfd_create`` is Python 3.13+)."""

    def __init__(self, first: float, period: float) -> None:
        import ctypes  # noqa: PLC0415 - only this baseline needs it

        class Timespec(ctypes.Structure):
            _fields_ = (("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long))

        class Itimerspec(ctypes.Structure):
            _fields_ = (("it_interval", Timespec), ("it_value", Timespec))

        def spec(seconds: float) -> Timespec:
            ns = max(1, round(seconds * 1e9))
            return Timespec(ns // 1_000_000_000, ns % 1_000_000_000)

        libc = ctypes.CDLL(None, use_errno=True)
        fd = libc.timerfd_create(1, os.O_NONBLOCK | os.O_CLOEXEC)  # CLOCK_MONOTONIC
        if fd < 0:
            raise OSError(ctypes.get_errno(), "timerfd_create")
        self.fd: int = fd
        value = Itimerspec(spec(period), spec(first))
        if libc.timerfd_settime(fd, 1, ctypes.byref(value), None) != 0:  # TFD_TIMER_ABSTIME
            error = ctypes.get_errno()
            os.close(fd)
            raise OSError(error, "timerfd_settime")

    def clear(self) -> None:
        """Read the expiration count (what makes the descriptor unreadable again)."""
        with contextlib.suppress(BlockingIOError):
            os.read(self.fd, 8)

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


class RawTicker:
    """One 1 kHz tick source for a raw process: a :class:`PeriodicTimerfd` watched with
    ``loop.add_reader``, the :class:`RawSchedule`, and ``spin`` as ``Ticker(spin=)`` does it (the
    timer goes off ``spin`` before each deadline, the rest is waited on the CPU, counted in
    :attr:`spun`). ``on_tick(tick, deadline, gap)`` is called for every tick served."""

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        anchor: float,
        spin: float,
        on_tick: Callable[[int, float, int], None],
    ) -> None:
        now = monotonic()
        first = max(0, math.ceil((now + spin - anchor) * RATE))
        self.schedule = RawSchedule(anchor, first)
        self.spin = spin
        self.spun = 0.0
        self._loop = loop
        self._on_tick = on_tick
        self._timer = PeriodicTimerfd(self.schedule.deadline(first) - spin, PERIOD)
        loop.add_reader(self._timer.fd, self._fire)

    def _fire(self) -> None:
        self._timer.clear()
        now = monotonic()
        while True:
            due_at = self.schedule.deadline(self.schedule.next_tick)
            if due_at - now > self.spin:
                return  # the next expiry serves it
            if due_at > now:
                # Within ``spin`` of the next deadline, from this expiry or because serving the
                # last tick took until then (a late wake-up): wait for it here. The periodic
                # timer's next expiry is ``spin`` before the deadline after it, so a late
                # wake-up that returned now would leave every later tick ``period - spin`` late.
                spent = time.thread_time()  # CPU time, as TickGroup.spun counts it
                while now < due_at:
                    now = monotonic()
                self.spun += time.thread_time() - spent
            for tick, deadline, gap in self.schedule.due(now):
                self._on_tick(tick, deadline, gap)
            now = monotonic()

    def close(self) -> None:
        if self._timer.fd >= 0:
            self._loop.remove_reader(self._timer.fd)
            self._timer.close()


class RawSlaveProtocol(asyncio.DatagramProtocol):
    """The raw baseline's slave socket: a peer's first datagram makes it a session (its address is
    all the state a session has, with a count of what it sent); every datagram is counted as the
    tdtp slave counts its ``on_data`` samples."""

    def __init__(self, arrivals: Arrivals) -> None:
        self.arrivals = arrivals
        self.sessions: dict[Any, int] = {}

    def datagram_received(self, data: bytes, addr: Any) -> None:
        sessions = self.sessions
        count = sessions.get(addr)
        if count is None:
            sessions[addr] = 0  # the hello: a new session, served from the next tick
            return
        sessions[addr] = count + 1
        self.arrivals.record(data, monotonic())


async def _raw_slave(control: Any, seconds: float, spin: float) -> Json:
    loop = asyncio.get_running_loop()
    window = Window()
    ticks = Ticks()
    arrivals = Arrivals(window)
    inbox = Inbox(control)
    transport, protocol = await loop.create_datagram_endpoint(
        lambda: RawSlaveProtocol(arrivals), local_addr=("127.0.0.1", 0)
    )
    control.send({"port": transport.get_extra_info("sockname")[1]})
    sessions = protocol.sessions
    sendto = transport.sendto
    clock = monotonic
    pack = _STAMP.pack
    padding = _PADDING

    def on_tick(tick: int, deadline: float, gap: int) -> None:
        # One sample per session per tick, each handed to the kernel at once (uvloop's sendto
        # tries the socket first), its lateness measured as the tdtp slave measures each
        # session's tick callback.
        for addr in sessions:
            now = clock()
            _record_tick(ticks, window, deadline, now, gap)
            sendto(pack(now, tick) + padding, addr)
        if clock() > window.end + 0.2:
            ticker.close()

    ticker = RawTicker(loop, monotonic(), spin, on_tick)
    await _measure(window, inbox, seconds, lambda: ticker.spun)
    report = {
        "sessions": len(sessions),
        **_window_report(ticks, window, arrivals),
        "build": "raw-uvloop",
    }
    control.send({"window": report})
    await inbox.wait_for("stop")
    ticker.close()
    transport.close()
    return report


def raw_slave_worker(conn: Any, *, seconds: float, cpu_slot: int, spin: float = 0.0) -> None:
    common.pin_to_cpu(cpu_slot)
    common.run_in_loop("uvloop", lambda: _raw_slave(conn, seconds, spin))
    conn.send({"final": True})


class RawMasterProtocol(asyncio.DatagramProtocol):
    """One raw master's socket: counts the slave's samples (and notes the first, the answer to
    its hello)."""

    def __init__(self, arrivals: Arrivals) -> None:
        self.arrivals = arrivals
        self.answered = False

    def datagram_received(self, data: bytes, addr: Any) -> None:
        self.answered = True
        self.arrivals.record(data, monotonic())


async def _raw_masters(control: Any, port: int, sessions: int, seconds: float, spin: float) -> Json:
    loop = asyncio.get_running_loop()
    window = Window()
    arrivals = Arrivals(window)
    ticks = Ticks()
    inbox = Inbox(control)
    ends: list[tuple[asyncio.DatagramTransport, RawMasterProtocol]] = [
        await loop.create_datagram_endpoint(
            lambda: RawMasterProtocol(arrivals), remote_addr=("127.0.0.1", port)
        )
        for _ in range(sessions)
    ]
    # The hello: a datagram that makes the master a session of the slave, sent again until the
    # slave's first sample answers it.
    give_up = monotonic() + 30.0
    while waiting := [t for t, p in ends if not p.answered]:
        if monotonic() > give_up:
            raise RuntimeError(f"{len(waiting)} raw masters got no answer from the slave")
        for transport in waiting:
            transport.sendto(_payload(0))
        await asyncio.sleep(0.05)
    control.send({"connected": True})
    transports = [t for t, _ in ends]

    def on_tick(tick: int, deadline: float, gap: int) -> None:
        _record_tick(ticks, window, deadline, monotonic(), gap)
        payload = _payload(tick)
        for transport in transports:
            transport.sendto(payload)

    ticker = RawTicker(loop, monotonic(), spin, on_tick)
    await _measure(window, inbox, seconds)
    await inbox.wait_for("stop")
    ticker.close()
    report = {
        **_window_report(ticks, window, arrivals),
        "build": "raw-uvloop",
    }
    for transport in transports:
        transport.close()
    return report


def raw_masters_worker(
    conn: Any, *, port: int, sessions: int, seconds: float, cpu_slot: int, spin: float = 0.0
) -> None:
    common.pin_to_cpu(cpu_slot)
    _raise_fd_limit()
    report = common.run_in_loop("uvloop", lambda: _raw_masters(conn, port, sessions, seconds, spin))
    conn.send({"final": report})


# ---------------------------------------------------------------------------- coordinator


def _combine(slaves: list[Json]) -> Json:
    """One slave report for the step from every worker's: counts summed, CPU and lateness p99 the
    worst worker's (each has its own core, or shares one: the worst is the one that limits)."""
    if len(slaves) == 1:
        return {**slaves[0], "workers": [slaves[0]]}
    ticks = sum(s["ticks"] for s in slaves)
    late = sum(s["late"] for s in slaves)
    received = sum(s["received"] for s in slaves)
    arrival_late = sum(s["arrival_late"] for s in slaves)
    return {
        "sessions": sum(s["sessions"] for s in slaves),
        "ticks": ticks,
        "late": late,
        "skipped": sum(s["skipped"] for s in slaves),
        "late_fraction": late / ticks if ticks else math.nan,
        "tick_lateness_p99_us": max(
            (s["tick_lateness_p99_us"] for s in slaves if s["ticks"]), default=math.nan
        ),
        "cpu_percent": max(s["cpu_percent"] for s in slaves),
        "spin_percent": max(slaves, key=lambda s: s["cpu_percent"])["spin_percent"],
        "received": received,
        "received_rate": sum(s["received_rate"] for s in slaves),
        "arrival_late": arrival_late,
        "arrival_late_fraction": arrival_late / received if received else math.nan,
        "build": slaves[0]["build"],
        "workers": slaves,
    }


def run_step(
    sessions: int,
    seconds: float,
    controller: str = "trinomial",
    workers: int = 1,
    pure: bool = False,
    serve: str = "callback",
    spin: float = 0.0,
    program: str = "tdtp",
    binary: str = "",
) -> Json:
    """One step: ``workers`` slave processes on one port (``SO_REUSEPORT`` when more than one),
    ``sessions`` masters in another process, and the verdict. ``program="raw-uvloop"`` or ``"c"``: that
    baseline's slave (one process; ``binary``: the C slave's) and the raw masters instead."""
    others = common.OthersMeter()
    kind = dict(sessions=sessions, seconds=seconds, controller=controller, spin=spin)
    slaves: list[common.WorkerHandle] = []
    masters = None
    try:
        port = 0
        if program != "tdtp":
            if workers != 1:
                raise ValueError("a baseline runs one slave process")
            if program == "c":
                slaves.append(
                    common.start_worker(
                        f"c-slave-{sessions}",
                        c_slave_worker,
                        binary=binary,
                        cpu_slot=1,
                        seconds=seconds,
                        spin=spin,
                        rate=RATE,
                        late=LATE,
                        max_catch_up=MAX_CATCH_UP,
                        payload=PAYLOAD_SIZE,
                    )
                )
            else:
                slaves.append(
                    common.start_worker(
                        f"raw-slave-{sessions}",
                        raw_slave_worker,
                        cpu_slot=1,
                        seconds=seconds,
                        spin=spin,
                    )
                )
            port = slaves[-1].recv(30)["port"]
            masters = common.start_worker(
                f"raw-masters-{sessions}",
                raw_masters_worker,
                port=port,
                cpu_slot=0,
                sessions=sessions,
                seconds=seconds,
                spin=spin,
            )
        for i in range(workers if program == "tdtp" else 0):
            slaves.append(
                common.start_worker(
                    f"slave-{sessions}-{i}",
                    slave_worker,
                    pure=pure,
                    cpu_slot=1 + i,
                    port=port,
                    reuse_port=workers > 1,
                    serve=serve,
                    **kind,
                )
            )
            port = slaves[-1].recv(30)["port"]
        if masters is None:
            masters = common.start_worker(
                f"masters-{sessions}", masters_worker, pure=pure, port=port, cpu_slot=0, **kind
            )
        masters.recv(60 + sessions)  # every master connected
        start = {"start": monotonic() + WARMUP}
        for handle in (*slaves, masters):
            handle.send(start)
        reports = [slave.recv(60 + 2 * seconds)["window"] for slave in slaves]
        masters.send({"stop": True})
        m = masters.recv(60)["final"]
        for slave in slaves:
            slave.send({"stop": True})
        for slave in slaves:
            slave.recv(30)
    finally:
        for slave in slaves:
            slave.finish()
        if masters is not None:
            masters.finish()
    s = _combine(reports)
    s["others_percent"] = others.percent()  # the whole step, start-up included
    builds = {r["build"] for r in reports} | {m["build"]}
    if program == "tdtp" and builds != {"pure" if pure else common.tdtp_build()}:
        raise RuntimeError(f"step of {sessions}: the workers ran the {builds} builds")
    offered = sessions * RATE
    slave_ok = s["late_fraction"] <= MAX_LATE_FRACTION
    load_ok = s["received_rate"] >= MIN_OFFERED_FRACTION * offered
    if slave_ok and load_ok:
        verdict = "pass"
    elif slave_ok:
        verdict = "master-limited"  # the slave kept up, but the masters did not offer the load
    else:
        verdict = "fail"  # the slave's own ticks were late, whatever the masters did
    return {"sessions": sessions, "verdict": verdict, "program": program, "slave": s, "masters": m}


@dataclass(frozen=True)
class Setup:
    """What a ramp measures: how many slave processes share the port, which build of tdtp."""

    workers: int = 1
    pure: bool = False
    serve: str = "callback"
    spin: float = 0.0
    program: str = "tdtp"
    """``tdtp``, or a baseline's slave: ``raw-uvloop`` or ``c``."""
    binary: str = ""
    """The C slave's program (``c``)."""

    @property
    def label(self) -> str:
        if self.program != "tdtp":
            return (
                f"{BASELINES[self.program]}: 1 kHz bidirectional sessions one slave process serves"
            )
        build = "pure-Python build: " if self.pure else ""
        if self.workers == 1:
            return f"{build}1 kHz bidirectional sessions one slave process serves"
        return (
            f"{build}1 kHz bidirectional sessions {self.workers} slave processes serve on one "
            "port (SO_REUSEPORT)"
        )


def ramp(
    steps: list[int], seconds: float, rep: int, repeat: int, controller: str, setup: Setup
) -> list[Json]:
    results = []
    for n in steps:
        for attempt in range(1 + CONTENDED_RETRIES):
            print(
                f"ramp {rep + 1}/{repeat}, {setup.program}, workers {setup.workers}"
                f"{', pure' if setup.pure else ''}: {n} sessions ...",
                file=sys.stderr,
                flush=True,
            )
            step = run_step(
                n,
                seconds,
                controller,
                setup.workers,
                setup.pure,
                setup.serve,
                setup.spin,
                setup.program,
                setup.binary,
            )
            step["attempt"] = attempt + 1
            others = step["slave"]["others_percent"]
            print(
                f"  {step['verdict']}: slave late {step['slave']['late_fraction']:.2%}, "
                f"CPU {step['slave']['cpu_percent']:.0f} % (spin "
                f"{step['slave']['spin_percent']:.0f} %), other tenants {others:.0f} %",
                file=sys.stderr,
            )
            if step["verdict"] == "pass" or not others > common.CONTENDED_PERCENT:
                break
            step["verdict"] = "contended"  # a neighbour took a core: inconclusive, try again
        results.append(step)
        if step["verdict"] != "pass":
            break
    return results


def next_steps(steps: list[int], previous: list[Json]) -> list[int]:
    """The steps of the next ramp: from the largest step at most half of what the previous ramp
    passed (the small steps pass on every ramp; running them again only costs time)."""
    best = largest_passing(previous)
    floor = [n for n in steps if n <= best // 2]
    return steps[steps.index(floor[-1]) :] if floor else steps


def largest_passing(results: list[Json]) -> int:
    passed = [r["sessions"] for r in results if r["verdict"] == "pass"]
    return max(passed) if passed else 0


def cost_per_session(results: list[Json]) -> float:
    """The busiest slave's CPU per session and 1 ms period (us) at the largest step that passed:
    CPU time, so other tenants hardly move it; NaN when no step passed."""
    passed = [r for r in results if r["verdict"] == "pass"]
    if not passed:
        return math.nan
    return step_cost(max(passed, key=lambda r: r["sessions"]))


def step_cost(step: Json) -> float:
    """The busiest slave's busy CPU (spin left out) per session and 1 ms period (us) in a step;
    NaN when the spin, counted in wall time, came to the CPU time or more (a neighbour took the
    core during the busy-waits: the busy CPU is unknown)."""
    workers = max(1, len(step["slave"]["workers"]))
    per_worker: float = step["sessions"] / workers  # the busiest has at least its share
    busy: float = step["slave"]["cpu_percent"] - step["slave"].get("spin_percent", 0.0)
    return 10.0 * busy / per_worker if busy > 0.0 else math.nan


def costs_at_common_step(mine: list[Json], theirs: list[Json]) -> tuple[float, float, int]:
    """Two slaves' busy CPU per session-ms at the largest step both passed in a pair of ramps
    (a fixed cost per wake-up weighs more per session at fewer sessions, so compare the same N),
    and that N; NaNs and 0 when they passed no step in common."""
    passed = {r["sessions"]: r for r in theirs if r["verdict"] == "pass"}
    common_steps = [r for r in mine if r["verdict"] == "pass" and r["sessions"] in passed]
    if not common_steps:
        return math.nan, math.nan, 0
    step = max(common_steps, key=lambda r: r["sessions"])
    n = step["sessions"]
    return step_cost(step), step_cost(passed[n]), n


def stop_note(ramps: list[list[Json]]) -> str:
    """Why the ramps stopped, with the figures of the step that stopped them (never a bare verdict:
    a contended step says how busy the other tenants were and how late the slave was anyway)."""
    notes = []
    for results in ramps:
        if not results or results[-1]["verdict"] == "pass":
            continue
        last = results[-1]
        s = last["slave"]
        n = last["sessions"]
        if last["verdict"] == "contended":
            notes.append(
                f"{n} contended: slave late {100 * s['late_fraction']:.1f} % while other tenants "
                f"used {s['others_percent']:.0f} % of a core"
            )
        elif last["verdict"] == "master-limited":
            notes.append(
                f"{n} master-limited: the slaves received {s['received_rate'] / (n * RATE):.1%} "
                f"of the offered load, late {100 * s['late_fraction']:.2f} %"
            )
        else:
            notes.append(
                f"{n} failed: late {100 * s['late_fraction']:.1f} % at {s['cpu_percent']:.0f} % CPU"
            )
    return "stopped at " + "; ".join(notes) if notes else "every step passed"


def baseline_rows(ramps_of: dict[Setup, list[list[Json]]], pure: bool) -> list[Row]:
    """tdtp's one-slave-process figures against each baseline's from the same run: sessions passed
    and busy CPU per session-ms, ratios paired by repetition (ramp i of tdtp against ramp i of the
    baseline, run back to back)."""
    tdtp = next((r for s, r in ramps_of.items() if s.program == "tdtp" and s.workers == 1), None)
    if tdtp is None:
        return []
    build = "pure-Python build: " if pure else ""
    rows = []
    for setup, ramps in ramps_of.items():
        if setup.program == "tdtp":
            continue
        name = BASELINES[setup.program]
        mine = [float(largest_passing(r)) for r in tdtp]
        theirs = [float(largest_passing(r)) for r in ramps]
        rows.append(
            Row(
                "scale",
                f"{build}1 kHz bidirectional sessions one slave process serves, <= 1 % late: tdtp "
                f"against the {name}",
                "sessions",
                Stat.of(mine),
                baseline=name,
                baseline_value=Stat.of(theirs),
                ratio=Stat.of(common.paired_ratios(mine, theirs)),
                ratio_label=f"x {name}",
                note="same run, same ramp, load, pinning and measure of late; ratio paired by ramp",
                digits=0,
                ratio_digits=2,
            )
        )
        pairs = [costs_at_common_step(a, b) for a, b in zip(tdtp, ramps, strict=True)]
        my_cost = [a for a, _, _ in pairs]
        their_cost = [b for _, b, _ in pairs]
        at = ", ".join(str(n) if n else "none" for _, _, n in pairs)
        rows.append(
            Row(
                "scale",
                f"{build}slave CPU per 1 kHz session: tdtp against the {name}",
                "us per ms",
                Stat.of(my_cost),
                baseline=name,
                baseline_value=Stat.of(their_cost),
                ratio=Stat.of(common.paired_ratios(my_cost, their_cost)),
                ratio_label=f"x {name}",
                note=f"busy CPU at the largest step both passed in a pair of ramps: N = {at}",
                digits=1,
                ratio_digits=2,
            )
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    p = common.parser(__doc__, seconds=2.0, repeat=2, help_seconds="measurement window per step")
    p.add_argument(
        "--ramp",
        default=DEFAULT_RAMP,
        help=f"session counts to try in order (default {DEFAULT_RAMP})",
    )
    p.add_argument(
        "--controller",
        default="trinomial",
        choices=["trinomial", "tfrc", "fixed"],
        help="flow control on both sides (default trinomial, the library default; fixed = unpaced)",
    )
    p.add_argument(
        "--workers",
        default="1",
        help="slave processes sharing the port, a ramp for each value: e.g. 1,2 (default 1)",
    )
    p.add_argument(
        "--pure",
        action="store_true",
        help="run slaves and masters on tdtp's pure-Python build (TDTP_PURE_PYTHON=1)",
    )
    p.add_argument(
        "--serve",
        default="callback",
        choices=["callback", "task"],
        help="how the slave runs each session's 1 kHz loop: a tick callback (Ticker.call_each, "
        "the default) or a task iterating a Ticker",
    )
    p.add_argument(
        "--spin",
        type=float,
        default=DEFAULT_SPIN,
        help=f"Ticker(spin=) of slave and masters, seconds before each deadline spent waiting on "
        f"the CPU (default {DEFAULT_SPIN}; 0 sleeps until the deadline)",
    )
    p.add_argument(
        "--slave",
        default="tdtp",
        help="which slaves to ramp, comma-separated, each with the same ramp in turn: tdtp (the "
        f"figure judged) and the baselines {', '.join(BASELINES)} (default tdtp)",
    )
    args = p.parse_args(argv)
    if not 0.0 <= args.spin <= PERIOD:
        p.error(f"--spin takes 0 to {PERIOD} s, got {args.spin}")
    workers = common.as_list(args.workers)
    if not workers or min(workers) < 1:
        p.error(f"--workers takes counts of 1 or more, got {args.workers!r}")
    programs = common.as_list(args.slave, str)
    unknown = sorted(set(programs) - {"tdtp", *BASELINES})
    if not programs or unknown:
        p.error(f"--slave takes tdtp and {', '.join(BASELINES)}, got {args.slave!r}")
    common.warn_if_loaded()
    if not common.have_uvloop():
        print("uvloop is not installed: this benchmark measures the slave on uvloop; skipped")
        return common.emit("scale", args, [], details={"skipped": "uvloop missing"})
    steps = common.as_list(args.ramp)
    setups = [Setup(count, args.pure, args.serve, args.spin) for count in workers]
    setups = setups if "tdtp" in programs else []
    with tempfile.TemporaryDirectory(prefix="tdtp-scale-") as tmp:
        binary = compile_slave(Path(tmp)) if "c" in programs else None
        if "c" in programs and binary is None:
            print("no C compiler: no C baseline", file=sys.stderr)
        setups += [
            Setup(spin=args.spin, program=b, binary=str(binary) if b == "c" else "")
            for b in BASELINES
            if b in programs and (b != "c" or binary is not None)
        ]
        # Ramps interleaved, repetition by repetition (tdtp's, then each baseline's), so that a
        # ratio pairs ramps run minutes apart, not a whole script apart.
        ramps_of: dict[Setup, list[list[Json]]] = {setup: [] for setup in setups}
        for rep in range(args.repeat):
            for setup in setups:
                ramps = ramps_of[setup]
                ramp_steps = next_steps(steps, ramps[-1]) if ramps else steps
                ramps.append(
                    ramp(ramp_steps, args.seconds, rep, args.repeat, args.controller, setup)
                )
    rows_of: dict[Setup, list[Row]] = {setup: [] for setup in setups}
    lines = [
        "Slave columns: all slave processes together (late %, rx), the busiest one (CPU %, tick "
        "lateness p99); sessions per worker as the kernel spread them.",
        "",
        "| slave | workers | ramp | N | verdict (attempt) | sessions per worker | slave late % "
        "| slave tick lateness p99 (us) | slave CPU % (spin) | slave rx (samples/s) "
        "| M->S arrivals > 1 ms | S->M arrivals > 1 ms | masters late % | masters CPU % "
        "| other tenants CPU % |",
        "| --- | ---: | ---: | ---: | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: "
        "| ---: | ---: |",
    ]
    details: Json = {
        "controller": args.controller,
        "pure": args.pure,
        "serve": args.serve,
        "spin": args.spin,
        "setups": [],
    }
    for setup, ramps in ramps_of.items():
        rows = rows_of[setup]
        count = setup.workers
        best = [largest_passing(r) for r in ramps]
        value = Stat.of([float(b) for b in best])
        if setup.program != "tdtp":
            target, meets = "", None
        elif args.pure:
            target, meets = (
                f">= {PURE_BEFORE} (before the compiled core)",
                value.median >= PURE_BEFORE,
            )
        elif count == 1:
            target, meets = f">= {TARGET_SESSIONS}", value.median >= TARGET_SESSIONS
        else:
            target, meets = "", None
        shared = count + 1 > len(common.usable_cpus())
        how = {
            "tdtp": f"{args.controller}, {args.serve}s",
            "raw-uvloop": "periodic timerfd, sendto per sample",
            "c": "periodic timerfd, epoll, recvmmsg/sendmmsg",
        }[setup.program]
        rows.append(
            Row(
                "scale",
                f"{setup.label}, <= 1 % late",
                "sessions",
                value,
                target=target,
                meets=meets,
                note=f"{how}, spin {1e6 * args.spin:.0f} us, ramp {args.ramp}"
                + (", masters share a core with a slave" if count > 1 and shared else "")
                + f"; {stop_note(ramps)}",
                digits=0,
            )
        )
        costs = [cost_per_session(r) for r in ramps]
        cost = Stat.of(costs)
        if count == 1 and cost.n:
            prefix = (
                setup.label.split(":")[0] + ": " if args.pure or setup.program != "tdtp" else ""
            )
            rows.append(
                Row(
                    "scale",
                    f"{prefix}slave CPU per 1 kHz session, at the largest step that passed",
                    "us per ms",
                    cost,
                    note=f"busy CPU (spin excluded); one core at this cost: about "
                    f"{1000 / cost.median:.0f} sessions",
                    digits=1,
                )
            )
        details["setups"].append(
            {
                "slave": setup.program,
                "workers": count,
                "ramps": ramps,
                "largest_passing": best,
                "cost_us_per_session_ms": costs,
                "shared_core": shared,
            }
        )
        for i, results in enumerate(ramps):
            for r in results:
                s, m = r["slave"], r["masters"]
                spread = "/".join(str(w["sessions"]) for w in s["workers"])
                lines.append(
                    f"| {setup.program} | {count} | {i + 1} | {r['sessions']} "
                    f"| {r['verdict']} ({r.get('attempt', 1)}) "
                    f"| {spread} | {100 * s['late_fraction']:.2f} "
                    f"| {s['tick_lateness_p99_us']:.0f} | {s['cpu_percent']:.0f} "
                    f"({s.get('spin_percent', 0.0):.0f}) "
                    f"| {s['received_rate']:,.0f} | {100 * s['arrival_late_fraction']:.2f} % "
                    f"| {100 * m['arrival_late_fraction']:.2f} % | {100 * m['late_fraction']:.2f} "
                    f"| {m['cpu_percent']:.0f} | {s['others_percent']:.0f} |"
                )
    # Each baseline's rows and the comparisons beside tdtp's one-process rows, the other
    # tdtp setups after them.
    first, *others = setups or [Setup()]
    rows = rows_of.get(first, []) + [r for s in others if s.program != "tdtp" for r in rows_of[s]]
    rows += baseline_rows(ramps_of, args.pure)
    rows += [r for s in others if s.program == "tdtp" for r in rows_of[s]]
    return common.emit("scale", args, rows, details=details, text="\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
