"""A slave serving several masters on one address (section 5.1, "A server with several masters";
slots 5.1 rule 2.7; RESET 5.7; path migration 5.8; exclusive control 5.9)."""

from __future__ import annotations

import ipaddress
from collections import OrderedDict
from dataclasses import dataclass

from . import wire
from .admission import Admission
from .bucket import TokenBucket
from .config import Addr, Config
from .connection import CLOSED, ESTABLISHED, Connection, Sent, Sink
from .endpoint import is_open, make_reset

MAX_REPEATS = 8


@dataclass
class Notice:
    """An evicted or displaced master's CLOSE, repeated to its later datagrams (rule 2.7 step 4)."""

    close: bytes
    label: str
    at: float
    last: float
    repeats: int = 0


def source_of(addr: Addr) -> str | None:
    """The source a share counts (rule 2.7.1): an IPv4 address, the /64 of a global IPv6
    address, any other IPv6 address whole; None for loopback (not counted)."""
    ip = ipaddress.ip_address(addr[0])
    if ip.is_loopback:
        return None
    if ip.version == 6 and ip.is_global:
        return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(ip)


class Server:
    def __init__(self, cfg: Config, randoms: list[tuple[bytes, int]], now: float = 0.0) -> None:
        self.cfg = cfg
        self.sink = Sink()
        self.admission = Admission(cfg, now)
        self.randoms = list(randoms)  # (nonce, initial_seq) per session, in creation order
        self.sessions: dict[Addr, Connection] = {}
        self.notices: OrderedDict[Addr, Notice] = OrderedDict()
        trial_burst = max(1.0, cfg.migration_trials_per_second / 10)
        self.trials = TokenBucket(cfg.migration_trials_per_second, trial_burst, now)
        self.resets = TokenBucket(cfg.resets_per_second, cfg.resets_per_second, now)

    def _drop(self, reason: str) -> None:
        self.sink.drops.append((self, reason))

    def _send(self, data: bytes, addr: Addr, label: str) -> None:
        self.sink.sent.append(Sent(data, addr, label))

    # -- each datagram, in the order of section 5.1 ----------------------------------------------
    def receive(self, data: bytes, addr: Addr, now: float) -> None:
        conn = self.sessions.get(addr)
        if conn is not None:  # step 1
            conn.receive(data, addr, now)
            if conn.state == CLOSED and conn.replacing is not None:
                del self.sessions[addr]  # replaced (rule 5): the OPEN goes on to step 2
                self._open(data, addr, now)
            return
        if is_open(data):  # step 2
            return self._open(data, addr, now)
        notice = self.notices.get(addr)  # step 3.1
        if notice is not None and now - notice.at < self.cfg.idle_timeout:
            if (
                len(data) >= len(notice.close)
                and notice.repeats < MAX_REPEATS
                and now - notice.last >= self.cfg.silence_timeout
            ):
                notice.repeats += 1
                notice.last = now
                self._send(notice.close, addr, notice.label)
            return None
        return self._migrate(data, addr, now)  # steps 3.2 and 3.3

    # -- step 2: an OPEN from an address without a session ---------------------------------------
    def _open(self, data: bytes, addr: Addr, now: float) -> None:
        v = self.admission.judge(data, addr, now)
        if v.reply is not None:
            self._send(v.reply, addr, v.reply_label)
        if v.drop is not None:
            return self._drop(v.drop)
        op = v.open
        assert op is not None
        if self.cfg.exclusive and self.sessions:  # section 5.9
            takeover = bool(op.flags & wire.FLAG_KEYED) and bool(op.flags & wire.FLAG_TAKEOVER)
            limit = self.cfg.takeover_after * self.cfg.silence_timeout
            if not takeover and any(s.silence(now) < limit for s in self.sessions.values()):
                return self._refuse(op.nonce, wire.IN_USE, addr)
            for s in list(self.sessions.values()):
                self._end(s, wire.TAKEN_OVER, "taken_over", now)
        if not self._room(v.psk, addr, now):
            return self._refuse(op.nonce, wire.BUSY, addr)
        nonce, isn = self.randoms.pop(0)
        conn = Connection("slave", self.cfg, self.sink, nonce, isn, now, admission=self.admission)
        conn.accept_open(v, addr, wire.Header.decode(data).seq, now)
        self.sessions[addr] = conn
        self.notices.pop(addr, None)  # a new session for that address forgets its notice
        return None

    def _refuse(self, nonce: bytes, reason: int, addr: Addr) -> None:
        self._send(
            wire.control_datagram(wire.Reject(nonce, reason), wire.plain_header()),
            addr,
            f"REJECT {wire.reason_name(reason)}",
        )
        self._drop("refused")

    def _room(self, psk: bytes | None, addr: Addr, now: float) -> bool:
        """Rule 2.7: share, free, reclaim (only from a master that is gone)."""
        cfg = self.cfg
        src = source_of(addr)
        share = max(1, int(cfg.source_share * cfg.max_peers))
        own = [
            s
            for s in self.sessions.values()
            if src is not None and s.peer and source_of(s.peer) == src
        ]
        if src is not None and len(own) >= share:
            pool = own
        elif len(self.sessions) < cfg.max_peers:
            return True
        else:
            pool = list(self.sessions.values())
        same_key = [
            s
            for s in pool
            if psk is not None and s.psk == psk and s.silence(now) >= cfg.silence_timeout
        ]
        gone = [s for s in pool if s.silence(now) >= cfg.reclaim_after]
        candidates = same_key or gone
        if not candidates:
            return False
        victim = max(candidates, key=lambda s: s.silence(now))
        self._end(victim, wire.EVICTED, "evicted", now)
        return True

    def _end(self, conn: Connection, reason: int, cause: str, now: float) -> None:
        """End a session for an eviction or a takeover; remember its CLOSE for the repeats."""
        addr = conn.peer
        assert addr is not None
        close = conn.end(now, reason, cause)
        conn.tick(now)  # its CLOSE leaves now, before the new session's OPEN_ACK
        self.sessions.pop(addr, None)
        label = "CLOSE" if conn.keyed else f"CLOSE {wire.reason_name(reason)}"
        self.notices.pop(addr, None)
        self.notices[addr] = Notice(close, label, now, now)
        while len(self.notices) > self.cfg.max_peers:
            self.notices.popitem(last=False)

    # -- step 3.2: path migration (section 5.8) and step 3.3: RESET ------------------------------
    def _migrate(self, data: bytes, addr: Addr, now: float) -> None:
        reset_ok = False
        reason = self._migration_step(data, addr, now)
        if reason is None:
            return
        self._drop(reason)
        established = [s for s in self.sessions.values() if s.state == ESTABLISHED]
        if reason == "no_quiet_session":
            reset_ok = not established  # no established session at all
        elif reason == "unauthenticated":
            reset_ok = all(s.keyed and s.quiet(now) for s in established)
        if reset_ok:
            reset = make_reset(data, self.cfg.psks)
            if reset is not None and self.resets.take(now):
                self._send(reset, addr, "RESET")

    def _migration_step(self, data: bytes, addr: Addr, now: float) -> str | None:
        """Steps 1 to 6 of section 5.8; the drop reason, or None (moved, or a challenge drawn)."""
        # 1. a PATH_RESPONSE goes to path validation
        if len(data) >= 6 and data[0] >> 6 == wire.CONTROL and data[5] == wire.PATH_RESPONSE:
            try:
                msg = wire.decode_control(data[5:])
            except wire.BadControlError:
                return "bad_control"
            assert isinstance(msg, wire.PathResponse)
            if not self.admission.tokens.challenge_ok(msg.token, now, addr):
                return "bad_token"
            for s in self.sessions.values():
                if s.state == ESTABLISHED and not s.keyed and s.nonce == msg.nonce:
                    self._rekey(s, addr)
                    s.move(addr, now, by_response=True)
                    return None
            return "no_session"
        # 2. from the address an unkeyed session moved away from, before the move is validated
        for s in list(self.sessions.values()):
            if not s.keyed and s.moved_from == addr and not s.validated:
                self._rekey(s, addr)
                s.move_back()
                s.receive(data, addr, now)
                return None
        # 3. no quiet session
        quiet = [s for s in self.sessions.values() if s.quiet(now)]
        if not quiet:
            return "no_quiet_session"
        # 4. each quiet keyed session tries it, one token of the trial budget per trial
        for s in quiet:
            if not s.keyed:
                continue
            if not self.trials.take(now):
                return "trial_budget"
            verdict = s.trial(data)
            if verdict == "replayed":
                return "replayed"
            if verdict == "ahead":
                self._rekey(s, addr)
                s.move(addr, now, by_response=False)
                s.receive(data, addr, now)
                return None
        # 5. no unkeyed session among the quiet ones
        unkeyed = [s for s in quiet if not s.keyed]
        if not unkeyed:
            return "unauthenticated"
        # 6. a PATH_CHALLENGE: no larger than what drew it, within the sessions' and reply budgets
        if len(data) < 22:
            return "too_small"
        paid = [s.challenges.take(now) for s in unkeyed]
        if not any(paid):
            return "challenge_budget"
        if not self.admission.replies.take(now):
            return "rate_limited"
        token = self.admission.tokens.challenge(now, addr)
        self._send(
            wire.control_datagram(wire.PathChallenge(token), wire.plain_header()),
            addr,
            "PATH_CHALLENGE",
        )
        return None

    def _rekey(self, conn: Connection, addr: Addr) -> None:
        """The table is by the master's address: a session that moves changes its key."""
        if conn.peer is not None:
            self.sessions.pop(conn.peer, None)
        self.sessions[addr] = conn

    # -- timers ---------------------------------------------------------------------------------
    def tick(self, now: float) -> None:
        for conn in list(self.sessions.values()):
            conn.tick(now)
        for addr, conn in list(self.sessions.items()):
            if conn.state == CLOSED:
                del self.sessions[addr]

    def close(self, addr: Addr, now: float) -> None:
        conn = self.sessions.get(addr)
        if conn is not None:
            conn.close(now)
