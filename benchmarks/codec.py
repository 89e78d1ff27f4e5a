"""Nanoseconds to encode and decode one 5-byte TDTP header: the struct fast path vs the construct schema.

Usage: ``python benchmarks/codec.py [--seconds 0.2] [--repeat 5] [--json]``

Method. ``timeit`` in this process, one header value (the worked example of docs/PROTOCOL.md 7.1: DATA,
SEQ 0xABC, ACK 0x123, SACK 0x2A, HOLD 31, bytes ``2a f0 48 ea 1f``):

- fast path (what the connection runs): ``tdtp.wire.encode_header(ptype, seq, ack, sack, hold)`` and
  ``tdtp.wire.decode_header(data)``;
- baseline, the schema of record: ``tdtp.wire.schema.Header.build(dict(...))`` and
  ``Header.parse(data)`` (construct's ``BitStruct``).

Each repetition times every path for about ``--seconds`` (the call count is calibrated first); the four
paths take turns within a repetition. Figures are ns per call including timeit's loop (a few ns), medians
over the repetitions; the ratio is construct / struct, repetition by repetition: how many times faster
the fast path is. Both paths are first checked to give the same bytes and fields.

There is no target in issue 6; ``tdtp/wire/schema.py`` says the fast path is "about 70 times faster
per parse".
"""

from __future__ import annotations

import struct
import sys
import timeit
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat

from tdtp.wire import decode_header, encode_header
from tdtp.wire.schema import Header as HeaderSchema

FIELDS = {"ptype": 0, "seq": 0xABC, "ack": 0x123, "sack": 0x2A, "hold": 31}
WIRE = bytes.fromhex("2af048ea1f")
CLAIMED_SPEEDUP = 70.0


def _paths() -> dict[str, Callable[[], object]]:
    ptype, seq, ack, sack, hold = FIELDS.values()
    build = HeaderSchema.build
    parse = HeaderSchema.parse
    fields = dict(FIELDS)
    data = WIRE
    return {
        "encode struct": lambda: encode_header(ptype, seq, ack, sack, hold),
        "encode construct": lambda: build(fields),
        "decode struct": lambda: decode_header(data),
        "decode construct": lambda: parse(data),
    }


_WORD = struct.Struct(">BI")


def _decode_plain(
    data: bytes, unpack: Callable[..., tuple[int, int]] = _WORD.unpack_from
) -> tuple[int, ...]:
    """Not library code: the same decode returning a plain tuple, to show what the NamedTuple costs."""
    hi, lo = unpack(data)
    return (
        hi >> 6,
        ((hi & 0x3F) << 6) | (lo >> 26),
        (lo >> 14) & 0xFFF,
        (lo >> 8) & 0x3F,
        lo & 0xFF,
    )


def check_agreement() -> None:
    assert encode_header(*FIELDS.values()) == WIRE
    assert HeaderSchema.build(FIELDS) == WIRE
    assert tuple(decode_header(WIRE)) == tuple(FIELDS.values())
    parsed = HeaderSchema.parse(WIRE)
    assert tuple(parsed[k] for k in FIELDS) == tuple(FIELDS.values())


def time_ns(fn: Callable[[], object], seconds: float) -> float:
    timer = timeit.Timer(fn)
    probe = 50
    per_call = timer.timeit(probe) / probe
    number = max(10, int(seconds / max(per_call, 1e-9)))
    return timer.timeit(number) / number * 1e9


def main(argv: list[str] | None = None) -> int:
    p = common.parser(__doc__, seconds=0.2, repeat=5, help_seconds="time per path per repetition")
    args = p.parse_args(argv)
    common.warn_if_loaded()
    check_agreement()
    paths = _paths()
    samples: dict[str, list[float]] = {name: [] for name in paths}
    for rep in range(args.repeat):
        print(f"rep {rep + 1}/{args.repeat} ...", file=sys.stderr)
        for name, fn in paths.items():
            samples[name].append(time_ns(fn, args.seconds))
    data = WIRE
    assert _decode_plain(data) == tuple(FIELDS.values())
    plain = [time_ns(lambda: _decode_plain(data), args.seconds) for _ in range(args.repeat)]
    samples["decode sketch: plain tuple"] = plain
    text = (
        "For comparison (not library code): the same decode returning a plain tuple instead of the "
        f"Header NamedTuple takes {Stat.of(plain).median:.0f} ns "
        f"(decode_header: {Stat.of(samples['decode struct']).median:.0f} ns)."
    )
    rows: list[Row] = []
    for op in ("encode", "decode"):
        fast, slow = samples[f"{op} struct"], samples[f"{op} construct"]
        rows.append(
            Row(
                "codec",
                f"{op} one header, struct fast path",
                "ns",
                Stat.of(fast),
                baseline="construct schema",
                baseline_value=Stat.of(slow),
                ratio=Stat.of(common.paired_ratios(slow, fast)),
                ratio_label="x faster",
                ratio_digits=1,
                target=f"none (schema.py claims ~{CLAIMED_SPEEDUP:.0f}x)",
                digits=0,
            )
        )
    details: Json = {"ns_per_call": samples, "header": FIELDS, "wire": WIRE.hex()}
    return common.emit("codec", args, rows, details=details, text=text)


if __name__ == "__main__":
    sys.exit(main())
