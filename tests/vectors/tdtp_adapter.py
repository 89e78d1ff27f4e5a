"""Drives tdtp's sans-IO Connection through an endpoint script of tdtp-v4-endpoint.json.

Another implementation writes the same adapter for itself (tests/vectors/README.md says what it must
do). Here it serves twice: tools/vectors/generate.py records what tdtp does for each script, and the
test suite runs the committed scripts again and compares.
"""

from __future__ import annotations

import random
from collections import deque
from typing import Any

from tdtp import (
    Connection,
    ConnectionClosed,
    ConnectionConfig,
    ControlReceived,
    DataReceived,
    MultipathConfig,
    Role,
    State,
)
from tdtp.admission import Admission, AdmittedOpen, Reply
from tdtp.admission.slots import EvictionNotices, SessionSlots, Verdict
from tdtp.config import AckMode, AdmissionConfig
from tdtp.protection.derivation import derive_open_secret
from tdtp.protection.keys import KeyRing, PresharedKey
from tdtp.protection.packet_protection import Direction
from tdtp.session.events import Address
from tdtp.wire import (
    PROTOCOL_VERSION,
    CipherSuite,
    CloseReason,
    ControlCode,
    OpenBody,
    OpenFlags,
    PacketType,
    encode_header,
    encode_open,
)
from tdtp.wire.header import HEADER_SIZE

ADDRESSES: dict[str, tuple[str, int]] = {
    "master": ("192.0.2.1", 40001),
    "slave": ("192.0.2.2", 40002),
    "stranger": ("198.51.100.7", 666),
    "master_socket2": ("192.0.2.1", 40003),
    "master_moved": ("192.0.2.1", 50001),
    "master2": ("203.0.113.9", 40009),
    "master3": ("203.0.113.10", 40010),
}
"""The named addresses of the scripts: the endpoint suite uses the first three and (multipath) the
master's second socket, the server suite all but that (a master after a NAT rebinding: same host,
another port; two more masters, each a source of its own)."""
COOKIE_PLACEHOLDER = "{cookie}"
TOKEN_PLACEHOLDER = "{token}"
"""In a multipath script: the 8-byte token of the last MP_CHALLENGE or MP_RESPONSE the endpoint sent
with one (random: a runner echoes what it got)."""
_MP_TOKEN = slice(5 + 1 + 16 + 1, 5 + 1 + 16 + 1 + 8)  # an unkeyed MP_CHALLENGE's token
_MP_OWN_TOKEN = slice(5 + 1 + 16 + 1 + 8, 5 + 1 + 16 + 1 + 16)  # an MP_RESPONSE's own token
_MAX_TIMER_RUNS = 16


class ScriptedRandom(random.Random):
    """Hands tdtp the script's random values, in the order tdtp draws them: a slave's cookie
    secret (32 bytes, any value), then the master's nonce, the slave's nonce, the initial sequence
    number. The value the role does not choose itself is a placeholder it replaces."""

    def __init__(self, role: Role, nonce: bytes, initial_seq: int) -> None:
        super().__init__(0)
        placeholder = bytes(16)
        order = [nonce, placeholder] if role is Role.MASTER else [placeholder, nonce]
        self._nonces = deque(order)
        self._initial_seq = initial_seq

    def randbytes(self, n: int) -> bytes:
        if n == 16 and self._nonces:
            return self._nonces.popleft()
        return bytes(n)

    def randrange(self, *args: Any, **kwargs: Any) -> int:
        return self._initial_seq


def make_config(config: dict[str, Any]) -> ConnectionConfig:
    return ConnectionConfig(
        takeover=config.get("takeover", False),
        admission=AdmissionConfig(reclaim_after=config.get("reclaim_after", 10.0)),
        max_payload=config.get("max_payload", 1200),
        min_peer_payload=config.get("min_peer_payload", 1),
        ack_mode=AckMode(config.get("ack_mode", "bidirectional")),
        cipher_suite=CipherSuite(config.get("suite", 1)),
        encrypt=config.get("encrypt", True),
        deliver_late=config.get("deliver_late", False),
        deliver_duplicates=config.get("deliver_duplicates", False),
        control_window=config.get("control_window", 64),
        # The reorder wait is the receiver's local choice (PROTOCOL.md 5.5): the scripts pin
        # delivery without one, each new sample at once.
        max_reorder_wait=config.get("max_reorder_wait", 0.0),
        # Scripts are sessions without send timestamps unless they ask (PROTOCOL.md 5.13).
        timestamp_interval=config.get("timestamp_interval", 0.0),
        multipath=MultipathConfig(**config["multipath"]) if "multipath" in config else None,
    )


def control_name(datagram: bytes, keyed: bool) -> str:
    """A control datagram as the scripts list it: its code, and for an unkeyed CLOSE or any
    REJECT the reason (a keyed CLOSE seals it)."""
    code = ControlCode(datagram[5])
    if code is ControlCode.REJECT or (code is ControlCode.CLOSE and not keyed):
        reason = datagram[-1]
        try:
            return f"{code.name} {CloseReason(reason).name}"
        except ValueError:
            return f"{code.name} {reason}"
    return code.name


class _Runner:
    """What both script runners share: a script, run step by step."""

    script: dict[str, Any]

    def step(self, step: dict[str, Any]) -> dict[str, Any]:
        raise NotImplementedError

    def record(self) -> dict[str, Any]:
        """The script with each step's expectations: what tdtp does."""
        steps = []
        for step in self.script["steps"]:
            inputs = {k: v for k, v in step.items() if k != "expect"}
            steps.append({**inputs, "expect": self.step(inputs)})
        return {**self.script, "steps": steps}


class ScriptRunner(_Runner):
    """Runs one script against a fresh Connection; :meth:`record` returns the script with the
    expectations tdtp meets filled in."""

    def __init__(self, script: dict[str, Any]) -> None:
        self.script = script
        role = Role(script["role"])
        config = script.get("config", {})
        given = script["random"]
        psk = config.get("psk")
        key = PresharedKey(bytes.fromhex(psk)) if psk is not None else None
        self.conn = Connection(
            make_config(config),
            role=role,
            rng=ScriptedRandom(role, bytes.fromhex(given["nonce"]), given["initial_seq"]),
            key=key if role is Role.MASTER else None,
            keys=[key] if key is not None and role is Role.SLAVE else None,
        )
        self.cookie: bytes | None = None
        self.token: bytes | None = None

    def _datagram(self, text: str) -> bytes:
        if COOKIE_PLACEHOLDER in text:
            if self.cookie is None:
                raise ValueError("the script uses {cookie} before the endpoint sent a COOKIE")
            text = text.replace(COOKIE_PLACEHOLDER, self.cookie.hex())
        if TOKEN_PLACEHOLDER in text:
            if self.token is None:
                raise ValueError("the script uses {token} before the endpoint sent a token")
            text = text.replace(TOKEN_PLACEHOLDER, self.token.hex())
        return bytes.fromhex(text)

    def step(self, step: dict[str, Any]) -> dict[str, Any]:
        conn = self.conn
        now = float(step["at"])
        drops_before = dict(conn.stats.drops)
        action = step.get("action")
        if action == "connect":
            conn.connect(ADDRESSES["slave"], now=now)
        elif action == "close":
            conn.close(now=now, restarting=bool(step.get("restarting", False)))
        elif action == "send_control":
            conn.send_control(bytes.fromhex(step["message"]), now=now)
        elif action == "hold_control":
            conn.control_held(int(step["count"]))
        elif action is None:
            conn.receive_datagram(
                self._datagram(step["datagram"]), ADDRESSES[step["from"]], now=now
            )
        elif action != "advance":
            raise ValueError(f"unknown action {action!r}")
        for _ in range(_MAX_TIMER_RUNS):
            timer = conn.get_timer()
            if timer is None or timer > now:
                break
            conn.handle_timer(now=now)
        sent = conn.datagrams_to_send(now=now)
        delivered = []
        control_delivered = []
        closed: dict[str, Any] | None = None
        while (event := conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                delivered.append(event.payload.hex())
            elif isinstance(event, ControlReceived):
                control_delivered.append(event.payload.hex())
            elif isinstance(event, ConnectionClosed):
                closed = {"cause": event.cause.value, "reason": event.reason}
        control = []
        control_hex = []
        for datagram, _addr in sent:
            if datagram[0] >> 6 == PacketType.CONTROL:
                if datagram[5] == ControlCode.COOKIE:
                    self.cookie = datagram[-16:]
                elif datagram[5] == ControlCode.MP_CHALLENGE:
                    self.token = datagram[_MP_TOKEN]
                elif datagram[5] == ControlCode.MP_RESPONSE and any(datagram[_MP_OWN_TOKEN]):
                    self.token = datagram[_MP_OWN_TOKEN]
                control.append(control_name(datagram, conn.keyed))
                control_hex.append(datagram.hex())
        new = [
            reason
            for reason, count in conn.stats.drops.items()
            if count != drops_before.get(reason, 0)
        ]
        if len(new) > 1 or (new and conn.stats.drops[new[0]] != drops_before.get(new[0], 0) + 1):
            raise AssertionError(f"one datagram counted more than one drop: {new}")
        expect: dict[str, Any] = {
            "drop": new[0] if new else None,
            "state": conn.state.value,
            "delivered": delivered,
            "control_sent": control,
        }
        if control_delivered:
            expect["control_delivered"] = control_delivered
        if closed is not None:
            expect["closed"] = closed
        if step.get("exact"):
            expect["control_sent_hex"] = control_hex
        return expect


def _address_name(addr: Address) -> str:
    for name, known in ADDRESSES.items():
        if known == addr[:2]:
            return name
    return f"{addr[0]}:{addr[1]}"


def datagram_name(datagram: bytes) -> str:
    """Any datagram as the server scripts list it: DATA, ACK, or a control packet's code (with the
    reason of a REJECT or an unkeyed CLOSE, which is 23 bytes)."""
    ptype = datagram[0] >> 6
    if ptype == PacketType.DATA:
        return "DATA"
    if ptype == PacketType.ACK:
        return "ACK"
    return control_name(datagram, keyed=len(datagram) != _UNKEYED_CLOSE_SIZE)


_UNKEYED_CLOSE_SIZE = 23


def is_open(data: bytes) -> bool:
    """Whether a datagram is an OPEN (TYPE 2, at least 6 bytes, code 1)."""
    return len(data) > HEADER_SIZE and data[0] >> 6 == PacketType.CONTROL and data[5] == 1


class ServerRunner(_Runner):
    """Runs one script of tdtp-v4-server.json: a slave serving several masters on one address.

    tdtp's :class:`tdtp.aio.server.Server` does this with a socket and a clock; here the same
    sans-IO parts are composed in the same order (PROTOCOL.md 5.1, "A server with several
    masters", which ``Server._datagram_received``, ``_on_unattached``, ``_exclusive_refuses``,
    ``_open`` and ``_evict`` follow): a session per master address, one shared
    :class:`~tdtp.admission.Admission` (cookies, rates, budgets, RESETs, path migration), the slot
    policy, the eviction notices and the exclusive rule. Every session is accepted at once (no
    accept backlog)."""

    def __init__(self, script: dict[str, Any]) -> None:
        self.script = script
        config = script.get("config", {})
        self.config = make_config(config)
        psks = config.get("psks", [])
        ring = KeyRing([bytes.fromhex(psk) for psk in psks]) if psks else None
        # The cookie and path-token secrets are the server's own business: all zeros here.
        self.admission = Admission(self.config, ring, rng=ScriptedRandom(Role.SLAVE, b"", 0))
        max_peers = int(config.get("max_peers", 4))
        policy = self.config
        self.slots = SessionSlots(policy, max_peers)
        self.notices = EvictionNotices(max_peers, policy.idle_timeout, policy.silence_timeout)
        self.exclusive = bool(config.get("exclusive", False))
        self.takeover_after = int(config.get("takeover_after", 3))
        self.sessions: dict[Address, Connection] = {}
        self._randoms = deque(script["random"]["sessions"])
        self.cookie: bytes | None = None
        self.token: bytes | None = None
        self._out: list[tuple[bytes, Address]] = []
        self._drops: list[str] = []
        self._delivered: dict[str, list[str]] = {}
        self._control_delivered: dict[str, list[str]] = {}
        self._closed: dict[str, dict[str, Any]] = {}

    # ------------------------------------------------------------------ the front door

    def _receive(self, data: bytes, src: Address, now: float) -> None:
        conn = self.sessions.get(src)
        if conn is not None:
            conn.receive_datagram(data, src, now=now)
            self._flush(src, conn, now)
            if src in self.sessions or not is_open(data):
                return
            # The session ended on this OPEN (its master restarted): it opens anew.
        if not is_open(data):
            self._unattached(data, src, now)
            return
        verdict = self.admission.admit(data, src, now)
        if isinstance(verdict, Reply):
            self._drops.append(verdict.reason.value)
            self._out.append((verdict.datagram, src))
        elif isinstance(verdict, AdmittedOpen):
            self._open(verdict, src, now)
        else:
            self._drops.append(verdict.value)

    def _unattached(self, data: bytes, src: Address, now: float) -> None:
        notices = self.notices
        if notices.holds(src, now):
            close = notices.answer(src, len(data), now)
            if close is not None:
                self._out.append((close, src))
            return
        paths = self.admission.paths
        outcome = paths.on_unattached(data, src, now, list(self.sessions.values()))
        if outcome is None:
            if paths.unclaimed:
                reset = self.admission.reset(data, now)
                if reset is not None:
                    self._out.append((reset, src))
            return
        if isinstance(outcome, bytes):
            self._out.append((outcome, src))  # a PATH_CHALLENGE
            return
        for old, conn in list(self.sessions.items()):
            if conn is outcome:
                del self.sessions[old]
                self.sessions[src] = conn
                self._flush(src, conn, now)
                return

    def _exclusive_refuses(self, admitted: AdmittedOpen, src: Address, now: float) -> bool:
        holders = [(a, c) for a, c in self.sessions.items() if c.state is not State.CLOSED]
        if not holders:
            return False
        takeover = admitted.key is not None and bool(admitted.body.flags & OpenFlags.TAKEOVER)
        silence = self.takeover_after * self.config.silence_timeout
        if not takeover and any(conn.quiet_for(now) < silence for _, conn in holders):
            self._drops.append("refused")
            self._out.append((self.admission.reject(admitted, CloseReason.IN_USE), src))
            return True
        for where, conn in holders:
            close = conn.close(now=now, taken_over=True)
            self._flush(where, conn, now)
            if close is not None:
                self.notices.add(where, close, now)
        return False

    def _open(self, admitted: AdmittedOpen, src: Address, now: float) -> None:
        if self.exclusive and self._exclusive_refuses(admitted, src, now):
            return
        placement = self.slots.place(admitted.key, src, list(self.sessions.values()), now)
        if placement.verdict is Verdict.BUSY or placement.verdict is Verdict.SHARE:
            self._drops.append("refused")
            self._out.append((self.admission.reject(admitted, CloseReason.BUSY), src))
            return
        if placement.holder is not None:
            where = next(a for a, c in self.sessions.items() if c is placement.holder)
            close = placement.holder.evict(placement.detail, now=now)
            self._flush(where, placement.holder, now)
            if close is not None:
                self.notices.add(where, close, now)
        self.notices.forget(src)
        given = self._randoms.popleft()
        rng = ScriptedRandom(Role.SLAVE, bytes.fromhex(given["nonce"]), given["initial_seq"])
        conn = Connection(self.config, role=Role.SLAVE, rng=rng, admission=self.admission)
        self.sessions[src] = conn
        conn.accept_open(admitted, src, now=now)
        self._flush(src, conn, now)

    # ------------------------------------------------------------------ sessions

    def _flush(self, where: Address, conn: Connection, now: float) -> None:
        """What the session sends now, and what its application hears; an ended session leaves
        the table."""
        self._out.extend(conn.datagrams_to_send(now=now))
        name = _address_name(where)
        while (event := conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                self._delivered.setdefault(name, []).append(event.payload.hex())
            elif isinstance(event, ControlReceived):
                self._control_delivered.setdefault(name, []).append(event.payload.hex())
            elif isinstance(event, ConnectionClosed):
                self._closed[name] = {"cause": event.cause.value, "reason": event.reason}
        if conn.state is State.CLOSED and self.sessions.get(where) is conn:
            del self.sessions[where]

    def _open_datagram(self, fields: dict[str, Any]) -> bytes:
        """The OPEN a step describes (section 4.3) with the last cookie the server sent, and,
        keyed, its tag (section 5.6): a cookie is the server's own, so only the runner can."""
        psk = fields.get("psk")
        key = PresharedKey(bytes.fromhex(psk)) if psk is not None else None
        suite = int(fields.get("suite", 1 if key is not None else 0))
        attempt = int(fields.get("attempt", 0))
        cookie = bytes(16)
        if fields.get("cookie", False):
            if self.cookie is None:
                raise ValueError("the script asks for a cookie before the server sent one")
            cookie = self.cookie
        nonce = bytes.fromhex(fields["nonce"])
        body = OpenBody(
            int(fields.get("version", PROTOCOL_VERSION)),
            int(fields.get("flags", 6 if key is not None else 0)),
            suite,
            int(fields.get("max_payload", 1200)),
            attempt,
            nonce,
            key.key_id if key is not None else bytes(8),
            cookie,
        )
        datagram = encode_header(PacketType.CONTROL, int(fields["seq"]), 0, 0, 255) + encode_open(
            body
        )
        if key is not None:
            secret = derive_open_secret(key.secret, nonce, CipherSuite(suite))
            datagram += Direction(CipherSuite(suite), secret).tag(attempt, datagram)
        return datagram

    def _datagram(self, text: str) -> bytes:
        for placeholder, value in (("{cookie}", self.cookie), ("{token}", self.token)):
            if placeholder in text:
                if value is None:
                    raise ValueError(f"the script uses {placeholder} before the server sent one")
                text = text.replace(placeholder, value.hex())
        return bytes.fromhex(text)

    def step(self, step: dict[str, Any]) -> dict[str, Any]:
        now = float(step["at"])
        self._out = []
        self._drops = []
        self._delivered = {}
        self._control_delivered = {}
        self._closed = {}
        sessions_before = list(self.sessions.values())
        counts_before = [dict(c.stats.drops) for c in sessions_before]
        paths_before = dict(self.admission.paths.stats.drops)
        action = step.get("action")
        if action == "close":
            where = ADDRESSES[step["session"]]
            conn = self.sessions[where]
            conn.close(now=now, restarting=bool(step.get("restarting", False)))
            self._flush(where, conn, now)
        elif action is None:
            data = (
                self._open_datagram(step["open"])
                if "open" in step
                else self._datagram(step["datagram"])
            )
            self._receive(data, ADDRESSES[step["from"]], now)
        elif action != "advance":
            raise ValueError(f"unknown action {action!r}")
        for where, conn in list(self.sessions.items()):
            for _ in range(_MAX_TIMER_RUNS):
                timer = conn.get_timer()
                if timer is None or timer > now:
                    break
                conn.handle_timer(now=now)
            self._flush(where, conn, now)
        drops: list[str] = []
        seen = set()
        for conn, before in zip(sessions_before, counts_before, strict=True):
            seen.add(id(conn))
            drops += _new_drops(before, conn.stats.drops)
        for conn in self.sessions.values():
            if id(conn) not in seen:
                drops += _new_drops({}, conn.stats.drops)
        drops += _new_drops(paths_before, self.admission.paths.stats.drops)
        drops += self._drops
        sent = []
        for datagram, addr in self._out:
            if datagram[0] >> 6 == PacketType.CONTROL and len(datagram) > 5:
                if datagram[5] == ControlCode.COOKIE:
                    self.cookie = datagram[-16:]
                elif datagram[5] == ControlCode.PATH_CHALLENGE:
                    self.token = datagram[-16:]
            sent.append(f"{datagram_name(datagram)} -> {_address_name(addr)}")
        expect: dict[str, Any] = {
            "drops": drops,
            "sessions": {
                _address_name(where): conn.state.value for where, conn in self.sessions.items()
            },
            "sent": sent,
        }
        if self._delivered:
            expect["delivered"] = self._delivered
        if self._control_delivered:
            expect["control_delivered"] = self._control_delivered
        if self._closed:
            expect["closed"] = self._closed
        if step.get("exact"):
            expect["sent_hex"] = [datagram.hex() for datagram, _ in self._out]
        return expect


def _new_drops(before: dict[str, int], after: dict[str, int]) -> list[str]:
    """The reasons counted between two snapshots of a drop counter, each as often as counted."""
    return [reason for reason, count in after.items() for _ in range(count - before.get(reason, 0))]
