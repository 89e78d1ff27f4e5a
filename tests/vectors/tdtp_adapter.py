"""Drives tdtp's sans-IO Connection through an endpoint script of tdtp-v4-endpoint.json.

Another implementation writes the same adapter for itself (tests/vectors/README.md says what it must
do). Here it serves twice: tools/vectors/generate.py records what tdtp does for each script, and the
test suite runs the committed scripts again and compares.
"""

from __future__ import annotations

import random
from collections import deque
from typing import Any

from tdtp import Connection, ConnectionConfig, ControlReceived, DataReceived, MultipathConfig, Role
from tdtp.config import AckMode
from tdtp.protection.keys import PresharedKey
from tdtp.wire import CipherSuite, CloseReason, ControlCode, PacketType

ADDRESSES: dict[str, tuple[str, int]] = {
    "master": ("192.0.2.1", 40001),
    "master2": ("192.0.2.1", 40003),
    "slave": ("192.0.2.2", 40002),
    "stranger": ("198.51.100.7", 666),
}
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


class ScriptRunner:
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
            conn.close(now=now)
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
        while (event := conn.next_event()) is not None:
            if isinstance(event, DataReceived):
                delivered.append(event.payload.hex())
            elif isinstance(event, ControlReceived):
                control_delivered.append(event.payload.hex())
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
        if step.get("exact"):
            expect["control_sent_hex"] = control_hex
        return expect

    def record(self) -> dict[str, Any]:
        """The script with each step's expectations: what tdtp does."""
        steps = []
        for step in self.script["steps"]:
            inputs = {k: v for k, v in step.items() if k != "expect"}
            steps.append({**inputs, "expect": self.step(inputs)})
        return {**self.script, "steps": steps}
