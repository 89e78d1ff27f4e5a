"""``tdtp bandwidth``: the paper's figure-5 model (eqs. 3-8, :mod:`tdtp.analysis.bandwidth`) on the command line.

What one direction's application data costs on the wire, both directions together, for TCP, UDP,
Trinomial (separate ACKs) and TDTP (piggybacked ACKs)::

    tdtp bandwidth                              # the paper's 400 kbit/s each way, a few data sizes
    tdtp bandwidth --size 100 --rate 800        # one row: 100-byte samples at 1 kHz
    tdtp bandwidth --size 1-1000 --csv          # every size, bit/s, for a spreadsheet
    tdtp bandwidth --encapsulation all --png figure5.png

``--size`` takes data field sizes in bytes (``100``, ``20,100,500`` or a range ``1-1000``); ``--rate``
the application data rate in each direction (kbit/s, or with a unit: ``400kbit``, ``1mbit``,
``50000bit``); ``--encapsulation`` where the 5-byte header sits: ``native`` (on IPv4, the paper's),
``udp`` (UDP/IPv4, this implementation's), ``udp6`` (UDP/IPv6) or ``all``. A bad argument prints one
line and exits with status 2.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from tdtp.analysis.bandwidth import (
    PAPER_APP_RATE,
    Encapsulation,
    Figure5Row,
    PlotUnavailableError,
    eq8_separate_ack_factor,
    figure5_table,
    format_csv,
    plot_figure5,
    schemes,
)
from tdtp.cli.parser import EXIT_USAGE, CommandParser
from tdtp.config import MAX_UDP_PAYLOAD

__all__ = ["bandwidth_main", "build_parser"]

TABLE_SIZES = (10, 20, 50, 100, 200, 500, 1000)
"""Data sizes of the default table (the PNG draws every size from 1 to 1000 bytes)."""
_RANGE = re.compile(r"^(\d+)-(\d+)$")
_RATE = re.compile(
    r"^\s*([0-9]*\.?[0-9]+(?:e[+-]?\d+)?)\s*(bit|kbit|mbit|gbit)?(?:/s|ps)?\s*$", re.I
)
_UNITS = {None: 1e3, "bit": 1.0, "kbit": 1e3, "mbit": 1e6, "gbit": 1e9}
_SCHEME_NAMES = ("TCP", "UDP", "Trinomial", "TDTP")


def _sizes(text: str) -> tuple[int, ...]:
    sizes: list[int] = []
    for raw in text.split(","):
        part = raw.strip()
        match = _RANGE.match(part)
        if match:
            low, high = int(match.group(1)), int(match.group(2))
            if low > high:
                raise argparse.ArgumentTypeError(f"the range {part!r} runs backwards")
            sizes.extend(range(low, high + 1))
        elif part.isdigit():
            sizes.append(int(part))
        else:
            raise argparse.ArgumentTypeError(
                f"{part!r} is not a size in bytes: give 100, 20,100,500 or 1-1000"
            )
    if not sizes or min(sizes) < 1 or max(sizes) > MAX_UDP_PAYLOAD:
        raise argparse.ArgumentTypeError(
            f"data sizes must be 1..{MAX_UDP_PAYLOAD} bytes, got {text!r}"
        )
    return tuple(dict.fromkeys(sizes))


def _rate(text: str) -> float:
    match = _RATE.match(text)
    if not match:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a rate: give kbit/s (400) or a unit (400kbit, 1mbit)"
        )
    unit = match.group(2).lower() if match.group(2) else None
    value = float(match.group(1)) * _UNITS[unit]
    if not 0 < value <= 1e12:
        raise argparse.ArgumentTypeError(f"the rate must be positive, got {text!r}")
    return value


def build_parser(prog: str = "tdtp bandwidth") -> argparse.ArgumentParser:
    parser = CommandParser(
        prog=prog,
        description="Wire bandwidth of TCP, UDP, Trinomial and TDTP for bilateral teleoperation "
        "data (the paper's eqs. 3-8 and figure 5), both directions together.",
    )
    parser.add_argument(
        "--size",
        type=_sizes,
        default=None,
        help="data field size(s) in bytes: 100, 20,100,500 or 1-1000 "
        f"(default: {','.join(map(str, TABLE_SIZES))}; the PNG: 1-1000)",
    )
    parser.add_argument(
        "--rate",
        type=_rate,
        default=PAPER_APP_RATE,
        help="application data rate in each direction: kbit/s, or 400kbit, 1mbit "
        "(default: the paper's 400)",
    )
    parser.add_argument(
        "--encapsulation",
        choices=(*(e.value for e in Encapsulation), "all"),
        default="native",
        help="under the 5-byte header: native (IPv4, the paper's), udp (UDP/IPv4), "
        "udp6 (UDP/IPv6), or all (default: native)",
    )
    output = parser.add_mutually_exclusive_group()
    output.add_argument("--csv", action="store_true", help="print CSV (bit/s) instead of a table")
    output.add_argument("--json", action="store_true", help="print JSON (bit/s) instead of a table")
    parser.add_argument("--png", type=Path, metavar="FILE", help="also draw figure 5 into FILE")
    return parser


def _table(rows: Sequence[Figure5Row], rate: float) -> str:
    head = (
        f"{'encapsulation':<13} {'data B':>7} {'pkt/s':>9}  "
        + "  ".join(f"{name:>9}" for name in _SCHEME_NAMES)
        + f"  {'TDTP saves':>10}"
    )
    lines = [
        f"wire bandwidth in Mbit/s, both directions, {rate / 1e3:g} kbit/s of data each way "
        "(tdtp.analysis.bandwidth, eqs. 3-8)",
        head,
        "-" * len(head),
    ]
    for row in rows:
        values = row.by_scheme()
        tdtp_header = schemes(row.encapsulation)[3].header
        saving = 1.0 - 1.0 / eq8_separate_ack_factor(row.data_size, tdtp_header)
        lines.append(
            f"{row.encapsulation.label:<13} {row.data_size:>7} {row.packet_rate:>9.1f}  "
            + "  ".join(f"{values[name] / 1e6:>9.3f}" for name in _SCHEME_NAMES)
            + f"  {saving:>9.1%}"
        )
    lines.append("TDTP saves: the share of Trinomial's bandwidth piggybacking saves (eq. 8).")
    return "\n".join(lines)


def bandwidth_main(argv: Sequence[str]) -> int:
    """Entry point of ``tdtp bandwidth``; returns the process exit code."""
    args = build_parser().parse_args(list(argv))
    encapsulations = (
        tuple(Encapsulation)
        if args.encapsulation == "all"
        else (Encapsulation(args.encapsulation),)
    )
    sizes: tuple[int, ...] = args.size if args.size is not None else TABLE_SIZES
    rows = figure5_table(sizes, app_rate=args.rate, encapsulations=encapsulations)
    if args.csv:
        sys.stdout.write(format_csv(rows))
    elif args.json:
        data = {
            "app_rate_bps": args.rate,
            "rows": [
                {"encapsulation": r.encapsulation.value, "data_size": r.data_size}
                | {"packets_per_s": r.packet_rate}
                | {f"{k.lower()}_bps": v for k, v in r.by_scheme().items()}
                for r in rows
            ],
        }
        print(json.dumps(data, indent=2))
    else:
        print(_table(rows, args.rate))
    if args.png is not None:
        try:
            path = plot_figure5(
                args.png,
                data_sizes=args.size if args.size is not None else range(1, 1001),
                app_rate=args.rate,
                encapsulations=encapsulations,
            )
        except PlotUnavailableError as exc:
            print(f"tdtp bandwidth: {exc}", file=sys.stderr)
            return 1
        except (OSError, ValueError) as exc:
            print(f"tdtp bandwidth: cannot write {args.png}: {exc}", file=sys.stderr)
            return EXIT_USAGE
        print(f"wrote {path}", file=sys.stderr if (args.csv or args.json) else sys.stdout)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(bandwidth_main(sys.argv[1:]))
