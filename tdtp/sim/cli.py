"""``tdtp simulate NAME --out DIR [--json] [--seed N] [--duration S]``: run a scenario, write its JSON
and figures into DIR, print a summary (or, with ``--json``, the summary as JSON).

NAME is ``paper``, ``friendliness``, ``fairness``, ``best-effort`` or ``all``. ``--duration`` means
the run length for ``paper`` (default 100 s) and ``best-effort`` (60 s), the length of each case for
``friendliness`` (60 s), and the time after the last flow started for ``fairness`` (40 s).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from tdtp.cli_parser import CommandParser
from tdtp.sim.scenarios import (
    MS,
    SCENARIOS,
    SCHEMES,
    SM,
    BestEffortResult,
    FairnessResult,
    FriendlinessResult,
    PaperResult,
    best_effort,
    fairness,
    friendliness,
    paper,
)

__all__ = ["build_parser", "simulate_main"]

_NAMES = (*SCENARIOS, "all")


def build_parser(prog: str = "tdtp simulate") -> argparse.ArgumentParser:
    parser = CommandParser(
        prog=prog,
        description="Run a virtual-time simulation of the paper's experiments with the real protocol "
        "code; write NAME.json and PNG figures into --out.",
    )
    parser.add_argument("name", choices=_NAMES, help="scenario to run ('all' runs every one)")
    parser.add_argument("--out", type=Path, default=Path("."), help="directory for JSON and PNGs")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument("--seed", type=int, default=1, help="random seed (runs are deterministic)")
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        help="seconds of simulated time (see the module help for each scenario's meaning)",
    )
    parser.add_argument(
        "--schemes",
        default="tdtp,trinomial,tfrc",
        help=f"comma-separated schemes among {', '.join(SCHEMES)}",
    )
    parser.add_argument("--no-plots", action="store_true", help="write the JSON only")
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="run up to this many scenarios at once, in separate processes (with 'all')",
    )
    return parser


def _kwargs(args: argparse.Namespace) -> dict[str, Any]:
    schemes = tuple(s.strip() for s in args.schemes.split(",") if s.strip())
    kwargs: dict[str, Any] = {"seed": args.seed, "schemes": schemes}
    return kwargs


def _run(name: str, args: argparse.Namespace) -> Any:
    kwargs = _kwargs(args)
    if args.duration is not None:
        kwargs["settle" if name == "fairness" else "duration"] = args.duration
    runners: dict[str, Callable[..., Any]] = {
        "paper": paper,
        "friendliness": friendliness,
        "fairness": fairness,
        "best-effort": best_effort,
    }
    return runners[name](**kwargs)


def _plot(name: str, result: Any, out: Path) -> list[Path]:
    from tdtp.sim import plots  # noqa: PLC0415 - matplotlib only when figures are wanted

    if name == "paper":
        return plots.plot_paper(result, out)
    if name == "friendliness":
        return [plots.plot_friendliness(result, out / "friendliness.png")]
    if name == "fairness":
        return [plots.plot_fairness(result, out / "fairness.png")]
    return [plots.plot_best_effort(result, out / "best_effort.png")]


def _fmt(value: float | None, spec: str = ".1f") -> str:
    return "-" if value is None else format(value, spec)


def _paper_text(result: PaperResult) -> list[str]:
    lines = ["paper (figures 7 and 8): mean over the run; 'free' = no TCP master->slave"]
    for run in result.runs.values():
        lines.append(f"  {run.label}  [wall {run.wall_time:.1f} s, {run.events} events]")
        for direction in (MS, SM):
            s = run.summaries[direction]["all"]
            free = run.summaries[direction]["free"]
            lines.append(
                f"    {direction}: goodput {s.goodput_kbps:6.1f} kbit/s ({s.delivered_pps:5.1f} samples/s), "
                f"free {free.goodput_kbps:6.1f}, loss {100 * s.loss_ratio:4.1f} %, "
                f"delay mean {1000 * s.mean_delay:5.1f} ms p95 {1000 * s.p95_delay:5.1f} ms"
            )
        tcp = ", ".join(f"{d} {t.goodput_kbps:.0f}" for d, t in run.tcp.items())
        lines.append(f"    TCP goodput kbit/s: {tcp}")
    for pair, windows in result.ratios.items():
        parts = ", ".join(
            f"{w}: {_fmt(v[MS], '.2f')} / {_fmt(v[SM], '.2f')}" for w, v in windows.items()
        )
        lines.append(f"  goodput ratio {pair} (M->S / S->M): {parts}")
    return lines


def _friendliness_text(result: FriendlinessResult) -> list[str]:
    lines = ["friendliness: tdtp/TCP packet-rate ratio (eq. 2's prediction at tdtp's p and RTT)"]
    for case in result.cases:
        lines.append(
            f"  {case.scheme:9s} {case.capacity_mbps:4g} Mbit/s {case.rtt_ms:5g} ms: "
            f"ratio {case.ratio_pps:4.2f} (eq. 2: {case.eq2_ratio:4.2f}), tdtp {case.tdtp_pps:6.1f} pkt/s, "
            f"TCP {case.tcp_pps:6.1f} pkt/s, TCP loss {100 * case.tcp_loss:4.1f} %"
        )
    return lines


def _fairness_text(result: FairnessResult) -> list[str]:
    lines = ["fairness: Jain's index of master-to-slave goodput after convergence (target >= 0.95)"]
    for run in result.runs:
        lines.append(
            f"  {run.scheme:9s} N={run.flows}: mean {run.mean_jain_ms:.3f}, min {run.min_jain_ms:.3f}, "
            f"of means {run.jain_of_means_ms:.3f}; per flow kbit/s "
            + " ".join(f"{v:.0f}" for v in run.per_flow_kbps)
        )
    return lines


def _best_effort_text(result: BestEffortResult) -> list[str]:
    lines = ["best effort: UDP source on, off, on; tdtp master-to-slave goodput"]
    for run in result.runs:
        lines.append(
            f"  {run.scheme:9s} congested {run.congested_level_kbps:5.0f} kbit/s, free "
            f"{run.free_level_kbps:5.0f} kbit/s; fills 50 %/90 % in {_fmt(run.fill_time_50)}/"
            f"{_fmt(run.fill_time_90)} s, gives back in {_fmt(run.give_back_time)} s; UDP loss "
            f"{100 * run.cbr_loss_after_restart:.1f} % in the 2 s after its restart"
        )
    return lines


def summary_text(result: Any) -> str:
    """A human-readable summary of a scenario result."""
    if isinstance(result, PaperResult):
        lines = _paper_text(result)
    elif isinstance(result, FriendlinessResult):
        lines = _friendliness_text(result)
    elif isinstance(result, FairnessResult):
        lines = _fairness_text(result)
    elif isinstance(result, BestEffortResult):
        lines = _best_effort_text(result)
    else:
        raise TypeError(f"not a scenario result: {type(result).__name__}")
    return "\n".join(lines)


def simulate_main(argv: Sequence[str]) -> int:
    """Entry point of ``tdtp simulate``; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(list(argv))
    names = list(SCENARIOS) if args.name == "all" else [args.name]
    unknown = [k for k in _kwargs(args)["schemes"] if k not in SCHEMES]
    if unknown or not _kwargs(args)["schemes"]:
        parser.error(f"unknown scheme(s) {unknown}; choose among {', '.join(SCHEMES)}")
    if args.duration is not None and not args.duration > 0:
        parser.error(f"--duration must be positive, got {args.duration}")
    if args.jobs < 1:
        parser.error(f"--jobs must be at least 1, got {args.jobs}")
    out: Path = args.out
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        parser.error(f"--out {out}: cannot create the directory ({exc.strerror or exc})")
    if args.jobs > 1 and len(names) > 1:
        with ProcessPoolExecutor(max_workers=min(args.jobs, len(names))) as pool:
            done = list(pool.map(_timed_run, names, [args] * len(names)))
    else:
        done = [_timed_run(name, args) for name in names]
    summaries: dict[str, Any] = {}
    status = 0
    for name, (result, wall) in zip(names, done, strict=True):
        json_path = out / f"{name.replace('-', '_')}.json"
        json_path.write_text(result.to_json() + "\n")
        figures: list[Path] = []
        if not args.no_plots:
            try:
                figures = _plot(name, result, out)
            except ImportError as exc:
                print(f"tdtp simulate: {exc}", file=sys.stderr)
                status = 1
        summaries[name] = {
            "wall_time_s": round(wall, 2),
            "json": str(json_path),
            "figures": [str(p) for p in figures],
            "headline": result.headline(),
        }
        if not args.json:
            print(summary_text(result))
            print(f"  wrote {json_path}" + "".join(f", {p}" for p in figures) + f" ({wall:.1f} s)")
    if args.json:
        print(json.dumps(summaries if len(names) > 1 else summaries[names[0]], indent=2))
    return status


def _timed_run(name: str, args: argparse.Namespace) -> tuple[Any, float]:
    started = time.perf_counter()
    result = _run(name, args)
    return result, time.perf_counter() - started


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(simulate_main(sys.argv[1:]))
