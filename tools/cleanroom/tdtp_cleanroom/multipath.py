"""Multipath (section 5.11): a session's table of paths, their validation and probes, the reports
of what arrived on each, and the copies of a sample that arrive on several.

The session (connection.py) owns the wire: it reads a multipath datagram (row 6a of section 5.5),
asks this table what to do, and sends what the table says, to the address it names.
"""

from __future__ import annotations

import os
from collections import deque
from dataclasses import dataclass, field

from . import wire
from .bucket import TokenBucket
from .config import Addr, Config

INF = float("inf")
TOKENS_KEPT = 4  # a side keeps its last four tokens per path
COPY_SPAN = 2048  # copies are recognised within the last 2048 sequence numbers
STALE_DEPTH = 64  # the receive window's depth (section 3.1)
NO_TOKEN = bytes(8)
LAG_UNIT = 100e-6  # MP_REPORT's lag: units of 100 us


def peer_may_open(role: str, path_id: int) -> bool:
    """A master numbers the paths it opens 1..127, a slave 128..255 (0: the opening path)."""
    return 1 <= path_id <= 127 if role == "slave" else 128 <= path_id <= 255


@dataclass
class Path:
    path_id: int
    addr: Addr
    created_at: float
    learned: bool  # its address came from the peer's datagram: the 3x limit until validated
    validated: bool = False
    failed: bool = False
    tokens: deque[tuple[bytes, float]] = field(default_factory=lambda: deque(maxlen=TOKENS_KEPT))
    bytes_in: int = 0
    bytes_out: int = 0
    last_sent: float = -INF  # the last datagram of ours on it
    last_arrival: float = -INF
    last_challenge: float = -INF
    rtt: float | None = None  # moving average, gain 1/4 (section 5.11, Sending)
    peer_lag: float = 0.0  # the lag the peer's last report of this path gave
    peer_lag_at: float = -INF
    # what arrived on it, for its MP_REPORT
    received: int = 0
    first: int = 0
    newest: int | None = None
    newest_at: float = 0.0
    lag: float = 0.0  # moving average, gain 1/8, of every datagram counted (4.3, lag)
    unreported_since: float | None = None
    last_report: float = -INF


class Multipath:
    """One multipath session's paths, seen from one side (role: "master" or "slave")."""

    def __init__(self, cfg: Config, role: str, nonce: bytes, addr: Addr, now: float) -> None:
        self.cfg = cfg
        self.role = role
        self.nonce = nonce  # the session's (the master's)
        self.paths: dict[int, Path] = {0: Path(0, addr, now, learned=False, validated=True)}
        # created when the session becomes established: path 0's probe interval runs from then
        self.paths[0].last_arrival = now
        self.paths[0].last_sent = now
        self.new_paths = TokenBucket(cfg.new_paths_per_second, cfg.max_paths, now)
        self.taken: dict[int, float] = {}  # full sequence number -> when its first copy arrived
        self.last_token: bytes | None = None  # the last token sent (the vector runner's {token})

    # -- the table ------------------------------------------------------------------------------
    def path_at(self, addr: Addr) -> Path | None:
        for p in self.paths.values():
            if p.addr == addr:
                return p
        return None

    def usable(self) -> list[Path]:
        return [p for p in self.paths.values() if p.validated and not p.failed]

    def best(self, now: float) -> Path | None:
        """The best usable path: the lowest round trip measured (no estimate: the lowest id)."""
        paths = self.usable()
        if not paths:
            return None
        return min(paths, key=lambda p: (self.one_way(p, now), p.path_id))

    def one_way(self, path: Path, now: float) -> float:
        """Section 5.11, Sending: half the path's round trip, plus the lag the peer's last report
        gave if that came within 1 s; a path with no sample yet comes last."""
        if path.rtt is None:
            return INF
        lag = path.peer_lag if now - path.peer_lag_at <= 1.0 else 0.0
        return path.rtt / 2 + lag

    def rtt_sample(self, path: Path, sample: float) -> None:
        path.rtt = sample if path.rtt is None else path.rtt + (sample - path.rtt) / 4

    def on_report(self, path: Path, report: wire.MpReport, now: float) -> None:
        path.peer_lag, path.peer_lag_at = report.lag * LAG_UNIT, now

    def new_token(self, path: Path, now: float) -> bytes:
        token = os.urandom(8)
        path.tokens.append((token, now))
        path.last_challenge = now
        self.last_token = token
        return token

    def learn(self, path_id: int, addr: Addr, now: float) -> tuple[Path | None, str | None, bool]:
        """An MP_CHALLENGE with the session's nonce from an address no path has (section 5.11,
        "Learning a path"): (the path, None, False), or (None, a drop reason, whether to answer
        it with MP_ABANDON PATH_LIMIT: only when the table is full)."""
        moved = self.paths.get(path_id)
        if moved is None and not peer_may_open(self.role, path_id):
            return None, "unknown_path", False
        # Every challenge past the id check spends one of the rate's tokens, a refused one too;
        # the rate is checked first, silently (the endpoint vectors: "the rate before the table").
        if not self.new_paths.take(now):
            return None, "path_limit", False
        if moved is not None:  # the same path id from a new address: the path moved
            moved.addr = addr
            moved.learned = True
            moved.validated = False
            moved.bytes_in = moved.bytes_out = 0
            return moved, None, False
        if len(self.paths) >= self.cfg.max_paths:
            return None, "path_limit", True  # a full table: answered with MP_ABANDON PATH_LIMIT
        path = Path(path_id, addr, now, learned=True)
        path.last_arrival = now
        self.paths[path_id] = path
        return path, None, False

    def abandon(self, path_id: int) -> bool:
        return self.paths.pop(path_id, None) is not None

    # -- the 3x limit on a path learned from the peer, until it is validated --------------------
    def may_send(self, path: Path, size: int) -> bool:
        if path.learned and not path.validated:
            return path.bytes_out + size <= 3 * path.bytes_in
        return True

    def sent(self, path: Path, size: int, now: float) -> None:
        if path.learned and not path.validated:
            path.bytes_out += size
        path.last_sent = now

    def arrived(self, path: Path, size: int, now: float) -> None:
        if path.learned and not path.validated:
            path.bytes_in += size
        path.last_arrival = now
        path.failed = False  # any datagram that arrives on a failed path makes it active again

    # -- DATA copies (row 6a) -------------------------------------------------------------------
    def copy_drop(
        self, full: int, highest: int | None, highest_at: float, now: float
    ) -> str | None:
        """`duplicate` for a copy of a sample taken in; `stale` for one 64 or more below the
        highest while newer samples arrive (less than silence_timeout since the last)."""
        if full in self.taken:
            return "duplicate"
        if (
            highest is not None
            and full <= highest - STALE_DEPTH
            and now - highest_at < self.cfg.silence_timeout
        ):
            return "stale"
        return None

    def on_data(self, path: Path, full: int, now: float, first: bool) -> None:
        """A DATA datagram counted on this path (4.3, received): a sample's first copy taken in,
        or a copy dropped before the packet protection as `duplicate` or `stale`."""
        path.received += 1
        if first:
            path.first += 1
            self.taken[full] = now
            for old in [n for n in self.taken if n <= full - COPY_SPAN]:
                del self.taken[old]
        d = now - self.taken.get(full, now)  # 0 for a first copy and a stale one
        path.lag += (d - path.lag) / 8
        if path.newest is None or full > path.newest:
            path.newest, path.newest_at = full, now
        if path.unreported_since is None:
            path.unreported_since = now

    # -- timers: reports, probes, failures, forgotten paths -------------------------------------
    def reports_due(self, now: float) -> list[tuple[Path, wire.MpReport]]:
        """Section 5.11, "Reports": at most one per path per report_interval, never in the instant
        of the arrival it is the first to report (the endpoint vectors: one step later)."""
        out: list[tuple[Path, wire.MpReport]] = []
        for p in self.paths.values():
            since = p.unreported_since
            if since is None or now <= since or now < p.last_report + self.cfg.report_interval:
                continue
            hold = (
                wire.hold_encode_seconds(now - p.newest_at)
                if p.newest is not None
                else wire.HOLD_NO_ACK
            )
            lag = min(int(p.lag / LAG_UNIT), 0xFFFF)
            report = wire.MpReport(  # the clock read as it is built, with the hold (4.3)
                self.nonce,
                p.path_id,
                (p.newest or 0) & 0xFFF,
                hold,
                p.received,
                p.first,
                lag,
                wire.clock_us(now),
            )
            p.unreported_since = None
            p.last_report = now
            out.append((p, report))
        return out

    def expire(self, now: float) -> None:
        for p in list(self.paths.values()):
            if p.learned and not p.validated and now >= p.created_at + self.cfg.validation_timeout:
                del self.paths[p.path_id]  # a path the peer opened, never validated: forgotten
                continue
            # a path with no round-trip sample yet counts initial_rtt (FINDINGS.md: open)
            rtt = p.rtt if p.rtt is not None else self.cfg.initial_rtt
            timeout = max(self.cfg.path_timeout, 2 * self.cfg.probe_interval + 3 * rtt)
            if p.validated and now >= p.last_arrival + timeout:
                p.failed = True

    def probes_due(self, now: float) -> list[Path]:
        """Section 5.11, "Liveness per path": a validated path that carried nothing of ours for
        probe_interval; a failed or not yet validated one every failed_probe_interval."""
        due: list[Path] = []
        for p in self.paths.values():
            # deadlines as sums (last + interval), as the vectors' times were computed
            if p.validated and not p.failed:
                if now >= p.last_sent + self.cfg.probe_interval:
                    due.append(p)
            elif now >= p.last_challenge + self.cfg.failed_probe_interval:
                due.append(p)
        return due

    def validated_by(self, path: Path, echo: bytes, now: float) -> bool:
        """An MP_RESPONSE on this path echoing one of our last four tokens validates it."""
        for token, sent_at in path.tokens:
            if token == echo:
                path.validated = True
                path.failed = False
                self.rtt_sample(path, now - sent_at)
                return True
        return False
