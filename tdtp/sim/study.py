"""The paper's experiment over many seeds: one record per run, medians and 95 % intervals per reading.

A single run of :func:`~tdtp.sim.scenarios.paper` is one draw: the TCP start times and the senders'
phases decide, among other things, whether a 1 kHz flow that fills the link in the free period locks
the returning TCP out. So every configuration is run for several seeds (10 by default), in parallel
processes, and reported per direction as the median over the seeds with the order-statistic interval
of :mod:`tdtp.sim.spread`, for the whole run and for the windows with the master-to-slave TCP on and
off. A run in which a TCP flow starves (:data:`~tdtp.sim.scenarios.STARVATION_SHARE`) is flagged: the
summaries list the starved seeds, and every ratio is given over all seeds *and* over the seeds where no
TCP starved, so a lock-out is never averaged away silently.

* :class:`PaperTask` names one simulation (reading, scheme, seed, controller variant); it is what the
  process pool ships; :func:`run_task` runs it and returns a compact :class:`RunRecord`.
* :func:`paper_study` runs the tasks of several readings and gives a :class:`PaperStudy`;
  :func:`lockout_study` runs the lock-out check, current and earlier controllers side by side,
  and gives a :class:`LockoutStudy`. Both take records already computed (``records=``), so a caller
  running several studies runs each simulation once.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar, Final, Literal

from tdtp.config import AckMode
from tdtp.control import TfrcConfig, TrinomialConfig
from tdtp.sim.metrics import mean
from tdtp.sim.readings import DEFAULT_READING, READINGS, Reading
from tdtp.sim.scenarios.paper import (
    MS,
    SM,
    STARVATION_SHARE,
    WINDOWS,
    PaperRun,
    paper,
    tail_window,
    tcp_pause,
)
from tdtp.sim.scenarios.results import ScenarioResult, json_safe
from tdtp.sim.scenarios.schemes import DEFAULT_SCHEMES, SCHEMES
from tdtp.sim.spread import INTERVAL_METHOD, MedianInterval, median_interval, quantile

__all__ = [
    "BOTH",
    "CONTROLLER_VARIANTS",
    "DEFAULT_SEEDS",
    "EARLIER_SEEDS",
    "LOCKOUT_SEEDS",
    "LockoutStudy",
    "PaperStudy",
    "PaperTask",
    "RunRecord",
    "lockout_study",
    "lockout_tasks",
    "paper_study",
    "paper_tasks",
    "run_task",
    "run_tasks",
]

DEFAULT_SEEDS: Final = 10
LOCKOUT_SEEDS: Final = 20
EARLIER_SEEDS: Final = 10
"""The lock-out check runs the earlier controllers on the first this-many seeds only: enough to show
how often they locked TCP out, at half the cost (make figures has five minutes)."""
DIRECTIONS: Final = (MS, SM)
BOTH: Final = "both"
"""Both directions together: the paper's "TDTP sends approximately the double of data" may mean this."""
RATIO_DIRECTIONS: Final = (MS, SM, BOTH)
Controllers = Literal["current", "earlier"]
CONTROLLER_VARIANTS: Final[dict[str, dict[str, object]]] = {
    "current": {},
    # The controllers before the lock-out fix (docs/CONTROL.md, sections 3.8 and 5.1).
    "earlier": {
        "trinomial": TrinomialConfig(decrease_in_use=False),
        "tfrc": TfrcConfig(data_limited_decrease=None),
    },
}
BAND = (0.1, 0.9)
"""The per-bin band drawn around the median of the seeds in figures 7 and 8 (10th-90th percentile)."""
MECHANISM: Final = {
    "declared_lost": "data packets the sender declared lost",
    "network_drops": "data packets the network dropped",
    "ack_drops": "stand-alone ACKs for this direction's data the network dropped",
    "mean_p": "the sender's loss-event rate, mean of its per-bin samples",
    "mean_srtt_ms": "the sender's srtt, mean of its per-bin samples",
    "ack_share": "share of the packets offered to the bottleneck queue this data crosses that are "
    "stand-alone ACKs (for the other direction's data)",
}
"""The per-run figures that explain the ratios; in :attr:`RunRecord.mechanism`."""
SERIES: Final = ("goodput_kbps", "loss_ratio", "mean_delay")
"""The per-bin series that figures 7 and 8 draw as bands."""


@dataclass(frozen=True, slots=True)
class PaperTask:
    """One run of the paper scenario: picklable, so that a process pool can take it."""

    reading: Reading
    scheme: str
    seed: int
    duration: float = 100.0
    controllers: str = "current"
    bin_width: float = 1.0

    def key(self) -> tuple[Any, ...]:
        """What decides the run: two tasks with equal keys give the same record. A reading's name
        does not, nor does the ACK form for a scheme that sends no stand-alone ACKs."""
        effective = dataclasses.replace(self.reading, name="-", summary="")
        if SCHEMES[self.scheme].ack_mode is not AckMode.SEPARATE:
            effective = dataclasses.replace(effective, ack_form="redundant")
        return (
            effective,
            self.scheme,
            self.seed,
            self.duration,
            self.controllers,
            self.bin_width,
        )

    def cost(self) -> float:
        """A rough relative cost, for scheduling the longest first."""
        heavy = self.scheme == "trinomial" and self.reading.ack_form == "redundant"
        return (
            self.duration
            * (1.5 if heavy else 1.0)
            * (1.2 if self.controllers != "current" else 1.0)
        )


@dataclass
class RunRecord:
    """What one run contributes to the statistics (no per-packet data)."""

    reading: str
    scheme: str
    seed: int
    controllers: str
    goodput_kbps: dict[str, dict[str, float]]
    """By direction (and :data:`BOTH`), then window (:data:`~tdtp.sim.scenarios.WINDOWS`)."""
    loss_ratio: dict[str, float]
    mean_delay_ms: dict[str, float]
    ack_packets: dict[str, int]
    """Stand-alone ACK packets sent in each direction."""
    tcp: dict[str, dict[str, Any]]
    """:class:`~tdtp.sim.scenarios.TcpOutcome` by direction (directions with TCP only)."""
    starved: list[str]
    bin_width: float
    series: dict[str, dict[str, list[float | None]]]
    """Per-bin ``goodput_kbps``, ``loss_ratio``, ``mean_delay``, ``delivered_pps`` and the sender's
    ``allowed_pps`` (at the end of the bin) by direction, and ``tcp M->S`` / ``tcp S->M`` goodput."""
    wall_time: float
    events: int
    mechanism: dict[str, dict[str, float]] = field(default_factory=dict)
    """What explains a ratio, by name then direction of the data (see :data:`MECHANISM`)."""

    def to_dict(self, *, series: bool = False) -> dict[str, Any]:
        data = asdict(self)
        if not series:
            del data["series"]
        return data


def run_task(task: PaperTask) -> RunRecord:
    """Run one task (in whatever process calls it)."""
    result = paper(
        seed=task.seed,
        reading=task.reading,
        duration=task.duration,
        schemes=(task.scheme,),
        bin_width=task.bin_width,
        controller_configs=CONTROLLER_VARIANTS[task.controllers],
    )
    run = result.runs[task.scheme]
    series: dict[str, dict[str, list[float | None]]] = {
        d: {name: run.series[d][name] for name in SERIES} for d in DIRECTIONS
    }
    for d in DIRECTIONS:
        series[f"tcp {d}"] = {"goodput_kbps": run.series[f"tcp {d}"]["goodput_kbps"]}
    # The allowed rate at the end of each bin, packets/s: what the controller permitted, next to
    # what was sent (delivered_pps), shows an allowance that a loss event halves to no effect.
    for d, side in ((MS, "master"), (SM, "slave")):
        series[d]["allowed_pps"] = list(run.probes[side]["rate"])
        series[d]["delivered_pps"] = run.series[d]["delivered_pps"]
    mechanism = _mechanism(run)
    return RunRecord(
        reading=task.reading.name,
        scheme=task.scheme,
        seed=task.seed,
        controllers=task.controllers,
        goodput_kbps={d: {w: run.summaries[d][w].goodput_kbps for w in WINDOWS} for d in DIRECTIONS}
        | {
            BOTH: {
                w: run.summaries[MS][w].goodput_kbps + run.summaries[SM][w].goodput_kbps
                for w in WINDOWS
            }
        },
        loss_ratio={d: run.summaries[d]["all"].loss_ratio for d in DIRECTIONS},
        mean_delay_ms={d: run.summaries[d]["all"].mean_delay * 1000 for d in DIRECTIONS},
        ack_packets={MS: int(run.acks[MS].sent_packets), SM: int(run.acks[SM].sent_packets)},
        mechanism=mechanism,
        tcp={d: o.to_dict() for d, o in run.tcp_outcome.items()},
        starved=run.starved,
        bin_width=task.bin_width,
        series=series,
        wall_time=run.wall_time,
        events=run.events,
    )


def _mechanism(run: PaperRun) -> dict[str, dict[str, float]]:
    """:data:`MECHANISM` for one run, by direction of the data."""
    links = {link["link"]: link for link in run.links}
    sender = {MS: "master", SM: "slave"}
    other = {MS: SM, SM: MS}
    bottleneck = {MS: "R1->R2", SM: "R2->R1"}
    out: dict[str, dict[str, float]] = {name: {} for name in MECHANISM}
    for d in DIRECTIONS:
        probe = run.probes[sender[d]]
        out["declared_lost"][d] = float(run.connection[sender[d]]["packets_lost"])
        out["network_drops"][d] = float(run.summaries[d]["all"].dropped_packets)
        out["ack_drops"][d] = float(run.acks[other[d]].dropped_packets)
        out["mean_p"][d] = mean(probe["p"])
        out["mean_srtt_ms"][d] = 1000 * mean(probe["srtt"])
        offered = links[bottleneck[d]]["packets"]
        out["ack_share"][d] = run.acks[d].sent_packets / offered if offered else math.nan
    return out


def run_tasks(
    tasks: Iterable[PaperTask],
    *,
    jobs: int = 1,
) -> dict[tuple[Any, ...], RunRecord]:
    """Run every distinct task, ``jobs`` processes at a time, the longest first; records by key."""
    unique = {t.key(): t for t in tasks}
    order = sorted(unique.values(), key=lambda t: -t.cost())
    out: dict[tuple[Any, ...], RunRecord] = {}
    if jobs <= 1 or len(order) <= 1:
        for task in order:
            out[task.key()] = run_task(task)
        return out
    with ProcessPoolExecutor(max_workers=min(jobs, len(order))) as pool:
        for task, record in zip(order, pool.map(run_task, order), strict=True):
            out[task.key()] = record
    return out


# -- statistics ---------------------------------------------------------------------------------------


def _mi(values: Iterable[float]) -> MedianInterval:
    return median_interval([v for v in values if v is not None and math.isfinite(v)])


def _band(runs: Sequence[list[float | None]]) -> dict[str, list[float | None]]:
    """Per bin: the median and the :data:`BAND` quantiles over the runs (None where no run has data)."""
    out: dict[str, list[float | None]] = {"median": [], "low": [], "high": []}
    for values in zip(*runs, strict=True):
        ordered = sorted(v for v in values if v is not None and math.isfinite(v))
        if not ordered:
            for series in out.values():
                series.append(None)
            continue
        out["median"].append(quantile(ordered, 0.5))
        out["low"].append(quantile(ordered, BAND[0]))
        out["high"].append(quantile(ordered, BAND[1]))
    return out


@dataclass
class SchemeSummary:
    """One scheme under one reading, over its seeds."""

    scheme: str
    seeds: list[int]
    goodput_kbps: dict[str, dict[str, MedianInterval]]
    loss_ratio: dict[str, MedianInterval]
    mean_delay_ms: dict[str, MedianInterval]
    ack_packets_per_s: dict[str, MedianInterval]
    mechanism: dict[str, dict[str, MedianInterval]]
    """:data:`MECHANISM` by name then direction."""
    tcp_goodput_kbps: dict[str, MedianInterval]
    tcp_share_ratio: dict[str, MedianInterval]
    """TCP's share of the bottleneck after the pause over its share before it."""
    starved_seeds: dict[str, list[int]]
    bands: dict[str, dict[str, dict[str, list[float | None]]]]
    """Series key (``M->S``, ``S->M``, ``tcp M->S``, ``tcp S->M``) -> series name -> band."""

    def to_dict(self, *, bands: bool = True) -> dict[str, Any]:
        data: dict[str, Any] = {
            "seeds": self.seeds,
            "goodput_kbps": {
                d: {w: m.to_dict() for w, m in ws.items()} for d, ws in self.goodput_kbps.items()
            },
            "loss_ratio": {d: m.to_dict() for d, m in self.loss_ratio.items()},
            "mean_delay_ms": {d: m.to_dict() for d, m in self.mean_delay_ms.items()},
            "ack_packets_per_s": {d: m.to_dict() for d, m in self.ack_packets_per_s.items()},
            "mechanism": {
                name: {d: m.to_dict() for d, m in ds.items()} for name, ds in self.mechanism.items()
            },
            "tcp_goodput_kbps": {d: m.to_dict() for d, m in self.tcp_goodput_kbps.items()},
            "tcp_share_after_over_before": {
                d: m.to_dict() for d, m in self.tcp_share_ratio.items()
            },
            "tcp_starved_seeds": self.starved_seeds,
        }
        if bands:
            data["bands"] = self.bands
        return data


def summarise_scheme(records: Sequence[RunRecord], duration: float) -> SchemeSummary:
    seeds = [r.seed for r in records]
    tcp_dirs = sorted({d for r in records for d in r.tcp})
    keys = [*DIRECTIONS, *(f"tcp {d}" for d in DIRECTIONS)]
    bands = {
        key: {
            name: _band([r.series[key][name] for r in records])
            for name in records[0].series[key]
            if name in SERIES or key.startswith("tcp")
        }
        for key in keys
    }
    return SchemeSummary(
        scheme=records[0].scheme,
        seeds=seeds,
        goodput_kbps={
            d: {w: _mi(r.goodput_kbps[d][w] for r in records) for w in WINDOWS}
            for d in RATIO_DIRECTIONS
        },
        loss_ratio={d: _mi(r.loss_ratio[d] for r in records) for d in DIRECTIONS},
        mean_delay_ms={d: _mi(r.mean_delay_ms[d] for r in records) for d in DIRECTIONS},
        ack_packets_per_s={
            d: _mi(r.ack_packets[d] / duration for r in records) for d in DIRECTIONS
        },
        mechanism={
            name: {d: _mi(r.mechanism[name][d] for r in records if r.mechanism) for d in DIRECTIONS}
            for name in MECHANISM
        },
        tcp_goodput_kbps={d: _mi(r.tcp[d]["goodput_kbps"] for r in records) for d in tcp_dirs},
        tcp_share_ratio={d: _mi(r.tcp[d]["share_ratio"] for r in records) for d in tcp_dirs},
        starved_seeds={d: [r.seed for r in records if d in r.starved] for d in tcp_dirs},
        bands=bands,
    )


@dataclass
class RatioSummary:
    """``numerator/denominator`` goodput, seed by seed (same seed, same TCP start times)."""

    pair: str
    per_seed: dict[str, dict[str, list[float]]]
    """Direction -> window -> ratios in seed order."""
    all_seeds: dict[str, dict[str, MedianInterval]]
    without_starved: dict[str, dict[str, MedianInterval]]
    """Over the seeds in which neither run starved a TCP flow."""
    starved_seeds: list[int]

    def to_dict(self) -> dict[str, Any]:
        return {
            "per_seed": {
                d: {w: [round(v, 4) for v in vs] for w, vs in ws.items()}
                for d, ws in self.per_seed.items()
            },
            "median_and_interval": {
                d: {w: m.to_dict() for w, m in ws.items()} for d, ws in self.all_seeds.items()
            },
            "without_starved_seeds": {
                d: {w: m.to_dict() for w, m in ws.items()} for d, ws in self.without_starved.items()
            },
            "seeds_with_starved_tcp": self.starved_seeds,
        }


def summarise_ratio(top: Sequence[RunRecord], bottom: Sequence[RunRecord]) -> RatioSummary:
    by_seed = {r.seed: r for r in bottom}
    pairs = [(a, by_seed[a.seed]) for a in top if a.seed in by_seed]
    starved = [a.seed for a, b in pairs if a.starved or b.starved]

    def ratio(a: RunRecord, b: RunRecord, d: str, w: str) -> float:
        den = b.goodput_kbps[d][w]
        return a.goodput_kbps[d][w] / den if den > 0 else math.nan

    per_seed = {
        d: {w: [ratio(a, b, d, w) for a, b in pairs] for w in WINDOWS} for d in RATIO_DIRECTIONS
    }
    clean = [(a, b) for a, b in pairs if a.seed not in starved]
    return RatioSummary(
        pair=f"{top[0].scheme}/{bottom[0].scheme}" if top and bottom else "",
        per_seed=per_seed,
        all_seeds={d: {w: _mi(per_seed[d][w]) for w in WINDOWS} for d in RATIO_DIRECTIONS},
        without_starved={
            d: {w: _mi(ratio(a, b, d, w) for a, b in clean) for w in WINDOWS}
            for d in RATIO_DIRECTIONS
        },
        starved_seeds=starved,
    )


@dataclass
class ReadingSummary:
    reading: Reading
    schemes: dict[str, SchemeSummary]
    ratios: dict[str, RatioSummary]

    def to_dict(self, *, bands: bool = True) -> dict[str, Any]:
        return {
            "reading": self.reading.to_dict(),
            "schemes": {k: s.to_dict(bands=bands) for k, s in self.schemes.items()},
            "ratios": {k: r.to_dict() for k, r in self.ratios.items()},
        }


@dataclass
class PaperStudy(ScenarioResult):
    """The paper scenario under several readings, each over several seeds."""

    scenario: ClassVar[str] = "paper"
    params: dict[str, Any]
    readings: dict[str, ReadingSummary]
    records: list[RunRecord] = field(default_factory=list)

    def headline(self) -> dict[str, Any]:
        """Per reading: its parameters, the goodput ratios with their intervals, starved runs."""
        out: dict[str, Any] = {"interval": self.params["interval"]}
        for name, summary in self.readings.items():
            per: dict[str, Any] = {"parameters": summary.reading.describe()}
            for pair, ratio in summary.ratios.items():
                per[f"goodput ratio {pair}"] = {
                    d: {w: m.to_dict(3) for w, m in ws.items()} for d, ws in ratio.all_seeds.items()
                }
                per[f"seeds with starved TCP ({pair})"] = ratio.starved_seeds
            per["goodput_kbps"] = {
                key: {d: s.goodput_kbps[d]["all"].to_dict(1) for d in RATIO_DIRECTIONS}
                for key, s in summary.schemes.items()
            }
            per["tcp_starved_seeds"] = {key: s.starved_seeds for key, s in summary.schemes.items()}
            out[name] = per
        return json_safe(out)  # type: ignore[no-any-return]

    def details(self) -> dict[str, Any]:
        """Each reading's figures per scheme and ratios, and every run's record."""
        return {
            "readings": {k: r.to_dict() for k, r in self.readings.items()},
            "runs": [r.to_dict() for r in self.records],
        }


def _complete(
    tasks: Sequence[PaperTask],
    records: Mapping[tuple[Any, ...], RunRecord] | None,
    jobs: int,
) -> dict[tuple[Any, ...], RunRecord]:
    """``records`` (runs done already, by key) with every task of ``tasks`` it lacks run now."""
    done = dict(records) if records is not None else {}
    missing = [t for t in tasks if t.key() not in done]
    if missing:
        done.update(run_tasks(missing, jobs=jobs))
    return done


SchemeChoice = Sequence[str] | Mapping[str, Sequence[str]]
"""The schemes to run: the same for every reading, or by reading name."""


def _schemes_of(reading: Reading, schemes: SchemeChoice) -> Sequence[str]:
    if isinstance(schemes, Mapping):
        return schemes.get(reading.name, DEFAULT_SCHEMES)
    return schemes


def paper_tasks(
    readings: Sequence[Reading],
    *,
    seeds: Sequence[int],
    schemes: SchemeChoice = DEFAULT_SCHEMES,
    duration: float = 100.0,
    bin_width: float = 1.0,
) -> list[PaperTask]:
    return [
        PaperTask(reading, scheme, seed, duration, "current", bin_width)
        for reading in readings
        for scheme in _schemes_of(reading, schemes)
        for seed in seeds
    ]


def paper_study(
    readings: Sequence[Reading] = (READINGS[DEFAULT_READING],),
    *,
    seeds: Sequence[int] = tuple(range(1, DEFAULT_SEEDS + 1)),
    schemes: SchemeChoice = DEFAULT_SCHEMES,
    duration: float = 100.0,
    bin_width: float = 1.0,
    jobs: int = 1,
    records: Mapping[tuple[Any, ...], RunRecord] | None = None,
) -> PaperStudy:
    """Run (or take from ``records``) every reading x scheme x seed and summarise them.

    ``schemes`` may differ by reading (``{"literal": ("tdtp", "trinomial", "tfrc")}``; a reading
    not named gets all three)."""
    started = time.perf_counter()
    tasks = paper_tasks(
        readings, seeds=seeds, schemes=schemes, duration=duration, bin_width=bin_width
    )
    done = _complete(tasks, records, jobs)
    summaries: dict[str, ReadingSummary] = {}
    kept: list[RunRecord] = []
    for reading in readings:
        chosen = _schemes_of(reading, schemes)
        by_scheme = {
            scheme: [
                dataclasses.replace(
                    done[PaperTask(reading, scheme, s, duration, "current", bin_width).key()],
                    reading=reading.name,
                )
                for s in seeds
            ]
            for scheme in chosen
        }
        for recs in by_scheme.values():
            kept.extend(recs)
        ratios = {}
        if "trinomial" in by_scheme:
            for scheme in chosen:
                if scheme != "trinomial":
                    ratios[f"{scheme}/trinomial"] = summarise_ratio(
                        by_scheme[scheme], by_scheme["trinomial"]
                    )
        summaries[reading.name] = ReadingSummary(
            reading,
            {k: summarise_scheme(v, duration) for k, v in by_scheme.items()},
            ratios,
        )
    params = {
        "readings": {r.name: r.to_dict() for r in readings},
        "seeds": list(seeds),
        "schemes": {r.name: list(_schemes_of(r, schemes)) for r in readings},
        "duration": duration,
        "bin_width": bin_width,
        "tcp_ms_paused": list(tcp_pause(duration)),
        "windows": {
            "all": "the whole run",
            "tcp_on": "master-to-slave TCP on (both directions)",
            "tcp_off": "master-to-slave TCP paused (both directions)",
        },
        "interval": f"95 % {INTERVAL_METHOD} over the seeds (exact coverage given per interval)",
        "mechanism": dict(MECHANISM),
        "band": f"figures: per-bin median and {BAND[0]:.0%}-{BAND[1]:.0%} range over the seeds",
        "starvation": f"TCP below {STARVATION_SHARE:.0%} of its fair share of the bottleneck over "
        f"{tail_window(duration)[0]:g}-{duration:g} s",
        "wall_time_s": round(time.perf_counter() - started, 1),
    }
    return PaperStudy(params=params, readings=summaries, records=kept)


# -- the lock-out check -------------------------------------------------------------------------------


def lockout_tasks(
    *,
    seeds: Sequence[int] = tuple(range(1, LOCKOUT_SEEDS + 1)),
    earlier_seeds: Sequence[int] | None = None,
    schemes: Sequence[str] = ("tdtp", "tfrc", "teleop"),
    reading: Reading | None = None,
    duration: float = 100.0,
    bin_width: float = 1.0,
) -> list[PaperTask]:
    """The literal reading (a 1 kHz flow alone on the link in the pause), current and earlier
    controllers; the earlier ones on ``earlier_seeds`` (default: the first :data:`EARLIER_SEEDS`)."""
    how = reading if reading is not None else READINGS["literal"]
    before = seeds[:EARLIER_SEEDS] if earlier_seeds is None else earlier_seeds
    return [
        PaperTask(how, scheme, seed, duration, controllers, bin_width)
        for controllers, chosen in (("current", seeds), ("earlier", before))
        for scheme in schemes
        if _has_variant(scheme, controllers)
        for seed in chosen
    ]


def _has_variant(scheme: str, controllers: str) -> bool:
    """Whether ``scheme`` has a controller of the ``controllers`` kind: every scheme has current
    ones; only the paper's controllers had earlier ones (before the lock-out fix)."""
    return (
        controllers == "current" or SCHEMES[scheme].controller in CONTROLLER_VARIANTS[controllers]
    )


@dataclass
class LockoutOutcome:
    controllers: str
    scheme: str
    seeds: list[int]
    starved_seeds: list[int]
    share_ratio: MedianInterval
    share_ratios: list[float]
    outside_factor_two: list[int]
    """Seeds whose TCP share after the pause is not within a factor of 2 of its share before."""
    tdtp_goodput_kbps: MedianInterval
    """The scheme's master-to-slave goodput over the run."""
    tcp_goodput_kbps: MedianInterval
    bands: dict[str, dict[str, list[float | None]]]
    """``M->S`` and ``tcp M->S`` goodput bands."""
    share_after: MedianInterval | None = None
    """TCP's share of the bottleneck over the starvation window (after its return)."""

    def to_dict(self) -> dict[str, Any]:
        return {
            "controllers": self.controllers,
            "scheme": self.scheme,
            "seeds": self.seeds,
            "starved_seeds": self.starved_seeds,
            "tcp_share_after_over_before": self.share_ratio.to_dict(3),
            "tcp_share_ratios": [round(v, 3) for v in self.share_ratios],
            "seeds_outside_factor_two": self.outside_factor_two,
            "goodput_kbps_M->S": self.tdtp_goodput_kbps.to_dict(1),
            "tcp_goodput_kbps_M->S": self.tcp_goodput_kbps.to_dict(1),
            "bands": self.bands,
        }


@dataclass
class LockoutStudy(ScenarioResult):
    scenario: ClassVar[str] = "lockout"
    params: dict[str, Any]
    outcomes: list[LockoutOutcome]
    traces: dict[str, dict[str, Any]] = field(default_factory=dict)
    """By scheme: one seed that the earlier controller locked out (or the first seed), run by both:
    ``{"seed": n, "earlier": series, "current": series}`` with master-to-slave ``delivered_pps``,
    ``allowed_pps`` and TCP ``goodput_kbps`` per bin."""

    def headline(self) -> dict[str, Any]:
        """Per pair of controllers and scheme: seeds, starved seeds, runs outside a factor of two, and TCP's share after the return over before."""
        out: dict[str, Any] = {}
        for o in self.outcomes:
            out.setdefault(o.controllers, {})[o.scheme] = {
                "seeds": len(o.seeds),
                "starved": o.starved_seeds,
                "outside_factor_two": o.outside_factor_two,
                "tcp_share_after_over_before": o.share_ratio.to_dict(3),
            }
        return json_safe(out)  # type: ignore[no-any-return]

    def by_controller(self) -> dict[str, Any]:
        """The current controllers by controller name: ``{NAME: {starved_seeds, tcp_share_after_pause,
        ...}}``, where ``tcp_share_after_pause`` is the median over the seeds of TCP's share of the
        bottleneck after the pause over its share before (1 = all of it back)."""
        out: dict[str, Any] = {}
        for o in self.outcomes:
            if o.controllers != "current":
                continue
            name = SCHEMES[o.scheme].controller
            out[name] = {
                "scheme": o.scheme,
                "seeds": o.seeds,
                "starved_seeds": o.starved_seeds,
                "tcp_share_after_pause": None
                if o.share_after is None
                else o.share_after.to_dict(3)["median"],
                "tcp_share_after_pause_interval": None
                if o.share_after is None
                else o.share_after.to_dict(3),
                "tcp_share_after_over_before": o.share_ratio.to_dict(3),
                "note": "the paper's controller" if name in ("trinomial", "tfrc") else "default",
            }
        return json_safe(out)  # type: ignore[no-any-return]

    def details(self) -> dict[str, Any]:
        """Per controller its medians with intervals, the per-seed figures and the traces."""
        return {
            "controllers": self.by_controller(),
            "outcomes": [o.to_dict() for o in self.outcomes],
            "traces": self.traces,
        }


def lockout_study(
    *,
    seeds: Sequence[int] = tuple(range(1, LOCKOUT_SEEDS + 1)),
    earlier_seeds: Sequence[int] | None = None,
    schemes: Sequence[str] = ("tdtp", "tfrc", "teleop"),
    reading: Reading | None = None,
    duration: float = 100.0,
    bin_width: float = 1.0,
    jobs: int = 1,
    records: Mapping[tuple[Any, ...], RunRecord] | None = None,
) -> LockoutStudy:
    """Does a TCP flow get its share back after the pause? Current against earlier controllers.
    ``reading`` is the literal one unless given (``--queue bytes`` changes its queues)."""
    started = time.perf_counter()
    how = reading if reading is not None else READINGS["literal"]
    tasks = lockout_tasks(
        seeds=seeds,
        earlier_seeds=earlier_seeds,
        schemes=schemes,
        reading=how,
        duration=duration,
        bin_width=bin_width,
    )
    done = _complete(tasks, records, jobs)
    outcomes = []
    for controllers in ("current", "earlier"):
        for scheme in schemes:
            if not _has_variant(scheme, controllers):
                continue
            recs = [
                done[t.key()] for t in tasks if t.controllers == controllers and t.scheme == scheme
            ]
            ratios = [r.tcp[MS]["share_ratio"] for r in recs]
            outcomes.append(
                LockoutOutcome(
                    controllers=controllers,
                    scheme=scheme,
                    seeds=[r.seed for r in recs],
                    starved_seeds=[r.seed for r in recs if MS in r.starved],
                    share_ratio=_mi(ratios),
                    share_ratios=ratios,
                    outside_factor_two=[
                        r.seed
                        for r, v in zip(recs, ratios, strict=True)
                        if not (v is not None and 0.5 <= v <= 2.0)
                    ],
                    tdtp_goodput_kbps=_mi(r.goodput_kbps[MS]["all"] for r in recs),
                    tcp_goodput_kbps=_mi(r.tcp[MS]["goodput_kbps"] for r in recs),
                    share_after=_mi(r.tcp[MS].get("share_after", math.nan) for r in recs),
                    bands={
                        MS: _band([r.series[MS]["goodput_kbps"] for r in recs]),
                        f"tcp {MS}": _band([r.series[f"tcp {MS}"]["goodput_kbps"] for r in recs]),
                    },
                )
            )
    traces: dict[str, dict[str, Any]] = {}
    for scheme in schemes:
        earlier = next(
            (o for o in outcomes if o.scheme == scheme and o.controllers == "earlier"), None
        )
        if earlier is None:
            continue
        both = [seed for seed in earlier.seeds if seed in seeds]
        if not both:
            continue
        seed = next((x for x in earlier.starved_seeds if x in both), both[0])
        trace: dict[str, Any] = {"seed": seed}
        for t in tasks:
            if t.scheme == scheme and t.seed == seed:
                rec = done[t.key()]
                trace[t.controllers] = {
                    "delivered_pps": rec.series[MS]["delivered_pps"],
                    "allowed_pps": rec.series[MS]["allowed_pps"],
                    "tcp_goodput_kbps": rec.series[f"tcp {MS}"]["goodput_kbps"],
                }
        traces[scheme] = trace
    params = {
        "reading": how.to_dict(),
        "duration": duration,
        "bin_width": bin_width,
        "tcp_ms_paused": list(tcp_pause(duration)),
        "starvation": f"TCP below {STARVATION_SHARE:.0%} of its fair share over "
        f"{tail_window(duration)[0]:g}-{duration:g} s",
        "criterion": "TCP's share of the bottleneck over the starvation window within a factor of "
        "2 of its share before the pause",
        "controllers": {
            "current": "the controllers' defaults",
            "earlier": "decrease_in_use=False (trinomial), data_limited_decrease=None (tfrc): "
            "the controllers before the lock-out fix",
        },
        "interval": f"95 % {INTERVAL_METHOD}",
        "wall_time_s": round(time.perf_counter() - started, 1),
    }
    return LockoutStudy(params=params, outcomes=outcomes, traces=traces)
