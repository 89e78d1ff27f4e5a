"""``tdtp simulate NAME --out DIR [--json] [--jobs N] ...``: run scenarios, write their JSON and figures
into DIR, print a summary (or, with ``--json``, the summary as JSON).

NAME is ``paper``, ``lockout``, ``friendliness``, ``fairness``, ``best-effort`` or ``all``.

* ``paper`` runs the paper's figure 6-8 experiment under one or more readings (``--readings``, default
  ``literal``; ``all`` for every named one), each over ``--seeds`` seeds (10) starting at ``--seed``,
  and reports per reading the goodput ratio TDTP/Trinomial with its 95 % interval. ``--tcp-directions``,
  ``--tcp-variant``, ``--ack-form``, ``--queue`` and ``--send-jitter`` override a reading's parameters.
* ``lockout`` runs the literal reading (``--queue`` may change its queues) for TDTP, TDTP with TFRC and
  TDTP with the default teleop controller over ``--seeds`` seeds (20) with the
  current controllers, and over the first 10 of them with the controllers before the lock-out fix.
* ``friendliness``, ``fairness`` and ``best-effort`` run once, at ``--seed``.
* ``all`` runs every one of them, ``paper`` with every reading (TDTP with TFRC under the literal one
  only; friendliness and fairness for TDTP and TDTP with TFRC); one pool of ``--jobs`` processes runs
  every simulation once (``make figures``).

``--duration`` is the run length for ``paper``, ``lockout`` (100 s) and ``best-effort`` (60 s), the
length of each case for ``friendliness`` (60 s), and the time after the last flow started for
``fairness`` (40 s).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path
from typing import Any

from tdtp.cli.parser import CommandParser
from tdtp.sim.readings import ACK_FORMS, QUEUE_UNITS, READINGS, TCP_DIRECTIONS, Reading
from tdtp.sim.scenarios import (
    MS,
    SCHEMES,
    SM,
    BestEffortResult,
    FairnessResult,
    FriendlinessResult,
    best_effort,
    fairness,
    friendliness,
)
from tdtp.sim.study import (
    BOTH,
    DEFAULT_SEEDS,
    EARLIER_SEEDS,
    LOCKOUT_SEEDS,
    LockoutStudy,
    PaperStudy,
    PaperTask,
    RunRecord,
    lockout_study,
    lockout_tasks,
    paper_study,
    paper_tasks,
    run_task,
)
from tdtp.sim.tcp import TCP_VARIANTS

__all__ = ["build_parser", "simulate_main", "summary_text"]

_SINGLE = ("friendliness", "fairness", "best-effort")
_NAMES = ("paper", "lockout", *_SINGLE, "all")
_OVERRIDES = {
    "tcp_directions": "tcp-directions",
    "tcp_variant": "tcp-variant",
    "ack_form": "ack-form",
    "queue_unit": "queue",
    "send_jitter": "send-jitter",
}


class _UsageError(Exception):
    """A bad argument: one line on stderr, exit status 2."""


def build_parser(prog: str = "tdtp simulate") -> argparse.ArgumentParser:
    parser = CommandParser(
        prog=prog,
        description="Run a virtual-time simulation of the paper's experiments with the real protocol "
        "code; write NAME.json and PNG figures into --out.",
    )
    parser.add_argument("name", choices=_NAMES, help="scenario to run ('all' runs every one)")
    parser.add_argument("--out", type=Path, default=Path("."), help="directory for JSON and PNGs")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    parser.add_argument(
        "--seed", type=int, default=1, help="the (first) random seed; runs are deterministic"
    )
    parser.add_argument(
        "--seeds",
        type=int,
        default=None,
        help=f"seeds per configuration for paper ({DEFAULT_SEEDS}) and lockout ({LOCKOUT_SEEDS})",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        help="seconds of simulated time (see the module help for each scenario's meaning)",
    )
    parser.add_argument(
        "--schemes",
        default=None,
        help=f"comma-separated schemes among {', '.join(SCHEMES)} "
        "(default: tdtp,trinomial,tfrc; lockout: tdtp,tfrc,teleop)",
    )
    parser.add_argument(
        "--earlier-seeds",
        type=int,
        default=None,
        help=f"lockout: seeds for the controllers before the fix (default {EARLIER_SEEDS})",
    )
    parser.add_argument("--no-plots", action="store_true", help="write the JSON only")
    parser.add_argument(
        "--jobs", type=int, default=1, help="simulations to run at once, in separate processes"
    )
    reading = parser.add_argument_group("paper: how to read the paper (docs/REPRODUCTION.md)")
    reading.add_argument(
        "--readings",
        default="literal",
        help=f"comma-separated among {', '.join(READINGS)}, or 'all' (default: literal)",
    )
    reading.add_argument("--tcp-directions", choices=TCP_DIRECTIONS, help="override: TCP where")
    reading.add_argument("--tcp-variant", choices=TCP_VARIANTS, help="override: TCP variant")
    reading.add_argument("--ack-form", choices=ACK_FORMS, help="override: Trinomial's ACKs")
    reading.add_argument("--queue", choices=QUEUE_UNITS, help="override: queues count these")
    reading.add_argument(
        "--send-jitter", type=float, metavar="MS", help="override: send jitter, milliseconds"
    )
    return parser


# -- arguments ----------------------------------------------------------------------------------------


def _schemes(args: argparse.Namespace, default: Sequence[str]) -> tuple[str, ...]:
    if args.schemes is None:
        return tuple(default)
    schemes = tuple(s.strip() for s in args.schemes.split(",") if s.strip())
    unknown = [s for s in schemes if s not in SCHEMES]
    if unknown or not schemes:
        raise _UsageError(f"unknown scheme(s) {unknown}; choose among {', '.join(SCHEMES)}")
    return schemes


def _readings(args: argparse.Namespace) -> list[Reading]:
    names = list(READINGS) if args.readings == "all" else args.readings.split(",")
    unknown = [n for n in names if n not in READINGS]
    if unknown or not names:
        raise _UsageError(f"unknown reading(s) {unknown}; choose among {', '.join(READINGS)}, all")
    overrides: dict[str, Any] = {}
    for field in _OVERRIDES:
        value = getattr(args, field if field != "queue_unit" else "queue")
        if value is not None:
            overrides[field] = value / 1000.0 if field == "send_jitter" else value
    readings = []
    for name in names:
        base = READINGS[name]
        if not overrides:
            readings.append(base)
            continue
        label = ",".join(
            f"{_OVERRIDES[k]}={v * 1000:g}ms" if k == "send_jitter" else f"{_OVERRIDES[k]}={v}"
            for k, v in overrides.items()
        )
        try:
            readings.append(dataclasses.replace(base, name=f"{name}[{label}]", **overrides))
        except ValueError as exc:
            raise _UsageError(str(exc)) from None
    return readings


def _lockout_reading(args: argparse.Namespace) -> Reading:
    """The literal reading, with the overrides given (``--queue bytes`` for byte-counted queues)."""
    if args.readings not in ("literal", None):
        raise _UsageError("lockout runs the literal reading; change it with --queue and the like")
    probe = argparse.Namespace(**{**vars(args), "readings": "literal"})
    return _readings(probe)[0]


def _seeds(args: argparse.Namespace, default: int) -> list[int]:
    count = default if args.seeds is None else args.seeds
    if count < 1:
        raise _UsageError(f"--seeds must be at least 1, got {count}")
    return list(range(args.seed, args.seed + count))


def _check(args: argparse.Namespace) -> None:
    if args.duration is not None and not args.duration > 0:
        raise _UsageError(f"--duration must be positive, got {args.duration}")
    if args.jobs < 1:
        raise _UsageError(f"--jobs must be at least 1, got {args.jobs}")
    if args.name in _SINGLE and args.seeds is not None:
        raise _UsageError(f"{args.name} runs once: use --seed, not --seeds")


# -- running ------------------------------------------------------------------------------------------

_RUNNERS: dict[str, Callable[..., Any]] = {
    "friendliness": friendliness,
    "fairness": fairness,
    "best-effort": best_effort,
}


def _single_parts(name: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    """A single-seed scenario cut into independent parts (per scheme, per flow count)."""
    kwargs: dict[str, Any] = {"seed": args.seed}
    if args.duration is not None:
        kwargs["settle" if name == "fairness" else "duration"] = args.duration
    default: tuple[str, ...] = ("tdtp", "trinomial", "tfrc")
    if args.name == "all" and name in ("friendliness", "fairness"):
        # The claims these check are TDTP's (trinomial or TFRC); the Trinomial scheme's own
        # friendliness and fairness are not the paper's, and make figures has five minutes.
        default = ("tdtp", "tfrc")
    schemes = _schemes(args, default)
    if name == "fairness":
        return [kwargs | {"schemes": (s,), "flow_counts": (n,)} for n in (2, 4, 8) for s in schemes]
    return [kwargs | {"schemes": (s,)} for s in schemes]


def _run_part(name: str, kwargs: dict[str, Any]) -> Any:
    return _RUNNERS[name](**kwargs)


def _part_cost(name: str, kwargs: dict[str, Any]) -> float:
    """A rough relative cost (a 100 s paper run is about 100), to start the longest first."""
    if name == "fairness":
        n: int = kwargs["flow_counts"][0]
        settle: float = kwargs.get("settle", 40.0)
        return n * ((n - 1) * 5.0 + settle) / 2.0
    duration: float = kwargs.get("duration", 60.0)
    return 9 * duration * 0.8 if name == "friendliness" else duration * 1.5


def _merge(name: str, parts: list[Any]) -> Any:
    first = parts[0]
    if name == "friendliness":
        cases = [c for p in parts for c in p.cases]
        params = first.params | {"schemes": [s for p in parts for s in p.params["schemes"]]}
        return FriendlinessResult(params=params, cases=cases)
    if name == "fairness":
        runs = [r for p in parts for r in p.runs]
        counts = list(dict.fromkeys(n for p in parts for n in p.params["flow_counts"]))
        schemes = list(dict.fromkeys(s for p in parts for s in p.params["schemes"]))
        params = first.params | {"flow_counts": counts, "schemes": schemes}
        return FairnessResult(params=params, runs=runs)
    runs = [r for p in parts for r in p.runs]
    params = first.params | {"schemes": [s for p in parts for s in p.params["schemes"]]}
    return BestEffortResult(params=params, runs=runs)


def _execute(names: list[str], args: argparse.Namespace) -> tuple[dict[str, Any], float]:
    """Run every scenario of ``names``: one pool, every simulation once, the longest first."""
    paper_seeds = _seeds(args, DEFAULT_SEEDS) if "paper" in names else []
    lockout_seeds = _seeds(args, LOCKOUT_SEEDS) if "lockout" in names else []
    duration = args.duration if args.duration is not None else 100.0
    tasks: list[PaperTask] = []
    readings = _readings(args) if "paper" in names else []
    paper_schemes: Sequence[str] | dict[str, Sequence[str]] = _schemes(
        args, ("tdtp", "trinomial", "tfrc")
    )
    if args.name == "all" and args.schemes is None:
        # TFRC is the paper's future work: under the literal reading only, which the lock-out
        # check runs anyway; every reading's ratio needs TDTP and Trinomial.
        paper_schemes = {
            r.name: ("tdtp", "trinomial", "tfrc") if r.name == "literal" else ("tdtp", "trinomial")
            for r in readings
        }
    lockout_schemes = _schemes(args, ("tdtp", "tfrc", "teleop"))
    lockout_reading = _lockout_reading(args) if "lockout" in names else None
    if "paper" in names:
        tasks += paper_tasks(readings, seeds=paper_seeds, schemes=paper_schemes, duration=duration)
    earlier_seeds = None
    if args.earlier_seeds is not None:
        if args.earlier_seeds < 1:
            raise _UsageError(f"--earlier-seeds must be at least 1, got {args.earlier_seeds}")
        earlier_seeds = list(range(args.seed, args.seed + args.earlier_seeds))
    if "lockout" in names:
        tasks += lockout_tasks(
            seeds=lockout_seeds,
            earlier_seeds=earlier_seeds,
            schemes=lockout_schemes,
            reading=lockout_reading,
            duration=duration,
        )
    unique = {t.key(): t for t in tasks}
    jobs: list[tuple[float, str, Any]] = [(t.cost(), "task", t) for t in unique.values()]
    single = [n for n in names if n in _SINGLE]
    for name in single:
        for kwargs in _single_parts(name, args):
            jobs.append((_part_cost(name, kwargs), name, kwargs))
    jobs.sort(key=lambda job: -job[0])
    started = time.perf_counter()
    outputs: list[Any] = []
    if args.jobs > 1 and len(jobs) > 1:
        with ProcessPoolExecutor(max_workers=min(args.jobs, len(jobs))) as pool:
            futures: list[Future[Any]] = [
                pool.submit(run_task, payload)
                if kind == "task"
                else pool.submit(_run_part, kind, payload)
                for _, kind, payload in jobs
            ]
            outputs = [f.result() for f in futures]
    else:
        outputs = [
            run_task(payload) if kind == "task" else _run_part(kind, payload)
            for _, kind, payload in jobs
        ]
    wall = time.perf_counter() - started
    records: dict[tuple[Any, ...], RunRecord] = {}
    parts: dict[str, list[tuple[int, Any]]] = {n: [] for n in single}
    order = {n: [repr(k) for k in _single_parts(n, args)] for n in single}
    for (_, kind, payload), output in zip(jobs, outputs, strict=True):
        if kind == "task":
            records[payload.key()] = output
        else:
            parts[kind].append((order[kind].index(repr(payload)), output))
    results: dict[str, Any] = {}
    if "paper" in names:
        results["paper"] = paper_study(
            readings, seeds=paper_seeds, schemes=paper_schemes, duration=duration, records=records
        )
    if "lockout" in names:
        results["lockout"] = lockout_study(
            seeds=lockout_seeds,
            earlier_seeds=earlier_seeds,
            schemes=lockout_schemes,
            reading=lockout_reading,
            duration=duration,
            records=records,
        )
    for name in single:
        results[name] = _merge(name, [out for _, out in sorted(parts[name], key=lambda x: x[0])])
    return {n: results[n] for n in names}, wall


# -- output -------------------------------------------------------------------------------------------


def _figure_jobs(name: str, result: Any, out: Path) -> list[Any]:
    """The figures of one scenario as (function, arguments) pairs."""
    from tdtp.sim import plots  # noqa: PLC0415 - matplotlib only when figures are wanted

    if name == "paper":
        return plots.study_figure_jobs(result, out)
    if name == "lockout":
        return [
            (plots.plot_lockout, (result, out / "lockout.png")),
            (plots.plot_lockout_trace, (result, out / "lockout_trace.png")),
        ]
    function = {
        "friendliness": plots.plot_friendliness,
        "fairness": plots.plot_fairness,
        "best-effort": plots.plot_best_effort,
    }[name]
    return [(function, (result, out / f"{name.replace('-', '_')}.png"))]


def _draw(job: Any) -> Path:
    function, args = job
    path: Path = function(*args)
    return path


def _draw_all(results: dict[str, Any], out: Path, jobs: int) -> dict[str, list[Path]]:
    """Every figure of every scenario, ``jobs`` processes at a time; raises ImportError without
    matplotlib."""
    from tdtp.sim.plots import ensure_matplotlib  # noqa: PLC0415 - matplotlib only when wanted

    ensure_matplotlib()
    per_name = {name: _figure_jobs(name, result, out) for name, result in results.items()}
    flat = [(name, job) for name, figure_jobs in per_name.items() for job in figure_jobs]
    if jobs > 1 and len(flat) > 1:
        with ProcessPoolExecutor(max_workers=min(jobs, len(flat))) as pool:
            paths = list(pool.map(_draw, [job for _, job in flat]))
    else:
        paths = [_draw(job) for _, job in flat]
    drawn: dict[str, list[Path]] = {name: [] for name in results}
    for (name, _), path in zip(flat, paths, strict=True):
        drawn[name].append(path)
    return drawn


def _num(value: float, spec: str = ".0f") -> str:
    return format(value, spec) if math.isfinite(value) else "-"


def _paper_text(study: PaperStudy) -> list[str]:
    seeds = len(study.params["seeds"])
    lines = [
        f"paper (figures 6-8): {seeds} seed{'' if seeds == 1 else 's'} per configuration; "
        "median [95 % interval] over the seeds"
    ]
    for name, summary in study.readings.items():
        lines.append(f"  reading '{name}': {summary.reading.describe()}")
        for key, s in summary.schemes.items():
            parts = []
            for d in (MS, SM):
                g = s.goodput_kbps[d]
                parts.append(
                    f"{d} {g['all'].format('.0f')} kbit/s (TCP on {_num(g['tcp_on'].median)}, "
                    f"off {_num(g['tcp_off'].median)}), loss {_num(100 * s.loss_ratio[d].median, '.1f')} %, "
                    f"delay {_num(s.mean_delay_ms[d].median)} ms"
                )
            lines.append(f"    {key:9s} " + "; ".join(parts))
            starved = {d: v for d, v in s.starved_seeds.items() if v}
            if starved:
                lines.append(f"    {'':9s} TCP STARVED in seeds {starved}")
        for pair, ratio in summary.ratios.items():
            for d in (MS, SM, BOTH):
                w = ratio.all_seeds[d]
                lines.append(
                    f"    goodput ratio {pair} {d}: {w['all'].format()} over the run, "
                    f"{w['tcp_on'].format()} with TCP on, {w['tcp_off'].format()} with TCP off"
                )
            if ratio.starved_seeds:
                clean = ratio.without_starved
                lines.append(
                    f"    (seeds {ratio.starved_seeds} starved a TCP flow; without them M->S "
                    f"{clean[MS]['all'].format()}, S->M {clean[SM]['all'].format()})"
                )
    return lines


def _lockout_text(study: LockoutStudy) -> list[str]:
    lines = [
        f"lockout: {study.params['reading'].get('name', 'literal')} reading; TCP's share after the pause over its share before "
        "(median [95 % interval])"
    ]
    for o in study.outcomes:
        lines.append(
            f"  {o.scheme:5s} {o.controllers:8s} controller: TCP starved in "
            f"{len(o.starved_seeds)} of {len(o.seeds)} seeds {o.starved_seeds or ''}; share ratio "
            f"{o.share_ratio.format()}; outside a factor of 2: {o.outside_factor_two or 'none'}"
            + ("" if o.share_after is None else f"; TCP's share after {o.share_after.format()}")
        )
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


def _fmt(value: float | None, spec: str = ".1f") -> str:
    return "-" if value is None else format(value, spec)


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
    if isinstance(result, PaperStudy):
        lines = _paper_text(result)
    elif isinstance(result, LockoutStudy):
        lines = _lockout_text(result)
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
    names = ["paper", "lockout", *_SINGLE] if args.name == "all" else [args.name]
    if args.name == "all" and args.readings == "literal":
        args.readings = "all"
    out: Path = args.out
    try:
        _check(args)
        for name in names:  # validate everything before the long part
            if name == "paper":
                _readings(args)
                _schemes(args, ())
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise _UsageError(
                f"--out {out}: cannot create the directory ({exc.strerror or exc})"
            ) from None
        results, wall = _execute(names, args)
    except _UsageError as exc:
        print(f"tdtp simulate: {exc}", file=sys.stderr)
        return 2
    summaries: dict[str, Any] = {}
    status = 0
    figures: dict[str, list[Path]] = {name: [] for name in results}
    if not args.no_plots:
        try:
            figures = _draw_all(results, out, args.jobs)
        except ImportError as exc:
            print(f"tdtp simulate: {exc}", file=sys.stderr)
            status = 1
    for name, result in results.items():
        json_path = out / f"{name.replace('-', '_')}.json"
        json_path.write_text(result.to_json() + "\n")
        summaries[name] = {
            "json": str(json_path),
            "figures": [str(p) for p in figures[name]],
            "headline": result.headline(),
        }
        if isinstance(result, LockoutStudy):
            summaries[name]["controllers"] = result.by_controller()
        if not args.json:
            print(summary_text(result))
            print(f"  wrote {json_path}" + "".join(f", {p}" for p in figures[name]))
    if args.json:
        payload = summaries if len(names) > 1 else summaries[names[0]]
        print(json.dumps(payload | {"wall_time_s": round(wall, 1)}, indent=2))
    else:
        print(f"simulated in {wall:.1f} s with {args.jobs} process(es)")
    return status


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(simulate_main(sys.argv[1:]))
