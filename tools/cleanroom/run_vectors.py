#!/usr/bin/env python3
"""Run every conformance vector file in tests/vectors/ against the clean-room implementation.

Usage: python tools/cleanroom/run_vectors.py [-v] [FILE ...]

Prints, per file, how many vectors passed and failed, with the first difference of each failure.
Exits 0 only if every vector of every file passes. Follows tests/vectors/README.md.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
VECTORS = HERE.parent.parent / "tests" / "vectors"

from scripts_runner import MismatchError, endpoint_suite, server_suite  # noqa: E402
from tdtp_cleanroom import crypto, wire  # noqa: E402
from tdtp_cleanroom.receiver import ReceiveWindow  # noqa: E402
from tdtp_cleanroom.sender import SentLog  # noqa: E402

KNOWN_FORMAT_VERSIONS = {1}
Vec = dict[str, Any]  # one vector as the JSON file has it


def close_enough(a: Any, b: Any) -> bool:
    """Floats to a relative 1e-9 (absolute 1e-12), everything else exactly (README: common layout)."""
    if isinstance(a, float) or isinstance(b, float):
        if a is None or b is None:
            return a is b
        return math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(close_enough(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(close_enough(a[k], b[k]) for k in a)
    return bool(a == b)


def check(where: str, got: Any, want: Any) -> None:
    if not close_enough(got, want):
        raise MismatchError(f"{where}: got {got!r}, want {want!r}")


# -- stateless suites ---------------------------------------------------------------------------
def header_suite(d: Vec) -> Iterable[tuple[str, Callable[[], None]]]:
    for v in d["valid"]:

        def run(v: Vec = v) -> None:
            h = wire.Header.decode(bytes.fromhex(v["hex"]))
            check(
                "decode",
                [h.type, h.seq, h.ack, h.sack, h.hold],
                [v["type"], v["seq"], v["ack"], v["sack"], v["hold"]],
            )
            enc = wire.Header(v["type"], v["seq"], v["ack"], v["sack"], v["hold"]).encode()
            check("encode", enc.hex(), v["hex"][:10])

        yield v["name"], run
    for v in d["invalid"]:

        def run(v: Vec = v) -> None:
            try:
                wire.Header.decode(bytes.fromhex(v["hex"]))
            except wire.TruncatedError:
                check("error", "truncated", v["error"])
                return
            raise MismatchError(f"decoded; want {v['error']}")

        yield v["name"], run


def hold_suite(d: Vec) -> Iterable[tuple[str, Callable[[], None]]]:
    for v in d["decode"]:

        def dec(v: Vec = v) -> None:
            check("hold_ns", wire.hold_decode_ns(v["code"]), v["hold_ns"])

        yield f"decode {v['code']}", dec
    for v in d["encode"]:

        def enc(v: Vec = v) -> None:
            check("code", wire.hold_encode_ns(v["hold_ns"]), v["code"])

        yield f"encode {v['hold_ns']}", enc


def seqnum_suite(d: Vec) -> Iterable[tuple[str, Callable[[], None]]]:
    for v in d["expand"]:

        def exp(v: Vec = v) -> None:
            check("full", wire.expand(v["truncated"], v["expected"]), v["full"])

        yield f"expand {v['truncated']} near {v['expected']}", exp
    for v in d["ack_expand"]:

        def run(v: Vec = v) -> None:
            log = SentLog(v["first_seq"])
            for i in range(v["packets_sent"]):
                log.on_sent(i * 0.001)
            log.largest_acked = v["largest_acked"]
            full = log.expand_ack(v["ack"], wire.HOLD_SATURATED, v["packets_sent"] * 0.001)
            check("optimistic", full is None, v["optimistic"])
            check("full", full, v["full"])

        yield v["name"], run


def _fields(msg: wire.ControlBody) -> Vec:
    out: dict[str, Any] = {}
    for k, val in vars(msg).items():
        if k in ("code", "tag"):
            continue
        if isinstance(val, bytes):
            out[k] = val.hex()
        elif isinstance(val, list):
            out[k] = [x.hex() for x in val]
        else:
            out[k] = val
    return out


def control_suite(d: Vec) -> Iterable[tuple[str, Callable[[], None]]]:
    for v in d["valid"]:

        def run(v: Vec = v) -> None:
            body = bytes.fromhex(v["body_hex"])
            msg = wire.decode_control(body)
            check("code", wire.CODE_NAMES[msg.code], v["code"])
            check("fields", _fields(msg), v["fields"])
            check("re-encoded", wire.encode_control(msg).hex(), v["body_hex"])
            dg = bytes.fromhex(v["datagram_hex"])
            check("datagram body", wire.decode_control(dg[5:]) == msg, True)

        yield v["name"], run
    for v in d["invalid"]:

        def run(v: Vec = v) -> None:
            try:
                wire.decode_control(bytes.fromhex(v["body_hex"]))
            except wire.BadControlError:
                check("error", "bad_control", v["error"])
                return
            raise MismatchError(f"decoded; want {v['error']}")

        yield v["name"], run


def keyed_suite(d: Vec) -> Iterable[tuple[str, Callable[[], None]]]:
    for i, v in enumerate(d["derivations"]):

        def run(v: Vec = v) -> None:
            psk, suite = bytes.fromhex(v["psk"]), v["suite"]
            mn, sn = bytes.fromhex(v["master_nonce"]), bytes.fromhex(v["slave_nonce"])
            ok, oi = crypto.open_key_iv(psk, suite, mn)
            sk = crypto.session_keys(psk, suite, mn, sn)
            got = {
                "key_id": crypto.key_id(psk).hex(),
                "open_key": ok.hex(),
                "open_iv": oi.hex(),
                "m2s_key": sk.m2s_key.hex(),
                "m2s_iv": sk.m2s_iv.hex(),
                "s2m_key": sk.s2m_key.hex(),
                "s2m_iv": sk.s2m_iv.hex(),
                "reset_key": crypto.reset_key(psk).hex(),
            }
            for k, val in got.items():
                check(k, val, v[k])

        yield f"derivation {i}", run
    for i, v in enumerate(d["handshake_tags"]):

        def run(v: Vec = v) -> None:
            psk, suite = bytes.fromhex(v["psk"]), v["suite"]
            dg = bytes.fromhex(v["datagram_without_tag"])
            if v["message"] == "OPEN":
                key, iv = crypto.open_key_iv(psk, suite, dg[13:29])  # master nonce at offset 13
            else:
                sk = crypto.session_keys(psk, suite, dg[13:29], dg[29:45])  # slave nonce at 29
                key, iv = sk.s2m_key, sk.s2m_iv
            tag = crypto.handshake_tag(crypto.make_aead(suite, key), iv, v["nonce_counter"], dg)
            check("tag", tag.hex(), v["tag"])

        yield f"handshake tag {i} ({v['message']})", run
    for i, v in enumerate(d["seal"]):

        def run(v: Vec = v) -> None:
            aead = crypto.make_aead(v["suite"], bytes.fromhex(v["key"]))
            iv, pn = bytes.fromhex(v["iv"]), v["packet_number"]
            prefix, body = bytes.fromhex(v["prefix"]), bytes.fromhex(v["body"])
            dg = crypto.seal(aead, iv, pn, prefix, body, v["encrypt"])
            check("datagram", dg.hex(), v["datagram"])
            op = crypto.Opener(v["suite"], bytes.fromhex(v["key"]), iv, v["encrypt"])
            if pn > 0:
                op.accept(pn - 1, 0.0)
            verdict, got, _ = op.open(bytes.fromhex(v["datagram"]), len(prefix), 0.0)
            check(
                "reopen", [verdict, got.hex() if got is not None else None], ["accepted", v["body"]]
            )

        yield f"seal {i} ({v['packet']} pn {v['packet_number']})", run
    o = d["opening"]
    for_suite = o.get("suite", 1)
    op = crypto.Opener(for_suite, bytes.fromhex(o["key"]), bytes.fromhex(o["iv"]), o["encrypt"])
    for v in o["steps"]:

        def run(v: Vec = v) -> None:
            # one receiver, steps in order; no time passes (the search's budget is full)
            verdict, body, _ = op.open(bytes.fromhex(v["datagram"]), o["prefix_size"], 0.0)
            check("verdict", verdict, v["verdict"])
            if "body" in v:
                check("body", body.hex() if body is not None else None, v["body"])
            check("highest", op.highest, v["highest"])

        yield f"opening: {v['name']}", run
    for i, v in enumerate(d["reset_tags"]):

        def run(v: Vec = v) -> None:
            echo = bytes.fromhex(v["echo"])
            tag = crypto.reset_tag(crypto.reset_key(bytes.fromhex(v["psk"])), echo)
            check("tag", tag.hex(), v["tag"])
            dg = wire.control_datagram(wire.Reset(echo, [tag]), wire.plain_header())
            check("datagram", dg.hex(), v["datagram"])

        yield f"reset tag {i}", run


# -- receiver and sender ------------------------------------------------------------------------
def receiver_suite(d: Vec) -> Iterable[tuple[str, Callable[[], None]]]:
    for c in d["cases"]:

        def run(c: Vec = c) -> None:
            w = ReceiveWindow(c["initial_seq"], 0.1, far_ahead_check=False)  # keyed: no far_ahead
            for i, e in enumerate(c["events"]):
                at = e.get("at", 0.0)
                if e.get("event") == "piggyback":
                    a = w.piggyback()
                    check(f"event {i} piggyback", [[a.ack, a.sack]] if a else [], e["acks"])
                elif e.get("event") == "ack_delay":
                    a = w.ack_delay_ack()
                    check(f"event {i} ack_delay", [[a.ack, a.sack]] if a else [], e["acks"])
                else:
                    r = w.arrive(e["seq"], at)
                    got = {
                        "kind": r.kind,
                        "full": r.full,
                        "gap": r.gap,
                        "acks": [[x.ack, x.sack] for x in r.acks],
                    }
                    want = {k: e[k] for k in ("kind", "full", "gap", "acks")}
                    check(f"event {i} (seq {e['seq']})", got, want)

        yield c["name"], run


def sender_suite(d: Vec) -> Iterable[tuple[str, Callable[[], None]]]:
    for c in d["cases"]:

        def run(c: Vec = c) -> None:
            log = SentLog(c["first_seq"], c["initial_rtt"], c["ack_delay"], c["reorder_threshold"])
            sent = sorted(c["sent"], key=lambda s: s["seq"])
            for s in sent:
                assert log.next_seq == s["seq"]
                log.on_sent(s["at"])
            spurious_total = 0
            for i, e in enumerate(c["events"]):
                x = e["expect"]
                if e.get("event") == "timer":
                    lost = log.on_timer(e["at"])
                    got = {
                        "lost": lost,
                        "unknown_total": log.unknown_total,
                        "loss_delay": log.loss_delay,
                        "loss_timer": log.loss_timer(),
                    }
                    check(f"event {i} (timer at {e['at']})", got, {k: x[k] for k in got})
                    continue
                r = log.on_ack(e["ack"], e["sack"], e["hold"], e["at"])
                if x["optimistic"]:
                    check(f"event {i} optimistic", r.optimistic, True)
                    continue
                spurious_total += r.spurious
                got = {
                    "optimistic": r.optimistic,
                    "ack_full": r.ack_full,
                    "newly_acked": r.newly_acked,
                    "rtt_sample": r.rtt_sample,
                    "srtt": log.srtt,
                    "rttvar": log.rttvar,
                    "largest_acked": log.largest_acked,
                    "lost": r.lost,
                    "unknown_total": log.unknown_total,
                    "spurious": r.spurious,
                    "loss_delay": log.loss_delay,
                    "loss_timer": log.loss_timer(),
                }
                check(f"event {i} (ack {e['ack']} at {e['at']})", got, {k: x[k] for k in got})

        yield c["name"], run


SUITES: dict[str, Callable[[Vec], Iterable[tuple[str, Callable[[], None]]]]] = {
    "header": header_suite,
    "hold": hold_suite,
    "seqnum": seqnum_suite,
    "control": control_suite,
    "keyed": keyed_suite,
    "receiver": receiver_suite,
    "sender": sender_suite,
    "endpoint": endpoint_suite,
    "server": server_suite,
}


def run_file(path: Path, verbose: bool) -> tuple[int, int, list[str]]:
    d = json.loads(path.read_text())
    if (
        d.get("format") != "tdtp-conformance-vectors"
        or d.get("format_version") not in KNOWN_FORMAT_VERSIONS
    ):
        return 0, 1, [f"unknown format {d.get('format')!r} version {d.get('format_version')!r}"]
    if d.get("protocol_version") != 4:
        return 0, 1, [f"protocol version {d.get('protocol_version')} is not 4"]
    suite = SUITES.get(d["suite"])
    if suite is None:
        return 0, 1, [f"no runner for suite {d['suite']!r}"]
    passed, failed, failures = 0, 0, []
    for name, run in suite(d):
        try:
            run()
            passed += 1
        except MismatchError as e:
            failed += 1
            failures.append(f"{name}: {e}")
        except Exception as e:  # an implementation crash is a failure, never a runner crash
            failed += 1
            failures.append(f"{name}: {type(e).__name__}: {e}")
    return passed, failed, failures


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args(argv)
    files = args.files or sorted(VECTORS.glob("*.json"))
    start = time.perf_counter()
    total_failed = 0
    for f in files:
        passed, failed, failures = run_file(f, args.verbose)
        total_failed += failed
        print(f"{f.name}: {passed} passed, {failed} failed")
        for msg in failures:
            print(f"    FAIL {msg}")
    print(f"total time {time.perf_counter() - start:.2f} s")
    return 0 if total_failed == 0 and files else 1


if __name__ == "__main__":
    sys.exit(main())
