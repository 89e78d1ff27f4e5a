"""The endpoint and server suites (tests/vectors/README.md, "Endpoint scripts", "Server scripts")."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from tdtp_cleanroom import crypto, wire
from tdtp_cleanroom.config import Addr, Config
from tdtp_cleanroom.connection import Sent
from tdtp_cleanroom.endpoint import Master, StandaloneSlave
from tdtp_cleanroom.server import Server

ADDRS: dict[str, Addr] = {
    "master": ("192.0.2.1", 40001),
    "slave": ("192.0.2.2", 40002),
    "stranger": ("198.51.100.7", 666),
    "master_socket2": ("192.0.2.1", 40003),  # the master's second socket: a second path
    "master_moved": ("192.0.2.1", 50001),
    "master2": ("203.0.113.9", 40009),
    "master3": ("203.0.113.10", 40010),
}
NAMES = {v: k for k, v in ADDRS.items()}
SLAVE = ADDRS["slave"]


Vec = dict[str, Any]  # one vector, script or step as the JSON file has it


class MismatchError(Exception):
    """What an implementation did differs from what a vector says."""


def make_config(c: Vec, role: str) -> Config:
    cfg = Config()
    for k in (
        "max_payload",
        "min_peer_payload",
        "control_window",
        "suite",
        "encrypt",
        "takeover",
        "max_peers",
        "exclusive",
        "takeover_after",
        "reclaim_after",
        "timestamp_interval",
    ):
        if k in c:
            setattr(cfg, k, c[k])
    if "psk" in c:
        if role == "master":
            cfg.psk = bytes.fromhex(c["psk"])
        else:
            cfg.psks = [bytes.fromhex(c["psk"])]
    if "psks" in c:
        cfg.psks = [bytes.fromhex(k) for k in c["psks"]]
    if "multipath" in c:  # the parameters of section 5.11, by name
        cfg.multipath = True
        for k, v in c["multipath"].items():
            if not hasattr(cfg, k):
                raise ValueError(f"unknown multipath parameter {k!r}")
            setattr(cfg, k, v)
    if "reclaim_after" in c:  # at least 10 x silence_timeout (5.1 rule 2.7)
        cfg.reclaim_after = max(c["reclaim_after"], 10 * cfg.silence_timeout)
    return cfg


def compare(where: str, got: Vec, want: Vec) -> None:
    for k in sorted(set(got) | set(want)):
        if got.get(k) != want.get(k):
            raise MismatchError(f"{where}: {k}: got {got.get(k)!r}, want {want.get(k)!r}")


def last_token(sent: list[Sent], code: int, offset: int) -> bytes | None:
    """The 16 bytes at `offset` of the last CONTROL datagram of this code sent (cookie, token)."""
    for s in reversed(sent):
        if len(s.data) >= offset + 16 and s.data[0] >> 6 == wire.CONTROL and s.data[5] == code:
            return s.data[offset : offset + 16]
    return None


COOKIE_OFFSET = 23  # header 5, code 1, version 1, nonce 16
TOKEN_OFFSET = 6


def substitute(text: str, history: list[Sent], mp_token: bytes | None = None) -> bytes:
    """`{cookie}`; `{token}`: an endpoint's last multipath token (`mp_token`, 8 bytes: it may be
    sealed on the wire, so the endpoint says which it was), else a server's last PATH_CHALLENGE
    token (16 bytes)."""
    if "{cookie}" in text:
        cookie = last_token(history, wire.COOKIE, COOKIE_OFFSET)
        text = text.replace("{cookie}", cookie.hex() if cookie else "00" * 16)
    if "{token}" in text:
        token = mp_token or last_token(history, wire.PATH_CHALLENGE, TOKEN_OFFSET)
        text = text.replace("{token}", token.hex() if token else "00" * 16)
    return bytes.fromhex(text)


def endpoint_suite(d: Vec) -> Iterable[tuple[str, Callable[[], None]]]:
    for script in d["scripts"]:

        def run(s: Vec = script) -> None:
            run_endpoint_script(s)

        yield script["name"], run


def run_endpoint_script(script: Vec) -> None:
    role = script["role"]
    cfg = make_config(script.get("config", {}), role)
    rnd = script["random"]
    ep: Master | StandaloneSlave
    if role == "master":
        ep = Master(cfg, bytes.fromhex(rnd["nonce"]), rnd["initial_seq"])
    else:
        ep = StandaloneSlave(cfg, bytes.fromhex(rnd["nonce"]), rnd["initial_seq"])
    history: list[Sent] = []
    for i, step in enumerate(script["steps"]):
        now = step["at"]
        ep.sink.clear()
        action = step.get("action")
        if action == "connect":
            assert isinstance(ep, Master)
            ep.connect(SLAVE, now)
        elif action == "close":
            assert ep.conn is not None
            ep.conn.close(now, step.get("restarting", False))
        elif action == "send_control":
            assert ep.conn is not None
            ep.conn.send_control(bytes.fromhex(step["message"]), now)
        elif action == "hold_control":
            assert ep.conn is not None
            ep.conn.hold_control(step["count"])
        elif action == "advance":
            pass
        elif "datagram" in step:
            mp = ep.conn.mp if ep.conn is not None else None
            token = mp.last_token if mp is not None else None
            ep.receive(substitute(step["datagram"], history, token), ADDRS[step["from"]], now)
        else:
            raise ValueError(f"unknown step {step}")
        ep.tick(now)
        history.extend(ep.sink.sent)
        want = step["expect"]
        drops = [r for _, r in ep.sink.drops]
        if len(drops) > 1:
            raise MismatchError(f"step {i} at {now}: more than one drop {drops}")
        sent = [s for s in ep.sink.sent if s.label not in ("DATA", "ACK")]
        got: dict[str, Any] = {
            "drop": drops[0] if drops else None,
            "state": ep.state,
            "delivered": [p.hex() for _, p in ep.sink.delivered],
            "control_sent": [s.label for s in sent],
        }
        if ep.sink.control_delivered:
            got["control_delivered"] = [p.hex() for _, p in ep.sink.control_delivered]
        if step.get("exact"):
            got["control_sent_hex"] = [s.data.hex() for s in sent]
        if ep.sink.closed:
            _, cause, reason = ep.sink.closed[-1]
            got["closed"] = {"cause": cause, "reason": reason}
        compare(f"step {i} at {now}", got, want)


def server_suite(d: Vec) -> Iterable[tuple[str, Callable[[], None]]]:
    for script in d["scripts"]:

        def run(s: Vec = script) -> None:
            run_server_script(s)

        yield script["name"], run


def build_open(o: Vec, history: list[Sent]) -> bytes:
    """An OPEN the runner builds (README, "Server scripts"; section 4.3), tagged with a psk."""
    psk = bytes.fromhex(o["psk"]) if "psk" in o else None
    flags = o.get("flags", 6 if psk else 0)
    suite = o.get("suite", 1 if psk else 0)
    cookie = (
        last_token(history, wire.COOKIE, COOKIE_OFFSET) if o.get("cookie") else None
    ) or bytes(16)
    nonce = bytes.fromhex(o["nonce"])
    op = wire.Open(
        wire.PROTOCOL_VERSION,
        flags,
        suite,
        o.get("max_payload", 1200),
        o["attempt"],
        nonce,
        crypto.key_id(psk) if psk else bytes(8),
        cookie,
    )
    dg = wire.control_datagram(op, wire.plain_header(wire.CONTROL, o["seq"]))
    if psk:
        key, iv = crypto.open_key_iv(psk, suite, nonce)
        dg += crypto.handshake_tag(crypto.make_aead(suite, key), iv, o["attempt"], dg)
    return dg


def run_server_script(script: Vec) -> None:
    cfg = make_config(script.get("config", {}), "slave")
    randoms = [(bytes.fromhex(r["nonce"]), r["initial_seq"]) for r in script["random"]["sessions"]]
    srv = Server(cfg, randoms)
    history: list[Sent] = []
    for i, step in enumerate(script["steps"]):
        now = step["at"]
        srv.sink.clear()
        action = step.get("action")
        if action == "close":
            srv.close(ADDRS[step["session"]], now)
        elif action == "advance":
            pass
        elif "open" in step:
            srv.receive(build_open(step["open"], history), ADDRS[step["from"]], now)
        elif "datagram" in step:
            srv.receive(substitute(step["datagram"], history), ADDRS[step["from"]], now)
        else:
            raise ValueError(f"unknown step {step}")
        srv.tick(now)
        history.extend(srv.sink.sent)
        want = step["expect"]

        def name(conn: object) -> str:
            peer = getattr(conn, "peer", None)
            return NAMES.get(peer, str(peer)) if peer is not None else "?"

        got: dict[str, Any] = {
            "drops": [r for _, r in srv.sink.drops],
            "sessions": {NAMES.get(a, str(a)): c.state for a, c in srv.sessions.items()},
            "sent": [
                f"{s.label} -> {NAMES.get(s.addr, str(s.addr)) if s.addr else '?'}"
                for s in srv.sink.sent
            ],
        }
        if step.get("exact"):
            got["sent_hex"] = [s.data.hex() for s in srv.sink.sent]
        for key, items in (
            ("delivered", srv.sink.delivered),
            ("control_delivered", srv.sink.control_delivered),
        ):
            if items:
                by: dict[str, list[str]] = {}
                for conn, payload in items:
                    by.setdefault(name(conn), []).append(payload.hex())
                got[key] = by
        if srv.sink.closed:
            got["closed"] = {
                name(c): {"cause": cause, "reason": reason} for c, cause, reason in srv.sink.closed
            }
        compare(f"step {i} at {now}", got, want)
