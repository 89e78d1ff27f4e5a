"""Reproduce the paper's figure 5: wire bandwidth of TCP, UDP, Trinomial and TDTP vs data field size.

Usage: ``python benchmarks/bandwidth_figure.py [--out benchmarks/results] [--json]``

Computed with ``tdtp.analysis.bandwidth`` (the paper's eqs. 3-8) at 400 kbit/s of application data in each
direction, data sizes 1..1000 bytes, for the paper's native encapsulation (the 5-byte header on IP) and
ours (over UDP). Writes into ``--out``:

- ``figure5.png``: both panels (needs matplotlib: the ``plot`` extra; skipped with a message without it);
- ``figure5.csv``: every data size, both encapsulations, bit/s;
- ``figure5.md``: a Markdown table at selected sizes, Mbit/s.

The rows check the paper's worked example (100-byte data, 500 packets/s each way: TDTP 1.000 Mbit/s,
UDP 1.024, Trinomial 1.200, TCP 1.440) against the model. Nothing is timed; ``--seconds`` and
``--repeat`` are accepted for the suite's uniform command line and ignored.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Row, Stat

from tdtp.analysis.bandwidth import (
    PAPER_APP_RATE,
    Encapsulation,
    PlotUnavailableError,
    figure5_table,
    format_csv,
    format_markdown,
    plot_figure5,
)

PAPER_EXAMPLE = {"TDTP": 1.000e6, "UDP": 1.024e6, "Trinomial": 1.200e6, "TCP": 1.440e6}
TABLE_SIZES = (1, 2, 5, 10, 20, 40, 50, 100, 200, 500, 1000)


def main(argv: list[str] | None = None) -> int:
    p = common.parser(__doc__, seconds=0.0, repeat=1, help_seconds="ignored")
    p.add_argument(
        "--out", type=Path, default=common.RESULTS, help="output folder (benchmarks/results)"
    )
    args = p.parse_args(argv)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    rows_all = figure5_table()
    common.write_text(out / "figure5.csv", format_csv(rows_all))
    table = format_markdown(figure5_table(TABLE_SIZES))
    common.write_text(
        out / "figure5.md",
        f"Figure 5: wire bandwidth, both directions, {PAPER_APP_RATE / 1e3:g} kbit/s of "
        "application data each way (tdtp.analysis.bandwidth).\n\n" + table + "\n",
    )
    try:
        png: str = str(plot_figure5(out / "figure5.png"))
    except PlotUnavailableError as exc:
        png = f"not drawn: {exc}"
        print(png, file=sys.stderr)
    (example,) = figure5_table([100], encapsulations=[Encapsulation.NATIVE])
    computed = example.by_scheme()
    rows = []
    for name, paper in PAPER_EXAMPLE.items():
        value = computed[name] / 1e6
        rows.append(
            Row(
                "bandwidth_figure",
                f"{name}, 100 B at 400 kbit/s each way (native, eq. 6-8)",
                "Mbit/s",
                Stat.of([value]),
                baseline="paper's figure 5 example",
                baseline_value=Stat.of([paper / 1e6]),
                ratio=Stat.of([value / (paper / 1e6)]),
                ratio_label="model/paper",
                ratio_digits=4,
                target="= paper",
                meets=abs(value - paper / 1e6) < 5e-4,
                digits=3,
            )
        )
    drawn = f"Figure 5 written to {png}" if not png.startswith("not drawn") else f"Figure 5 {png}"
    text = f"{drawn}; tables figure5.csv and figure5.md in {out}.\n\n{table}"
    details = {"png": png, "csv": str(out / "figure5.csv"), "markdown": str(out / "figure5.md")}
    return common.emit("bandwidth_figure", args, rows, details=details, text=text)


if __name__ == "__main__":
    sys.exit(main())
