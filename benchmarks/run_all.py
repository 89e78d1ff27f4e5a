"""Run the whole benchmark suite and write ``benchmarks/results/latest.json`` and ``latest.md``.

Usage: ``python benchmarks/run_all.py [--quick] [--only NAME ...]``  (``make bench``)

Each benchmark runs as its own process (``python benchmarks/NAME.py ... --json``), one after the other,
with the settings below, chosen so that the suite takes under five minutes on two cores (plus one to
two for scale.py's baseline slaves), plus about seven for paths.py (80 cells of 3 s: its README table
uses 10 s cells, run on their own) and two for cellular.py (--quick: its README table comes from its
full mode). pacing.py, which has no ``--repeat``, is run three times and its
repetitions are combined here. The table (every figure with its baseline from the same run, ratio,
target, repetitions, median and spread) is printed and written to ``latest.md`` with each
benchmark's detail; ``latest.json`` has every report in full.
``--quick`` runs everything for a fraction of a second (a check that the suite works, not a measurement).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class Bench:
    name: str
    args: tuple[str, ...]
    quick: tuple[str, ...]
    runs: int = 1
    timeout: float = 150.0
    script: str = ""
    """The script, when not ``name``.py (one script run twice with other options)."""
    requires: str = ""
    """A program the benchmark needs (on PATH): without it the suite skips it and says so."""

    @property
    def path(self) -> Path:
        return HERE / f"{self.script or self.name}.py"


SUITE = (
    Bench("codec", ("--seconds", "0.2", "--repeat", "5"), ("--seconds", "0.01", "--repeat", "1")),
    Bench("bandwidth_figure", (), ()),
    Bench(
        "wire_efficiency",
        ("--seconds", "2", "--repeat", "3"),
        ("--seconds", "0.1", "--repeat", "1"),
    ),
    Bench(
        "pacing",
        ("--seconds", "2", "--only", "timerfd", "naive"),
        ("--seconds", "0.1", "--only", "timerfd", "naive"),
        runs=3,
    ),
    Bench(
        "latency",
        ("--seconds", "3", "--repeat", "3"),
        ("--seconds", "0.1", "--repeat", "1"),
    ),
    Bench(
        "instructions",
        # (no --seconds or --repeat: a count of instructions, within a few % from run to run)
        ("--echoes", "2000"),
        ("--echoes", "100", "--variants", "raw-uvloop", "tdtp"),
        timeout=600.0,
        requires="valgrind",
    ),
    Bench(
        "keyed",
        ("--seconds", "1", "--repeat", "5"),
        ("--seconds", "0.1", "--repeat", "1"),
    ),
    Bench(
        "throughput",
        ("--seconds", "1", "--repeat", "3", "--both", "--profile"),
        ("--seconds", "0.1", "--repeat", "1"),
    ),
    Bench(
        "datagram",
        ("--seconds", "1", "--repeat", "3"),
        ("--seconds", "0.1", "--repeat", "1"),
    ),
    Bench(
        "quic_peer",
        ("--seconds", "1", "--repeat", "3"),
        ("--seconds", "0.1", "--repeat", "1"),
    ),
    Bench(
        "scale",
        # tdtp's ramps, and beside the one-process ramp those of a raw uvloop slave and a C slave
        # (about 2 minutes more): the sessions this machine allows, from the same run.
        ("--seconds", "2", "--repeat", "2", "--workers", "1,2", "--slave", "tdtp,raw-uvloop,c"),
        (
            "--seconds",
            "0.1",
            "--repeat",
            "1",
            "--ramp",
            "2",
            "--workers",
            "1,2",
            "--slave",
            "tdtp,raw-uvloop,c",
        ),
        timeout=600.0,
    ),
    Bench(
        "paths",
        ("--duration", "3"),
        ("--quick",),
        timeout=1800.0,
    ),
    Bench(
        "cellular",
        # Every controller and raw UDP on the recorded LTE traces in virtual time (5 s, one
        # offset), Zenoh and raw UDP on real sockets (~2 minutes); the README's figures come from
        # its full mode (python benchmarks/cellular.py, ~25 min).
        ("--quick",),
        (
            "--quick",
            "--duration",
            "1",
            "--trace",
            "verizon",
            "--queue",
            "150kB",
            "--controller",
            "teleop",
            "udp",
            "--real",
        ),
        timeout=900.0,
    ),
    Bench(
        "scale-pure",
        ("--seconds", "2", "--repeat", "1", "--pure", "--ramp", "2,5,8,10,15,20,25,30"),
        ("--seconds", "0.1", "--repeat", "1", "--ramp", "2", "--pure"),
        script="scale",
    ),
)


def run_one(bench: Bench, quick: bool) -> list[Json]:
    """The benchmark's JSON reports, one per run."""
    args = bench.quick if quick else bench.args
    command = [sys.executable, str(bench.path), *args, "--json"]
    reports = []
    for i in range(bench.runs):
        suffix = f" (run {i + 1}/{bench.runs})" if bench.runs > 1 else ""
        print(f"== {bench.name}{suffix}: {' '.join(command[1:])}", file=sys.stderr, flush=True)
        done = subprocess.run(
            command, stdout=subprocess.PIPE, text=True, timeout=bench.timeout, check=False
        )
        if done.returncode != 0:
            raise RuntimeError(f"{bench.name} exited with {done.returncode}")
        reports.append(json.loads(done.stdout))
    return reports


# ---------------------------------------------------------------------------- pacing.py's report


def pacing_rows(reports: list[Json]) -> list[Row]:
    """pacing.py reports one run; combine its runs into rows: the timerfd pacer against naive
    ``call_at`` on each loop (p99 deviation and CPU), with the issue's target."""
    target = reports[0]["targets"]
    rate = float(target["rate_hz"])
    tolerance = float(target["rate_tolerance"]) * rate
    rows: list[Row] = []
    loops = sorted({r["loop"] for r in reports[0]["results"]})
    for loop in loops:

        def pick(report: Json, prefix: str, loop: str = loop) -> Json:
            return next(
                r
                for r in report["results"]
                if r["loop"] == loop and r["variant"].startswith(prefix)
            )

        timerfd = [pick(r, "TimerfdTimer") for r in reports]
        naive = [pick(r, "naive") for r in reports]
        p99 = [t["dev_p99_us"] for t in timerfd]
        naive_p99 = [n["dev_p99_us"] for n in naive]
        cpu = [t["cpu_percent"] for t in timerfd]
        rates = [t["rate_hz"] for t in timerfd]
        ok = (
            Stat.of(p99).median <= target["p99_deviation_us"]
            and Stat.of(cpu).median <= target["cpu_percent"]
            and all(abs(r - rate) <= tolerance for r in rates)
        )
        rows.append(
            Row(
                "pacing",
                f"1 kHz departure deviation p99, TimerfdTimer, {loop}",
                "us",
                Stat.of(p99),
                baseline="naive call_at",
                baseline_value=Stat.of(naive_p99),
                ratio=Stat.of(common.paired_ratios(p99, naive_p99)),
                ratio_label="tdtp/naive",
                target=(
                    f"p99 <= {target['p99_deviation_us']:.0f} us at <= "
                    f"{target['cpu_percent']:.0f} % CPU, rate {rate:.0f} +- 0.1 %"
                ),
                meets=ok,
                note=f"rate {Stat.of(rates).median:.2f} Hz",
                digits=1,
            )
        )
        rows.append(
            Row(
                "pacing",
                f"CPU of the 1 kHz pacer, TimerfdTimer, {loop}",
                "% of a core",
                Stat.of(cpu),
                baseline="naive call_at",
                baseline_value=Stat.of([n["cpu_percent"] for n in naive]),
                target=f"<= {target['cpu_percent']:.0f} %",
                meets=Stat.of(cpu).median <= target["cpu_percent"],
                digits=1,
            )
        )
    return rows


def pacing_text(reports: list[Json]) -> str:
    lines = [
        "Every run of pacing.py (deviation from the absolute 1 ms schedule):",
        "",
        "| run | variant | loop | deviation p50 / p99 / max (us) | early | rate (Hz) | CPU % |",
        "| ---: | --- | --- | --- | ---: | ---: | ---: |",
    ]
    for i, report in enumerate(reports):
        for r in report["results"]:
            lines.append(
                f"| {i + 1} | {r['variant']} | {r['loop']} | {r['dev_p50_us']:.1f} / "
                f"{r['dev_p99_us']:.1f} / {r['dev_max_us']:.1f} | {r['early']} "
                f"| {r['rate_hz']:.2f} | {r['cpu_percent']:.1f} |"
            )
    return "\n".join(lines)


# ---------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--quick", action="store_true", help="a fraction of a second each")
    parser.add_argument(
        "--only", nargs="+", choices=[b.name for b in SUITE], metavar="NAME", help="a subset"
    )
    parser.add_argument(
        "--out", type=Path, default=common.RESULTS, help="results folder (benchmarks/results)"
    )
    args = parser.parse_args(argv)
    started = time.monotonic()
    others_meter = common.OthersMeter()
    environment = common.environment()
    common.warn_if_loaded()
    reports: dict[str, Json] = {}
    rows: list[Row] = []
    failed: list[str] = []
    skipped: dict[str, str] = {}
    for bench in SUITE:
        if args.only and bench.name not in args.only:
            continue
        if bench.requires and shutil.which(bench.requires) is None:
            skipped[bench.name] = f"{bench.requires} is not installed"
            print(f"== {bench.name}: skipped ({skipped[bench.name]})", file=sys.stderr)
            continue
        t0 = time.monotonic()
        try:
            runs = run_one(bench, args.quick)
        except (RuntimeError, subprocess.TimeoutExpired, json.JSONDecodeError) as exc:
            print(f"!! {bench.name} failed: {exc}", file=sys.stderr)
            reports[bench.name] = {"error": str(exc)}
            failed.append(bench.name)
            continue
        if bench.name == "pacing":
            reports[bench.name] = {"runs": runs}
            rows.extend(pacing_rows(runs))
        else:
            reports[bench.name] = runs[0]
            rows.extend(Row.from_json(r) for r in runs[0]["rows"])
        reports[bench.name]["wall_seconds"] = round(time.monotonic() - t0, 1)
    wall = time.monotonic() - started
    others = others_meter.percent()
    command = "python benchmarks/run_all.py" + (" --quick" if args.quick else "")
    if args.only:
        command += " --only " + " ".join(args.only)
    table = common.markdown_table(rows)
    env = environment
    header = (
        f"Command: `{command}` ({wall:.0f} s)  \n"
        f"Machine: {env['cpu_model']}, {env['nproc']} CPUs, Python {env['python']}, "
        f"uvloop {env['uvloop']}, aioquic {env['aioquic']}, load average "
        f"{' / '.join(str(x) for x in env['loadavg'])} at the start  \n"
        f"Date: {env['date']}  \n"
        f"Other tenants: {others:.0f} % of one core on average during the suite (CPU time of every "
        "process on the machine less the suite's own, from /proc/[pid]/stat and getrusage); more "
        "than a few % makes the timings noisy."
    )
    sections = [f"# Benchmark results\n\n{header}\n\n{table}\n"]
    for name, why in skipped.items():
        sections.append(f"## {name}\n\nSkipped: {why}.\n")
    for name, report in reports.items():
        if "error" in report:
            sections.append(f"## {name}\n\nFAILED: {report['error']}\n")
        elif name == "pacing":
            sections.append(f"## pacing\n\n{pacing_text(report['runs'])}\n")
        elif report.get("text"):
            sections.append(f"## {name}\n\n{report['text']}\n")
    markdown = "\n".join(sections)
    out: Path = args.out
    common.write_text(out / "latest.md", markdown)
    summary: Json = {
        "command": command,
        "wall_seconds": round(wall, 1),
        "other_tenants_percent": round(others, 1),
        "environment": environment,
        "rows": [r.as_json() for r in rows],
        "benchmarks": reports,
        "failed": failed,
        "skipped": skipped,
    }
    common.write_text(out / "latest.json", json.dumps(summary, indent=1, default=str) + "\n")
    print(f"{header}\n\n{table}")
    print(f"\nwritten: {out / 'latest.md'}, {out / 'latest.json'}", file=sys.stderr)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
