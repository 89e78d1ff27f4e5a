"""A multipath session's paths: the table, their validation, the receive side's copies, and where
each datagram leaves (docs/PROTOCOL.md 5.11).

:class:`Multipath` is the one object a :class:`~tdtp.session.connection.Connection` talks to once a
session opened with the MULTIPATH flag is established. The seam is narrow:

* ``admits(data, addr)``: whether a datagram from another address than the first path's came on one
  of the other paths (``rx_local`` names the local socket, set by a driver with several), or is the
  challenge that opens a new one; otherwise the connection drops it (``wrong_address``);
* ``intercept(data, addr, ptype, now)``: which path it came on; takes the multipath control packets
  (MP_CHALLENGE, MP_RESPONSE, MP_REPORT, MP_ABANDON) and drops a copy of a sample already taken in,
  as ``duplicate``, before the packet protection sees it (a sample counts as taken in once the
  connection's receive window holds it, which the next datagram or flush checks: a forged datagram
  never shadows a real sample);
* ``route(out, now)``: the connection's datagrams for the peer spread over the paths (a sample on
  the paths the scheduler names, the rest on the best path), with the paths' own control packets;
  what leaves through another local socket than the session's own goes to :attr:`routed`;
* ``deadline()`` and ``on_timer(now)``: probes, reports, path failures, the paths' controllers,
  reached through the session's controller (``MultipathController``, which replaces the single-path
  one): the connection's timer needs no hook of its own.

Everything a peer can grow is bounded: ``max_paths`` paths (the session's first included), new paths
at ``new_paths_per_second``, four outstanding tokens per path, fixed rings for copies; a learned path
gets no more than three times the bytes that arrived on it until it is validated.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Protocol

from tdtp.admission.rate_limit import TokenBucket
from tdtp.config import ConnectionConfig, MultipathConfig, Role
from tdtp.control.base import RateController
from tdtp.control.registry import create_controller
from tdtp.errors import InvalidArgumentError
from tdtp.protection.packet_protection import PacketOpener
from tdtp.protection.replay_window import WideReplayWindow
from tdtp.session.ack_scheduler import AckScheduler
from tdtp.session.event_queue import EventQueue
from tdtp.session.events import Address, PathChanged
from tdtp.session.handshake import Handshake
from tdtp.session.multipath.congestion import Bottlenecks, MultipathController, PathPacer
from tdtp.session.multipath.copies import CopyFilter, SentRing
from tdtp.session.multipath.path import (
    ACTIVE,
    CLOSED,
    DEGRADED,
    FAILED,
    PROBING,
    Path,
    PathStats,
)
from tdtp.session.multipath.scheduler import Scheduler, rank
from tdtp.session.one_way import PeerClock
from tdtp.session.outbox import Outbox
from tdtp.session.recovery import LossRecovery
from tdtp.session.sender import SampleSender
from tdtp.session.stats import ConnectionStats, DropReason
from tdtp.session.timer_hint import TimerHint
from tdtp.wire.control import (
    MP_LAG_MAX,
    MP_LAG_UNIT,
    MP_PROBE_PREFIX_SIZE,
    MP_TOKEN_SIZE,
    MULTIPATH_CODES,
    NO_MP_TOKEN,
    PROBE_CODES,
    STAMP_MODULUS,
    CloseReason,
    ControlCode,
    MpAbandonBody,
    MpChallengeBody,
    MpReportBody,
    MpResponseBody,
    decode_control,
    encode_mp_abandon,
    encode_mp_challenge,
    encode_mp_report,
    encode_mp_response,
)
from tdtp.wire.errors import MalformedPacketError
from tdtp.wire.header import HEADER_SIZE, PacketType, encode_header
from tdtp.wire.hold import HOLD_NO_ACK, decode_hold, encode_hold
from tdtp.wire.protected import PROTECTION_OVERHEAD
from tdtp.wire.seqnum import expand_seq

_DATA: Final = int(PacketType.DATA)
_ACK: Final = int(PacketType.ACK)
_CONTROL: Final = int(PacketType.CONTROL)
_CHALLENGE: Final = int(ControlCode.MP_CHALLENGE)
_MESSAGE: Final = int(ControlCode.MESSAGE)
_CLOSE: Final = int(ControlCode.CLOSE)
_SESSION_CODES: Final = frozenset(
    int(code)
    for code in (
        ControlCode.KEEPALIVE,
        ControlCode.CLOSE,
        ControlCode.MESSAGE,
        ControlCode.MESSAGE_ACK,
    )
)
"""Session control the router may put on any path (the handshake's answers go where they were
addressed)."""
REPLAY_WIDTH: Final = 4096
"""A keyed multipath session's replay window, in packet numbers: seconds of one path's datagrams
behind another's at a kilohertz."""
MASTER_IDS: Final = range(1, 128)
"""Path ids a master gives the paths it opens (0 is the path the session opened on)."""
SLAVE_IDS: Final = range(128, 256)
"""Path ids a slave gives the paths it opens."""
STALE_BEHIND: Final = 64
"""A sample this far behind the newest is older than the receive window (PROTOCOL.md 3.1)."""
DEGRADED_DWELL: Final = 0.5
"""A path stays degraded (or not) at least this long before it changes back: no flapping events."""


class Session(Protocol):
    """What :meth:`Multipath.attach` takes from the connection it serves (its pieces)."""

    config: ConnectionConfig
    role: Role
    _peer: Address | None
    _handshake: Handshake
    _stats: ConnectionStats
    _outbox: Outbox
    _recovery: LossRecovery
    _acks: AckScheduler
    _events: EventQueue
    _hint: TimerHint
    _opener: PacketOpener | None
    _controller: RateController
    _sender: SampleSender

    def _accept(self, size: int, payload_size: int, now: float) -> None: ...

    def _heard(self, now: float) -> None: ...


@dataclass(slots=True)
class MultipathStats:
    """What a multipath session counted over all its paths."""

    duplicates: int = 0
    """Copies of the peer's samples dropped because an earlier copy had been taken in."""
    copies_sent: int = 0
    """DATA datagrams sent beyond one per sample (the redundancy)."""
    copy_bytes: int = 0
    """Their bytes (TDTP datagram bytes, as ``stats.sent.bytes``, which counts one per sample)."""
    paths_opened: int = 0
    paths_learned: int = 0
    """Paths the peer opened and this side took."""
    paths_validated: int = 0
    paths_failed: int = 0
    """Times a path went silent for its timeout."""
    paths_refused: int = 0
    """New paths refused (``max_paths``, or too many too fast)."""
    paths_closed: int = 0
    single_samples: int = 0
    """Samples sent on one path only."""
    spread_samples: int = 0
    """Samples sent on several paths."""
    breaches: int = 0
    """Adaptive: times the best path broke a bound and every path took the samples."""
    bottleneck_skips: int = 0
    """Copies not sent because another congested path of the sample shares its bottleneck."""
    report_clocks_rejected: int = 0
    """Reports whose clock put our direction's delay outside the bounds a real one respects
    (forged, corrupted, or the peer's clock jumped): their delay sample was not used."""


class Multipath:
    """The session's paths and everything a multipath session does beyond a single-path one."""

    def __init__(
        self,
        config: ConnectionConfig,
        *,
        master: bool,
        peer: Address,
        nonce: bytes,
        rng: random.Random,
        stats: ConnectionStats,
        outbox: Outbox,
        recovery: LossRecovery,
        acks: AckScheduler,
        events: EventQueue,
        hint: TimerHint,
        accept: Callable[[int, int, float], None],
        heard: Callable[[float], None],
        opener: PacketOpener | None,
        now: float,
    ) -> None:
        self.config = mp = config.multipath if config.multipath is not None else MultipathConfig()
        self._initial_rtt = config.initial_rtt
        self._master = master
        self._nonce = nonce
        self._rng = rng
        self._stats = stats
        self._outbox = outbox
        self._recovery = recovery
        self._acks = acks
        self._events = events
        self._hint = hint
        self._accept = accept
        self._heard = heard
        self._opener = opener
        if opener is not None:
            # Datagrams of a slower path arrive far behind a faster one's packet numbers.
            old = opener.window
            wide = WideReplayWindow(REPLAY_WIDTH)
            for behind in range(64):
                number = old.highest - behind
                if number >= 0 and old.seen(number):
                    wide.accept(number)
            wide.highest = old.highest
            opener.window = wide
        self._peer: Address = (peer[0], peer[1])
        self._bottlenecks = Bottlenecks()
        self._report_clock = PeerClock()
        self._controller = (config.controller, config.controller_config)
        self._copies = CopyFilter()
        self._ring = SentRing()
        self.scheduler = Scheduler(mp, recovery, self._ring)
        self.stats = MultipathStats()
        self.paths: dict[int, Path] = {}
        self._by_address: dict[tuple[int, object, object], Path] = {}
        self.routed: list[tuple[bytes, Address, int]] = []
        """Datagrams for local sockets other than the session's own: (datagram, remote, local).
        A driver with several sockets sends and clears them after ``datagrams_to_send``."""
        self.rx_local = 0
        """The local socket the datagram being received came through (a driver with several sets
        it around ``receive_datagram``; 0: the session's own)."""
        self._rx: Path | None = None
        self._rx_address: Address = self._peer
        self._candidate: tuple[int, Path, float] | None = None  # a sample that may be a first copy
        self._pending: list[tuple[bytes, Path, int]] = []  # path control for the next flush
        self._new_paths = TokenBucket(mp.new_paths_per_second, float(mp.max_paths), now)
        self._retransmits_seen = stats.control_retransmits
        first = self._make(0, 0, self._peer, learned=False, validated=True, now=now)
        first.last_sent = now  # the opening just crossed it
        self._add(first)

    @classmethod
    def attach(cls, session: Session, now: float) -> Multipath:
        """The multipath state of an established session opened with the MULTIPATH flag."""
        peer = session._peer
        assert peer is not None  # established
        paths = cls(
            session.config,
            master=session.role is Role.MASTER,
            peer=peer,
            nonce=session._handshake.master_nonce,
            rng=random.SystemRandom(),
            stats=session._stats,
            outbox=session._outbox,
            recovery=session._recovery,
            acks=session._acks,
            events=session._events,
            hint=session._hint,
            accept=session._accept,
            heard=session._heard,
            opener=session._opener,
            now=now,
        )
        # The single-path controller's round trips would mix the paths (CONTROL.md 11): the
        # session's pieces that drive a controller get one that asks the paths' pacers.
        old = session._controller
        controller = MultipathController(
            paths.usable_pacers, paths.deadline, paths.on_timer, paths.failed_pacers
        )
        controller.feedback_delay = old.feedback_delay
        controller.sample_waiting = old.sample_waiting
        session._controller = controller
        session._sender._controller = controller
        session._recovery._controller = controller
        session._hint._controller = controller
        return paths

    def usable_pacers(self) -> list[PathPacer]:
        """The pacers of the paths a sample may go on now (of every validated one if none is)."""
        usable = [path.pacer for path in self.paths.values() if path.usable]
        return usable or [path.pacer for path in self.paths.values() if path.validated]

    def failed_pacers(self) -> list[PathPacer]:
        """The pacers of the validated paths nothing is heard on: each takes probe copies."""
        return [p.pacer for p in self.paths.values() if p.state is FAILED and p.validated]

    # ------------------------------------------------------------------ the application's

    def open_path(self, local: int, remote: Address, now: float) -> int:
        """Open a path from local socket ``local`` to ``remote``: it is challenged now and carries
        traffic once the peer has answered on it. Returns its id."""
        key = (local, remote[0], remote[1])
        if key in self._by_address:
            raise InvalidArgumentError(
                f"the session has a path from local socket {local} to {remote[0]}:{remote[1]} "
                "already"
            )
        if self._live_count() >= self.config.max_paths:
            raise InvalidArgumentError(
                f"the session has {self.config.max_paths} paths, its max_paths; remove one "
                "first or raise MultipathConfig.max_paths"
            )
        ids = MASTER_IDS if self._master else SLAVE_IDS
        path_id = next(i for i in ids if i not in self.paths)
        path = self._make(path_id, local, remote, learned=False, validated=False, now=now)
        self._add(path)
        self.stats.paths_opened += 1
        self._challenge(path, now)
        return path_id

    def close_path(self, path_id: int, now: float) -> None:
        """Stop using a path: the peer is told (MP_ABANDON) on it and on the best other path."""
        path = self.paths.get(path_id)
        if path is None:
            raise InvalidArgumentError(
                f"the session has no path {path_id}; its paths are {sorted(self.paths)}"
            )
        reason = int(CloseReason.PATH_CLOSED)
        body = encode_mp_abandon(self._nonce, path_id, reason)
        others = [p for p in rank(list(self.paths.values()), now) if p is not path]
        for target in [path, *others[:1]]:
            self._queue(self._seal(body, 1), target, 0)
        self._close(path, "closed by the application", now)

    def path_stats(self, now: float) -> list[PathStats]:
        self._confirm()
        return [path.snapshot(now) for path in sorted(self.paths.values(), key=_by_id)]

    def has_path(self, local: int, addr: Address) -> bool:
        return (local, addr[0], addr[1]) in self._by_address

    # ------------------------------------------------------------------ receiving

    def admits(self, data: bytes, addr: Address) -> bool:
        """A datagram from another address than the session's first path's: whether it came on
        one of the other paths, or is the challenge that opens a new one (False: the connection
        drops it as ``wrong_address``)."""
        if (self.rx_local, addr[0], addr[1]) in self._by_address:
            return True
        return (
            len(data) >= HEADER_SIZE + MP_PROBE_PREFIX_SIZE
            and data[0] >> 6 == _CONTROL
            and data[HEADER_SIZE] == _CHALLENGE
            and data[HEADER_SIZE + 1 : HEADER_SIZE + MP_PROBE_PREFIX_SIZE] == self._nonce
        )

    def intercept(self, data: bytes, addr: Address, ptype: int, now: float) -> bool:
        """True when the datagram was taken here (a multipath control packet, taken or dropped, or
        a copy of a sample already taken in, dropped as ``duplicate``). Notes which path it came
        on for the rest of its handling."""
        self._hint.value = -math.inf
        path = self._by_address.get((self.rx_local, addr[0], addr[1]))
        self._rx = path
        self._rx_address = addr
        if path is not None:
            path.bytes_in += len(data)
        if ptype == _CONTROL:
            if len(data) > HEADER_SIZE and data[HEADER_SIZE] in MULTIPATH_CODES:
                self._on_control(data, now)
                return True
            return False
        if ptype != _DATA or path is None:
            return False
        window = self._acks.window
        if window is None:
            return False
        self._confirm()
        low = ((data[0] & 0x3F) << 6) | (data[1] >> 2)
        seq = expand_seq(low, window.highest + 1)
        first_at = self._copies.first_arrival(seq) if window.has_data else None
        if first_at is None:
            if (
                window.has_data
                and window.highest - seq >= STALE_BEHIND
                and now - window.highest_arrival < window.silence_guard
            ):
                # Far behind while newer samples flow on another path: an old datagram a queue
                # held (a link coming back up), never a wrapped live flow. Dropped here, so that
                # the receive window's re-anchoring (PROTOCOL.md 3.1) never takes it for one.
                path.on_data_received(seq, False, 0.0, now)
                self._stats.count_drop(DropReason.STALE)
                if self._opener is None:
                    self._heard(now)  # unkeyed: as any stale DATA (keyed: not authenticated)
                return True
            self._candidate = (seq, path, now)
            return False
        path.on_data_received(seq, False, now - first_at, now)
        self.stats.duplicates += 1
        self._stats.count_drop(DropReason.DUPLICATE)
        if self._opener is None:
            # Unkeyed, a duplicate is a sign of life (PROTOCOL.md 5.2). Keyed, this copy never met
            # the packet protection: a replayed or forged one must not hide a silent peer.
            self._heard(now)
            self._path_heard(path, now)
        return True

    def _confirm(self) -> None:
        """The last sample that passed :meth:`intercept` as no copy: if the connection took it in
        (authenticated, in its receive window now), it is the first copy of its number."""
        candidate = self._candidate
        if candidate is None:
            return
        self._candidate = None
        seq, path, at = candidate
        window = self._acks.window
        if window is None or not window.arrived(seq):
            return  # dropped (forged, optimistic, stale): it shadows nothing
        self._copies.record(seq, path.path_id, at)
        path.on_data_received(seq, True, 0.0, at)
        self._path_heard(path, at)

    def _on_control(self, data: bytes, now: float) -> None:
        stats = self._stats
        code = data[HEADER_SIZE]
        prefix = HEADER_SIZE + (MP_PROBE_PREFIX_SIZE if code in PROBE_CODES else 1)
        size = len(data)
        opener = self._opener
        plain = data
        if opener is not None:
            if size < prefix + PROTECTION_OVERHEAD:
                stats.count_drop(DropReason.TRUNCATED)
                return
            body = opener.open(data, prefix, now)
            if body is None:
                stats.count_drop(DropReason(opener.failure))
                return
            plain = data[:prefix] + body
        try:
            decoded = decode_control(plain[HEADER_SIZE:])
        except MalformedPacketError:
            stats.count_drop(DropReason.BAD_CONTROL)
            return
        path = self._rx
        if isinstance(decoded, MpChallengeBody):
            self._on_challenge(decoded, path, size, now)
        elif isinstance(decoded, MpResponseBody):
            self._on_response(decoded, path, size, now)
        elif isinstance(decoded, MpReportBody):
            self._on_report(decoded, path, size, now)
        elif isinstance(decoded, MpAbandonBody):
            self._on_abandon(decoded, size, now)

    def _taken(self, path: Path, size: int, now: float) -> None:
        plain = size - self._outbox.overhead  # the connection's count adds the protection back
        self._accept(plain, plain - HEADER_SIZE, now)
        self._stats.received.control_packets += 1
        self._path_heard(path, now)

    def _on_challenge(
        self, body: MpChallengeBody, path: Path | None, size: int, now: float
    ) -> None:
        if body.nonce != self._nonce:
            self._stats.count_drop(DropReason.NONCE_MISMATCH)
            return
        if path is None:
            path = self._learn(body.path_id, size, now)
            if path is None:
                return
        elif body.path_id != path.path_id:
            self._stats.count_drop(DropReason.UNKNOWN_PATH)
            return
        self._taken(path, size, now)
        token = NO_MP_TOKEN if path.validated else self._new_token(path, now)
        reply = encode_mp_response(self._nonce, path.path_id, body.token, token)
        self._queue(self._seal(reply, MP_PROBE_PREFIX_SIZE), path, 0)

    def _on_response(self, body: MpResponseBody, path: Path | None, size: int, now: float) -> None:
        stats = self._stats
        if body.nonce != self._nonce:
            stats.count_drop(DropReason.NONCE_MISMATCH)
            return
        if path is None or body.path_id != path.path_id:
            stats.count_drop(DropReason.UNKNOWN_PATH)
            return
        sent_at = path.take_token(body.echo)
        if sent_at is None:
            stats.count_drop(DropReason.BAD_TOKEN)
            return
        self._taken(path, size, now)
        path.on_rtt_sample(now - sent_at, now)
        if not path.validated:
            path.validated = True
            path.ever_active = True
            self.stats.paths_validated += 1
            self._set_state(path, ACTIVE, "validated: the peer answered on it", now)
        if body.token != NO_MP_TOKEN:
            reply = encode_mp_response(self._nonce, path.path_id, body.token, NO_MP_TOKEN)
            self._queue(self._seal(reply, MP_PROBE_PREFIX_SIZE), path, 0)

    def _on_report(self, body: MpReportBody, path: Path | None, size: int, now: float) -> None:
        if body.nonce != self._nonce:
            self._stats.count_drop(DropReason.NONCE_MISMATCH)  # forged blind, or another session's
            return
        if path is None or body.path_id != path.path_id:
            self._stats.count_drop(DropReason.UNKNOWN_PATH)  # a report travels on its own path
            return
        self._taken(path, size, now)
        sent = self._recovery.sent
        highest = sent.next_seq - 1
        full: int | None = None
        sent_here = False
        send_time: float | None = None
        if highest >= sent.first_seq and body.hold != HOLD_NO_ACK:
            full = SentRing.expand(body.seq, highest)
            sent_here = bool(self._ring.paths(full) >> path.path_id & 1)
            send_time = self._ring.send_time(full)
        hold = decode_hold(body.hold)
        lag = body.lag * MP_LAG_UNIT
        got, lost, sample = path.on_report(
            full, sent_here, hold, send_time, body.received, body.first, lag, now
        )
        rtt = path.rtt
        pacer = path.pacer
        pacer.on_feedback(
            now, got, lost, sample, rtt.srtt, rtt.rttvar, path.min_rtt, path.reported_copies
        )
        clock = self._report_clock.read(body.clock)
        if sample is not None and full is not None and send_time is not None and hold is not None:
            # Our direction alone on this path: the named copy's arrival on the peer's clock less
            # its send time on ours (report_clock.py).
            delay = clock - hold - send_time
            if path.delay.take(delay, sample, path.min_rtt, now):
                copies = path.copies_through(full)
                pacer.on_one_way(now, delay, send_time, copies, hold, path.sent_data - copies)
            else:
                self.stats.report_clocks_rejected += 1
        self._judge(path, now)

    def _on_abandon(self, body: MpAbandonBody, size: int, now: float) -> None:
        stats = self._stats
        if body.nonce != self._nonce:
            stats.count_drop(DropReason.NONCE_MISMATCH)
            return
        target = self.paths.get(body.path_id)
        via = self._rx
        if target is None or via is None:
            stats.count_drop(DropReason.UNKNOWN_PATH)
            return
        self._taken(via, size, now)
        why = "the peer refused it" if body.reason == CloseReason.PATH_LIMIT else "the peer"
        self._close(target, f"abandoned by {why} (reason {body.reason})", now)
        if body.reason == CloseReason.PATH_LIMIT:
            self.stats.paths_refused += 1

    def _learn(self, path_id: int, size: int, now: float) -> Path | None:
        """A challenge from an address no path has: the peer opens a path (or moves one)."""
        stats = self._stats
        addr = self._rx_address
        theirs = path_id in (SLAVE_IDS if self._master else MASTER_IDS)
        if not theirs and (path_id != 0 or self._master):
            stats.count_drop(DropReason.UNKNOWN_PATH)  # only the peer's paths can move to us
            return None
        known = self.paths.get(path_id)
        if known is None and path_id == 0:
            stats.count_drop(DropReason.UNKNOWN_PATH)
            return None
        if not self._new_paths.take(now):
            stats.count_drop(DropReason.PATH_LIMIT)
            self.stats.paths_refused += 1
            return None
        if known is None and self._live_count() >= self.config.max_paths:
            stats.count_drop(DropReason.PATH_LIMIT)
            self.stats.paths_refused += 1
            refusal = self._make(
                path_id, self.rx_local, addr, learned=True, validated=False, now=now
            )
            refusal.bytes_in = size
            body = encode_mp_abandon(self._nonce, path_id, int(CloseReason.PATH_LIMIT))
            self._queue(self._seal(body, 1), refusal, 0)
            refusal.pacer.detach()
            return None
        if known is not None:
            # The opener's path, seen from a new address (a NAT rebinding): validated again.
            del self._by_address[(known.local, known.remote[0], known.remote[1])]
            known.local = self.rx_local
            known.remote = (addr[0], addr[1])
            known.learned = True
            known.validated = False
            known.bytes_in = size
            known.bytes_out = 0
            self._by_address[(known.local, addr[0], addr[1])] = known
            self._set_state(known, PROBING, "moved to a new address", now)
            return known
        path = self._make(path_id, self.rx_local, addr, learned=True, validated=False, now=now)
        path.bytes_in = size
        self._add(path)
        self.stats.paths_learned += 1
        return path

    # ------------------------------------------------------------------ sending

    def route(self, out: list[tuple[bytes, Address]], now: float) -> list[tuple[bytes, Address]]:
        """Spread the connection's datagrams for the peer over the paths, add the paths' own, and
        return what leaves through the session's own socket (the rest: :attr:`routed`)."""
        self._confirm()
        stats = self._stats
        retransmits = stats.control_retransmits - self._retransmits_seen
        self._retransmits_seen = stats.control_retransmits
        pending = self._pending
        if not out and not pending:
            return out
        result: list[tuple[bytes, Address]] = []
        ranked = rank(list(self.paths.values()), now)
        if pending:
            self._pending = []
            sent: list[tuple[bytes, Address]] = []
            for datagram, path, protection in pending:
                if len(datagram) > path.allowance():
                    self._stats.path_limited += 1
                    continue
                self._outbox.emit_control(sent, datagram, path.remote, now, protection, True)
                self._put(datagram, path, now, result)
        peer = self._peer
        best = ranked[0] if ranked else self.paths.get(0)
        for datagram, addr in out:
            ptype = datagram[0] >> 6
            if addr[0] != peer[0] or addr[1] != peer[1] or best is None:
                result.append((datagram, addr))
                continue
            if ptype == _DATA:
                self._send_sample(datagram, ranked, now, result)
                continue
            if ptype == _CONTROL:
                code = datagram[HEADER_SIZE] if len(datagram) > HEADER_SIZE else -1
                if code not in _SESSION_CODES:
                    result.append((datagram, addr))  # the handshake's answers: as addressed
                    continue
                if code == _CLOSE:
                    for path in ranked or [best]:
                        self._put(datagram, path, now, result)
                    continue
                if code == _MESSAGE and retransmits > 0 and len(ranked) > 1:
                    retransmits -= 1
                    self._put(datagram, ranked[1], now, result)  # sent again: another path
                    continue
            self._put(datagram, best, now, result)
        return result

    def _send_sample(
        self, datagram: bytes, ranked: list[Path], now: float, result: list[tuple[bytes, Address]]
    ) -> None:
        if not ranked:
            # No path known to work: every validated path (one may be back), else the first.
            ranked = sorted((p for p in self.paths.values() if p.validated), key=_by_id)
            if not ranked:
                ranked = sorted(self.paths.values(), key=_by_id)[:1]
        candidates = self.scheduler.candidates(ranked, now)
        chosen: list[Path] = []
        congested: list[PathPacer] = []
        for path in candidates:
            pacer = path.pacer
            if not pacer.allows(now):
                continue
            if pacer.congested():
                # At most one copy into each congested bottleneck (CONTROL.md 11).
                if any(pacer.shares_bottleneck(other, now) for other in congested):
                    self.stats.bottleneck_skips += 1
                    continue
                congested.append(pacer)
            chosen.append(path)
        for path in self.paths.values():  # silent our way in, maybe not out (CONTROL.md 11.2)
            failed = path.state is FAILED and path.validated and path not in chosen
            if failed and path.pacer.probe_due(now):
                chosen.append(path)
        if not chosen:
            # None of the scheduler's paths allows a copy now: a path that does, else the best.
            allowed = [path for path in ranked if path not in candidates and path.pacer.allows(now)]
            chosen = allowed[:1] or candidates[:1]
        seq = expand_seq(
            ((datagram[0] & 0x3F) << 6) | (datagram[1] >> 2), self._recovery.sent.next_seq - 1
        )
        size = len(datagram)
        mask = 0
        for path in chosen:
            mask |= 1 << path.path_id
            path.pacer.on_sent(size, now)
            path.on_data_sent(seq)
            self._put(datagram, path, now, result)
        self._ring.record(seq, now, mask)
        stats = self.stats
        extra = len(chosen) - 1
        if extra:
            stats.copies_sent += extra
            stats.copy_bytes += extra * size
            stats.spread_samples += 1
        else:
            stats.single_samples += 1
        stats.breaches = self.scheduler.breaches

    def _put(
        self, datagram: bytes, path: Path, now: float, result: list[tuple[bytes, Address]]
    ) -> None:
        path.on_sent(len(datagram), now)
        if path.local == 0:
            result.append((datagram, path.remote))
        else:
            self.routed.append((datagram, path.remote, path.local))

    def _queue(self, datagram: bytes, path: Path, protection: int = -1) -> None:
        """A path control datagram for the next flush (the hint says one is due)."""
        self._pending.append(
            (datagram, path, self._outbox.overhead if protection < 0 else protection)
        )
        self._hint.value = -math.inf

    def _seal(self, body: bytes, clear: int) -> bytes:
        """A multipath control datagram: header, then ``body`` (code byte first) of which the first
        ``clear`` bytes travel in the clear and the rest is sealed in a keyed session."""
        outbox = self._outbox
        header = encode_header(_CONTROL, self._recovery.sent.next_seq, 0, 0, HOLD_NO_ACK)
        return outbox.protect(header + body[:clear], body[clear:])

    def _new_token(self, path: Path, now: float) -> bytes:
        token = self._rng.randbytes(MP_TOKEN_SIZE)
        if token == NO_MP_TOKEN:
            token = b"\x01" * MP_TOKEN_SIZE
        path.new_token(token, now)
        return token

    def _challenge(self, path: Path, now: float) -> None:
        token = self._new_token(path, now)
        body = encode_mp_challenge(self._nonce, path.path_id, token)
        self._queue(self._seal(body, MP_PROBE_PREFIX_SIZE), path)

    def _report(self, path: Path, now: float) -> None:
        path.unreported = False
        path.last_report = now
        lag = int(path.rx_lag / MP_LAG_UNIT)
        body = encode_mp_report(
            MpReportBody(
                self._nonce,
                path.path_id,
                path.rx_highest & 0xFFF,
                encode_hold(now - path.rx_highest_at),
                path.received,
                path.first,
                lag if lag < MP_LAG_MAX else MP_LAG_MAX,
                int(now * 1e6) & (STAMP_MODULUS - 1),
            )
        )
        self._queue(self._seal(body, 1), path)

    # ------------------------------------------------------------------ timers

    def _timeout(self, path: Path) -> float:
        config = self.config
        rtt = path.rtt.srtt if path.rtt.has_sample else self._initial_rtt
        return max(config.path_timeout, 2.0 * config.probe_interval + 3.0 * rtt)

    def deadline(self) -> float | None:
        """When :meth:`on_timer` next has something to do."""
        config = self.config
        deadline = math.inf
        for path in self.paths.values():
            if path.validated:
                if path.state is FAILED:
                    due = path.last_challenge + config.failed_probe_interval
                else:
                    due = min(
                        max(path.last_sent, path.last_challenge) + config.probe_interval,
                        path.last_heard + self._timeout(path),
                    )
            elif path.learned:
                due = min(
                    path.last_challenge + config.failed_probe_interval,
                    path.created_at + config.validation_timeout,
                )
            else:
                due = path.last_challenge + config.failed_probe_interval
            if path.unreported:
                due = min(due, path.last_report + config.report_interval)
            pacing = path.pacer.get_timer()
            if pacing is not None and pacing < due:
                due = pacing
            if due < deadline:
                deadline = due
        return deadline if deadline < math.inf else None

    def on_timer(self, now: float) -> None:
        """Probes, reports and failures that are due (each compared with the very sum
        :meth:`deadline` gave, so that a deadline reached is always served)."""
        self._confirm()
        config = self.config
        for path in list(self.paths.values()):
            if path.validated:
                if path.state is not FAILED and now >= path.last_heard + self._timeout(path):
                    self.stats.paths_failed += 1
                    silent = now - path.last_heard
                    self._set_state(path, FAILED, f"nothing heard on it for {silent:.3f} s", now)
                if path.state is FAILED:
                    if now >= path.last_challenge + config.failed_probe_interval:
                        self._challenge(path, now)
                elif now >= max(path.last_sent, path.last_challenge) + config.probe_interval:
                    self._challenge(path, now)
            elif path.learned:
                if now >= path.created_at + config.validation_timeout:
                    self._close(path, "never validated", now)
                    continue
                if now >= path.last_challenge + config.failed_probe_interval:
                    self._challenge(path, now)
            elif now >= path.last_challenge + config.failed_probe_interval:
                self._challenge(path, now)  # ours, not answered yet: keep asking
            if path.unreported and now >= path.last_report + config.report_interval:
                self._report(path, now)
            pacing = path.pacer.get_timer()
            if pacing is not None and now >= pacing:
                path.pacer.on_timer(now)

    # ------------------------------------------------------------------ path states

    def _make(
        self,
        path_id: int,
        local: int,
        remote: Address,
        *,
        learned: bool,
        validated: bool,
        now: float,
    ) -> Path:
        name, settings = self._controller
        pacer = PathPacer(
            lambda: create_controller(name, settings),
            self.config.report_interval,
            self._bottlenecks,
        )
        return Path(
            path_id,
            local,
            remote,
            learned=learned,
            validated=validated,
            initial_rtt=self._initial_rtt,
            pacer=pacer,
            now=now,
        )

    def _add(self, path: Path) -> None:
        self.paths[path.path_id] = path
        self._by_address[(path.local, path.remote[0], path.remote[1])] = path

    def _live_count(self) -> int:
        return sum(1 for path in self.paths.values() if path.state is not CLOSED)

    def _path_heard(self, path: Path, now: float) -> None:
        path.last_heard = now
        if path.state is FAILED:
            path.recovered()
            self._set_state(path, ACTIVE, "heard again", now)

    def _judge(self, path: Path, now: float) -> None:
        """Degraded while its recent loss or one-way queueing breaks the adaptive bounds (half of
        them to recover), changing at most once per half second."""
        if not path.usable or now - path.state_since < DEGRADED_DWELL:
            return
        config = self.config
        queue = path.queue_delay / 2.0
        if path.state is ACTIVE and (path.loss > config.loss_bound or queue > config.delay_bound):
            what = f"loss {path.loss * 100:.1f} %" if path.loss > config.loss_bound else ""
            what = what or f"one-way queueing {queue * 1e3:.1f} ms"
            self._set_state(path, DEGRADED, what, now)
        elif (
            path.state is DEGRADED
            and path.loss <= config.loss_bound / 2.0
            and queue <= config.delay_bound / 2.0
        ):
            self._set_state(path, ACTIVE, "back within bounds", now)

    def _set_state(self, path: Path, state: str, detail: str, now: float) -> None:
        previous = path.state
        if previous is state:
            return
        path.state = state
        path.state_since = now
        self._events.push_watchdog(
            PathChanged(path.path_id, state, previous, path.remote, detail, now)
        )
        self._hint.value = -math.inf

    def _close(self, path: Path, detail: str, now: float) -> None:
        self.paths.pop(path.path_id, None)
        self._by_address.pop((path.local, path.remote[0], path.remote[1]), None)
        path.pacer.detach()
        self.stats.paths_closed += 1
        if path.ever_active:
            self._set_state(path, CLOSED, detail, now)
        else:
            path.state = CLOSED


def _by_id(path: Path) -> int:
    return path.path_id


__all__ = ["DEGRADED", "REPLAY_WIDTH", "Multipath", "MultipathStats"]
