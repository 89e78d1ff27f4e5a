"""What every benchmark script shares: statistics, the machine, the report format, worker processes.

Not a benchmark itself. Each script in ``benchmarks/`` imports it as ``_common`` (the scripts' own folder
is first on ``sys.path`` when they run) and reports a list of :class:`Row`: one measured figure with its
baseline from the same run, medians and spreads over the repetitions, the ratio and the issue's target.
``run_all.py`` gathers the rows of every script into ``results/latest.json`` and ``results/latest.md``.

Worker processes (sender and receiver on their own cores) are started with the ``spawn`` method, so a
child never inherits an event loop, and pinned to one CPU each when the machine has two or more.
"""

from __future__ import annotations

import argparse
import asyncio
import datetime
import functools
import importlib.metadata
import json
import math
import multiprocessing
import multiprocessing.connection
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NoReturn


class OneLineParser(argparse.ArgumentParser):
    """A benchmark's command line: misuse is one line on stderr and exit status 2, no usage dump."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled

RESULTS = ROOT / "benchmarks" / "results"

LoopFactory = Callable[[], asyncio.AbstractEventLoop]
Json = dict[str, Any]


# ---------------------------------------------------------------------------- statistics


def percentile(sorted_values: Sequence[float], q: float) -> float:
    """Nearest-rank percentile of an ascending sequence (``q`` in 0..1)."""
    if not sorted_values:
        return math.nan
    rank = max(1, math.ceil(q * len(sorted_values)))
    return sorted_values[min(rank, len(sorted_values)) - 1]


@dataclass
class Stat:
    """A figure measured ``n`` times: median and spread (min/max and the quartiles)."""

    median: float
    min: float
    max: float
    q1: float
    q3: float
    n: int
    values: list[float] = field(default_factory=list)

    @classmethod
    def of(cls, values: Sequence[float]) -> Stat:
        clean = sorted(v for v in values if not math.isnan(v))
        if not clean:
            return cls(math.nan, math.nan, math.nan, math.nan, math.nan, 0, [])
        if len(clean) >= 2:
            q1, _, q3 = statistics.quantiles(clean, n=4, method="inclusive")
        else:
            q1 = q3 = clean[0]
        return cls(statistics.median(clean), clean[0], clean[-1], q1, q3, len(clean), list(values))

    def spread(self, digits: int | None = None) -> str:
        """``min-max`` (what the tables show; the quartiles are in the JSON)."""
        if self.n <= 1:
            return "-"
        return f"{fmt(self.min, digits)} - {fmt(self.max, digits)}"


def fmt(value: float | None, digits: int | None = None) -> str:
    """A number for a table: 3-4 significant digits unless ``digits`` (decimals) is given."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if digits is not None:
        return f"{value:,.{digits}f}"
    magnitude = abs(value)
    if magnitude >= 1000:
        return f"{value:,.0f}"
    if magnitude >= 100:
        return f"{value:.1f}"
    if magnitude >= 10:
        return f"{value:.2f}"
    if magnitude >= 1:
        return f"{value:.3f}"
    return f"{value:.4f}"


def paired_ratios(numerators: Sequence[float], denominators: Sequence[float]) -> list[float]:
    """Ratios of the repetitions run side by side (rep i against rep i): noise common to a repetition
    cancels, which ratios of medians would not do."""
    return [a / b if b else math.nan for a, b in zip(numerators, denominators, strict=True)]


# ---------------------------------------------------------------------------- report rows


@dataclass
class Row:
    """One line of the suite's table: a figure, its baseline from the same run, and the target."""

    benchmark: str
    figure: str
    unit: str
    value: Stat
    baseline: str = ""
    baseline_value: Stat | None = None
    ratio: Stat | None = None
    ratio_label: str = ""
    target: str = ""
    meets: bool | None = None
    note: str = ""
    digits: int | None = None
    ratio_digits: int = 3

    @property
    def reps(self) -> int:
        return self.value.n

    def as_json(self) -> Json:
        data = asdict(self)
        data["reps"] = self.reps
        return data

    @classmethod
    def from_json(cls, data: Json) -> Row:
        def stat(d: Json | None) -> Stat | None:
            return None if d is None else Stat(**d)

        value = stat(data["value"])
        assert value is not None
        return cls(
            benchmark=data["benchmark"],
            figure=data["figure"],
            unit=data["unit"],
            value=value,
            baseline=data.get("baseline", ""),
            baseline_value=stat(data.get("baseline_value")),
            ratio=stat(data.get("ratio")),
            ratio_label=data.get("ratio_label", ""),
            target=data.get("target", ""),
            meets=data.get("meets"),
            note=data.get("note", ""),
            digits=data.get("digits"),
            ratio_digits=data.get("ratio_digits", 3),
        )


_MEETS = {True: "yes", False: "**no**", None: "-"}


def markdown_table(rows: Sequence[Row]) -> str:
    """The suite's table: one row per figure, medians with min-max over the repetitions."""
    lines = [
        "| benchmark | figure | median | spread (min - max) | baseline (same run): median "
        "| ratio | target | meets | reps |",
        "| --- | --- | ---: | ---: | --- | ---: | --- | --- | ---: |",
    ]
    for row in rows:
        unit = f" {row.unit}" if row.unit else ""
        if row.baseline_value is not None:
            baseline = f"{row.baseline}: {fmt(row.baseline_value.median, row.digits)}{unit}"
        else:
            baseline = row.baseline or "-"
        if row.ratio is not None and row.ratio.n:
            d = row.ratio_digits
            ratio = f"{fmt(row.ratio.median, d)}"
            if row.ratio.n > 1:
                ratio += f" ({fmt(row.ratio.min, d)} - {fmt(row.ratio.max, d)})"
            if row.ratio_label:
                ratio += f" {row.ratio_label}"
        else:
            ratio = "-"
        figure = row.figure + (f" ({row.note})" if row.note else "")
        lines.append(
            f"| {row.benchmark} | {figure} | {fmt(row.value.median, row.digits)}{unit} "
            f"| {row.value.spread(row.digits)} | {baseline} | {ratio} | {row.target or '-'} "
            f"| {_MEETS[row.meets]} | {row.reps} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------------- the machine


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def usable_cpus() -> list[int]:
    """The CPUs this process may run on (what ``nproc`` prints the count of)."""
    if hasattr(os, "sched_getaffinity"):
        return sorted(os.sched_getaffinity(0))
    return list(range(os.cpu_count() or 1))


def environment() -> Json:
    return {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "python": platform.python_version(),
        "uvloop": _version("uvloop"),
        "aioquic": _version("aioquic"),
        "platform": platform.platform(),
        "cpu_model": cpu_model(),
        "nproc": len(usable_cpus()),
        "loadavg": [round(x, 2) for x in os.getloadavg()],
    }


def cpu_seconds() -> float:
    """This process's user + system CPU time (``getrusage``), seconds."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def all_processes_cpu() -> float | None:
    """CPU seconds used by every process on the machine: user + system time of the live ones plus
    what their reaped children used (``/proc/[pid]/stat`` utime, stime, cutime, cstime), or None off
    Linux. Unlike the tick-sampled totals of ``/proc/stat``, these come from the scheduler's precise
    run time, so 1 kHz wake-ups do not alias."""
    proc = Path("/proc")
    if not (proc / "self" / "stat").exists():
        return None
    ticks = 0
    for entry in os.scandir(proc):
        if not entry.name.isdigit():
            continue
        try:
            text = Path(entry.path, "stat").read_text()
        except OSError:
            continue  # exited meanwhile
        fields = text[text.rfind(")") + 2 :].split()
        ticks += sum(int(x) for x in fields[11:15])  # utime stime cutime cstime (fields 14-17)
    return ticks / os.sysconf("SC_CLK_TCK")


def own_cpu() -> float:
    """CPU seconds of this process and of every child it has waited for (getrusage)."""
    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        usage = resource.getrusage(who)
        total += usage.ru_utime + usage.ru_stime
    return total


class OthersMeter:
    """How much CPU other tenants used between :meth:`start` and :meth:`percent`, in % of one core:
    every process's CPU time less this process's and its reaped children's. Call :meth:`percent`
    after the measured workers have been joined, so that their time counts as ours."""

    def __init__(self) -> None:
        self._t = time.monotonic()
        self._all = all_processes_cpu()
        self._own = own_cpu()

    def percent(self) -> float:
        now_all = all_processes_cpu()
        if self._all is None or now_all is None:
            return math.nan
        elapsed = time.monotonic() - self._t
        return max(0.0, 100.0 * ((now_all - self._all) - (own_cpu() - self._own)) / elapsed)


CONTENDED_PERCENT = 20.0
"""A run during which other processes used more than this much CPU (% of one core) is contended."""


class Retrier:
    """Reruns contended runs (other tenants above :data:`CONTENDED_PERCENT` meanwhile), drawing on
    one budget per script so that a machine busy all along cannot multiply the suite's time."""

    def __init__(self, budget: int) -> None:
        self.budget = budget
        self.retried = 0

    def run(self, label: str, fn: Callable[[], Json]) -> Json:
        while True:
            result = fn()
            others = float(result.get("others_percent", 0.0))
            result["contended"] = others > CONTENDED_PERCENT
            if not result["contended"]:
                return result
            if self.retried >= self.budget:
                print(
                    f"  {label}: other tenants used {others:.0f} % of a core; retry budget spent, "
                    "kept as it is (contended)",
                    file=sys.stderr,
                )
                return result
            self.retried += 1
            print(
                f"  {label}: other tenants used {others:.0f} % of a core: contended, run again",
                file=sys.stderr,
            )

    def interleaved(
        self,
        repeat: int,
        variants: Sequence[str],
        label: Callable[[str], str],
        run: Callable[[str], Json],
    ) -> dict[str, list[Json]]:
        """``run(variant)`` ``repeat`` times for every variant, interleaved (each variant's first
        run, then each one's second...) so that a neighbour's burst of load falls on all of them
        alike, each through :meth:`run`. Says on stderr which run starts (``label(variant)``)."""
        runs: dict[str, list[Json]] = {v: [] for v in variants}
        for rep in range(repeat):
            for variant in variants:
                name = f"rep {rep + 1}/{repeat}: {label(variant)}"
                print(f"{name} ...", file=sys.stderr, flush=True)
                runs[variant].append(self.run(name, functools.partial(run, variant)))
        return runs


def _enough(clean_count: int, total: int) -> bool:
    return clean_count >= min(2, total)


def clean(runs: Sequence[Json]) -> list[Json]:
    """The uncontended runs, if there are at least two (or the only run is): a run a neighbour
    disturbed is a known-bad measurement, not a sample of tdtp's behaviour. Else all runs."""
    ok = [r for r in runs if not r.get("contended")]
    return ok if _enough(len(ok), len(runs)) else list(runs)


def clean_pairs(a: Sequence[Json], b: Sequence[Json]) -> tuple[list[Json], list[Json]]:
    """Repetitions i where neither run was contended (if at least two), for paired ratios."""
    pairs = list(zip(a, b, strict=True))
    ok = [(x, y) for x, y in pairs if not x.get("contended") and not y.get("contended")]
    chosen = ok if _enough(len(ok), len(pairs)) else pairs
    return [x for x, _ in chosen], [y for _, y in chosen]


def left_out(*groups: Sequence[Json]) -> str:
    """A note for a row: how many contended runs its statistics left out, and how busy the other
    tenants were; or, when too few runs were clean to leave any out, that the figure was taken under
    contention and how much. Never a verdict without the figure: the row keeps its median either way."""
    runs = [r for g in groups for r in g]
    contended = [float(r.get("others_percent", 0.0)) for r in runs if r.get("contended")]
    if not contended:
        return ""
    low, high = f"{min(contended):.0f}", f"{max(contended):.0f}"
    busy = low if low == high else f"{low}-{high}"
    n = sum(len(g) - len(clean(g)) for g in groups)
    if n:
        return (
            f"{n} contended run{'s' if n != 1 else ''} left out: other tenants used {busy} % "
            "of a core"
        )
    return (
        f"contended: other tenants used {busy} % of a core in {len(contended)} of {len(runs)} "
        "runs, too few clean ones to leave them out: noisy"
    )


def warn_if_loaded() -> None:
    load, cpus = os.getloadavg()[0], len(usable_cpus())
    if load > cpus / 2:
        print(
            f"warning: load average {load:.2f} on {cpus} CPUs: other processes share the cores, "
            "expect noisy figures",
            file=sys.stderr,
        )


# ---------------------------------------------------------------------------- event loops


def loop_factory(name: str) -> LoopFactory:
    """``"asyncio"`` (the stock loop) or ``"uvloop"``; raises ImportError if uvloop is missing."""
    if name == "asyncio":
        return asyncio.new_event_loop
    if name == "uvloop":
        import uvloop  # noqa: PLC0415 - optional

        return uvloop.new_event_loop
    raise ValueError(f"unknown loop {name!r}")


def have_uvloop() -> bool:
    try:
        import uvloop  # noqa: F401, PLC0415
    except ImportError:
        return False
    return True


# ---------------------------------------------------------------------------- command line


def parser(
    doc: str | None, *, seconds: float, repeat: int, help_seconds: str
) -> argparse.ArgumentParser:
    """``--seconds S --repeat N --json``, the options every benchmark takes."""
    first = doc.strip().splitlines()[0] if doc else None
    p = argparse.ArgumentParser(
        description=first, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--seconds", type=float, default=seconds, help=f"{help_seconds} ({seconds:g})")
    p.add_argument("--repeat", type=int, default=repeat, help=f"repetitions ({repeat})")
    p.add_argument(
        "--json", action="store_true", help="print one JSON report on stdout (the table to stderr)"
    )
    return p


def emit(
    name: str,
    args: argparse.Namespace,
    rows: Sequence[Row],
    *,
    details: Json | None = None,
    text: str = "",
) -> int:
    """Print the report: JSON on stdout with ``--json`` (human text on stderr), else text."""
    table = markdown_table(rows)
    human = f"{text}\n\n{table}" if text else table
    report: Json = {
        "benchmark": name,
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "seconds": args.seconds,
        "repeat": args.repeat,
        "environment": environment(),
        "rows": [row.as_json() for row in rows],
        "text": text,
        "details": details or {},
    }
    if args.json:
        print(human, file=sys.stderr)
        print(json.dumps(report, default=_json_default))
    else:
        env = report["environment"]
        print(
            f"{name}: {env['cpu_model']}, {env['nproc']} CPUs, Python {env['python']}, "
            f"uvloop {env['uvloop']}, load {env['loadavg'][0]}\n"
        )
        print(human)
    return 0


def _json_default(value: object) -> object:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return str(value)


# ---------------------------------------------------------------------------- worker processes


def pin_to_cpu(slot: int) -> int | None:
    """Pin this process to the ``slot``-th usable CPU (modulo their number) when there are two or
    more, so that two workers do not share a core. Returns the CPU, or None when not pinned."""
    cpus = usable_cpus()
    if len(cpus) < 2 or not hasattr(os, "sched_setaffinity"):
        return None
    cpu = cpus[slot % len(cpus)]
    os.sched_setaffinity(0, {cpu})
    return cpu


Worker = Callable[..., None]


def _guarded(target: Worker, conn: multiprocessing.connection.Connection, kwargs: Json) -> None:
    try:
        target(conn, **kwargs)
    except BaseException:
        conn.send({"error": traceback.format_exc()})
        raise
    finally:
        conn.close()


@dataclass
class WorkerHandle:
    process: multiprocessing.process.BaseProcess
    conn: multiprocessing.connection.Connection
    name: str

    def recv(self, timeout: float) -> Json:
        """The worker's next message; raises RuntimeError on a timeout or an error in the worker."""
        if not self.conn.poll(timeout):
            raise RuntimeError(f"worker {self.name} sent nothing within {timeout:.0f} s")
        try:
            message: Json = self.conn.recv()
        except EOFError as exc:
            raise RuntimeError(f"worker {self.name} exited (code {self.process.exitcode})") from exc
        if "error" in message:
            raise RuntimeError(f"worker {self.name} failed:\n{message['error']}")
        return message

    def send(self, message: Json) -> None:
        self.conn.send(message)

    def finish(self, timeout: float = 5.0) -> None:
        self.process.join(timeout)
        if self.process.is_alive():
            self.process.terminate()  # our own child, by its handle
            self.process.join(2.0)
        self.conn.close()


_CONTEXT = multiprocessing.get_context("spawn")


PURE_ENV = "TDTP_PURE_PYTHON"
"""Set in a worker's environment, tdtp runs its pure-Python build there (``tdtp/_build.py``)."""


def start_worker(name: str, target: Worker, *, pure: bool = False, **kwargs: Any) -> WorkerHandle:
    """Run ``target(conn, **kwargs)`` in a fresh (spawned) process; talk to it through the handle.

    ``pure=True`` starts it with ``TDTP_PURE_PYTHON=1``, so that it imports tdtp's pure-Python build
    even where the compiled one is installed (the child reads its environment when it starts)."""
    parent, child = _CONTEXT.Pipe()
    process = _CONTEXT.Process(
        target=_guarded, args=(target, child, kwargs), name=name, daemon=True
    )
    saved = os.environ.get(PURE_ENV)
    if pure:
        os.environ[PURE_ENV] = "1"
    try:
        process.start()
    finally:
        if pure:
            if saved is None:
                del os.environ[PURE_ENV]
            else:
                os.environ[PURE_ENV] = saved
    child.close()
    return WorkerHandle(process, parent, name)


def compile_c(source: str, workdir: Path, name: str, libraries: Sequence[str] = ()) -> Path | None:
    """A C program written for a benchmark, compiled with the system's ``cc -O2`` into ``workdir``
    (a temporary directory: nothing is kept); None when there is no C compiler."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        return None
    path = workdir / f"{name}.c"
    path.write_text(source)
    binary = workdir / name
    command = [cc, "-O2", "-o", str(binary), str(path), *(f"-l{lib}" for lib in libraries)]
    subprocess.run(command, check=True)
    return binary


def tdtp_build() -> str:
    """``"compiled"`` or ``"pure"``: which build of tdtp's core this process runs."""
    import tdtp  # noqa: PLC0415 - the benchmarks import it anyway; late, so the env counts

    return tdtp.build_info().build


def run_in_loop(loop_name: str, coroutine: Callable[[], Any]) -> Any:
    """Run ``coroutine()`` to completion on a new loop of the named kind."""
    with asyncio.Runner(loop_factory=loop_factory(loop_name)) as runner:
        return runner.run(coroutine())


def profile_text(profiler: Any, limit: int = 25) -> str:
    """The top ``limit`` functions of a cProfile profiler by own time, as pstats prints them."""
    import io  # noqa: PLC0415
    import pstats  # noqa: PLC0415

    out = io.StringIO()
    stats = pstats.Stats(profiler, stream=out)
    stats.sort_stats("tottime").print_stats(limit)
    text = out.getvalue()
    # Keep the table and shorten the site-packages and checkout paths.
    text = text.replace(str(ROOT) + "/", "")
    marker = "ncalls"
    return text[text.find(marker) - 3 :] if marker in text else text


def write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def as_list(text: str, kind: Callable[[str], Any] = int) -> list[Any]:
    """``"10,25,50"`` -> ``[10, 25, 50]`` for list options."""
    return [kind(part) for part in text.split(",") if part.strip()]


def mean(values: Sequence[float]) -> float:
    return statistics.fmean(values) if values else math.nan
