"""Figures of the simulated scenarios (matplotlib, imported only when a figure is drawn).

matplotlib is an optional dependency: ``pip install 'tdtp[plot]'``. Without it every function here
raises :class:`PlotUnavailableError` (an :class:`ImportError`) saying so.
"""

from __future__ import annotations

import importlib
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from tdtp.sim.scenarios import (
    MS,
    SCHEMES,
    SM,
    BestEffortResult,
    FairnessResult,
    FriendlinessResult,
)
from tdtp.sim.study import BOTH, LockoutStudy, PaperStudy

__all__ = [
    "PlotUnavailableError",
    "ensure_matplotlib",
    "plot_best_effort",
    "plot_fairness",
    "plot_friendliness",
    "plot_lockout",
    "plot_lockout_trace",
    "plot_ratios",
    "plot_study",
    "plot_study_run",
    "study_figure_jobs",
]

_COLORS = {
    MS: "tab:blue",
    SM: "tab:red",
    "tdtp": "tab:blue",
    "trinomial": "tab:orange",
    "tfrc": "tab:green",
}


class PlotUnavailableError(ImportError):
    """matplotlib is not installed: ``pip install 'tdtp[plot]'`` (or ``pip install matplotlib``)."""


def _pyplot() -> Any:
    try:
        matplotlib = importlib.import_module("matplotlib")
    except ImportError as exc:
        raise PlotUnavailableError(
            "the simulator's figures need matplotlib, an optional dependency: "
            "pip install 'tdtp[plot]' (or pip install matplotlib); "
            "run with --no-plots to write the JSON only"
        ) from exc
    matplotlib.use("Agg")  # files only, no display needed
    return importlib.import_module("matplotlib.pyplot")


def ensure_matplotlib() -> None:
    """Raise :class:`PlotUnavailableError` at once if matplotlib is missing."""
    _pyplot()


def _nan(values: Sequence[float | None], scale: float = 1.0) -> list[float]:
    return [math.nan if v is None else v * scale for v in values]


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path


def _band(
    ax: Any,
    times: Sequence[float],
    band: dict[str, list[float | None]],
    scale: float,
    color: str,
    label: str,
    *,
    linestyle: str = "-",
    alpha: float = 0.25,
) -> None:
    ax.fill_between(
        times,
        _nan(band["low"], scale),
        _nan(band["high"], scale),
        color=color,
        alpha=alpha,
        linewidth=0,
    )
    ax.plot(times, _nan(band["median"], scale), color=color, linestyle=linestyle, label=label)


def _bin_times(study_params: dict[str, Any]) -> list[float]:
    width = study_params["bin_width"]
    n = round(study_params["duration"] / width)
    return [(i + 0.5) * width for i in range(n)]


def plot_study_run(study: PaperStudy, reading: str, scheme: str, path: str | Path) -> Path:
    """Figures 7/8 over the seeds: goodput, packet loss and delay vs time, both directions; the line
    is the per-bin median of the seeds, the band their 10th-90th percentiles."""
    plt = _pyplot()
    summary = study.readings[reading].schemes[scheme]
    params = study.params
    times = _bin_times(params)
    free = params["tcp_ms_paused"]
    fig, axes = plt.subplots(3, 1, figsize=(9.0, 8.0), sharex=True)
    for direction in (MS, SM):
        bands = summary.bands[direction]
        color = _COLORS[direction]
        mean = summary.goodput_kbps[direction]["all"]
        _band(
            axes[0],
            times,
            bands["goodput_kbps"],
            1.0,
            color,
            f"{direction} goodput, median {mean.median:.0f} kbit/s",
        )
        _band(axes[1], times, bands["loss_ratio"], 100.0, color, direction)
        _band(axes[2], times, bands["mean_delay"], 1000.0, color, direction)
    for direction, style in ((MS, ":"), (SM, "--")):
        band = summary.bands[f"tcp {direction}"]["goodput_kbps"]
        if any(v for v in band["high"]):
            _band(
                axes[0], times, band, 1.0, "0.45", f"TCP {direction}", linestyle=style, alpha=0.15
            )
    for ax in axes:
        ax.axvspan(free[0], free[1], color="0.9", zorder=0)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("goodput (kbit/s)")
    axes[1].set_ylabel("packet loss (%)")
    axes[2].set_ylabel("one-way delay (ms)")
    axes[2].set_xlabel("time (s); shaded: no TCP master-to-slave")
    axes[0].legend(loc="upper right", fontsize=8, ncol=2)
    axes[1].legend(loc="upper right", fontsize=8)
    how = study.readings[reading].reading
    starved = sum(len(v) for v in summary.starved_seeds.values())
    fig.suptitle(
        f"{SCHEMES[scheme].label}, reading '{reading}' ({len(summary.seeds)} seeds: median, "
        f"10-90 % band; {starved} with starved TCP)\n{how.describe()}",
        fontsize=10,
    )
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_ratios(study: PaperStudy, path: str | Path, pair: str = "tdtp/trinomial") -> Path:
    """The goodput ratio of every seed under every reading (dots), its median and 95 % interval."""
    plt = _pyplot()
    names = [n for n, r in study.readings.items() if pair in r.ratios]
    fig, axes = plt.subplots(1, 3, figsize=(14.0, 4.4), sharey=True)
    for ax, direction in zip(axes, (MS, SM, BOTH), strict=True):
        for x, name in enumerate(names):
            ratio = study.readings[name].ratios[pair]
            values = ratio.per_seed[direction]["all"]
            seeds = study.readings[name].schemes["trinomial"].seeds
            for i, (seed, v) in enumerate(zip(seeds, values, strict=True)):
                starved = seed in ratio.starved_seeds
                ax.plot(
                    x - 0.15 + 0.3 * i / max(1, len(values) - 1),
                    v,
                    "o",
                    color="tab:red" if starved else _COLORS["tdtp"],
                    markersize=4,
                    alpha=0.7,
                )
            m = ratio.all_seeds[direction]["all"]
            ax.errorbar(
                x + 0.28,
                m.median,
                yerr=[[m.median - m.low], [m.high - m.median]],
                fmt="D",
                color="k",
                capsize=4,
                markersize=5,
            )
            ax.annotate(f"{m.median:.2f}", (x + 0.33, m.median), fontsize=8, va="center")
        ax.axhline(1.0, color="0.4", linewidth=1, linestyle="--")
        ax.axhline(2.0, color="0.7", linewidth=1, linestyle=":")
        ax.set_xticks(range(len(names)))
        ax.set_xticklabels(names, fontsize=8, rotation=15)
        what = "both directions together" if direction == BOTH else direction
        ax.set_title(f"goodput {pair}, {what}", fontsize=10)
        ax.set_yscale("log")
        ticks = [0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0]
        ax.set_yticks(ticks)
        ax.set_yticklabels([f"{t:g}" for t in ticks])
        ax.minorticks_off()
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].set_ylabel("ratio (log scale); 2 = the paper's claim")
    fig.suptitle(
        "Goodput ratio per seed (dots; red: a TCP flow starved), median and 95 % interval (black)",
        fontsize=10,
    )
    fig.tight_layout()
    return _save(fig, Path(path))


FigureJob = tuple[Callable[..., Path], tuple[Any, ...]]
"""One figure to draw: a plotting function and its arguments (picklable, for a process pool)."""


def study_figure_jobs(study: PaperStudy, out_dir: str | Path) -> list[FigureJob]:
    """The figures of the paper study: figures 7 and 8 per reading, TFRC's, and the ratios. A run
    that a reading does not change (TDTP's under another ACK form) is drawn once."""
    out = Path(out_dir)
    jobs: list[FigureJob] = []
    drawn: list[Any] = []
    for name, summary in study.readings.items():
        suffix = (
            "" if name == "literal" else "_" + re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")
        )
        files = {
            "tdtp": f"figure7_tdtp{suffix}.png",
            "trinomial": f"figure8_trinomial{suffix}.png",
            "tfrc": f"paper_tfrc{suffix}.png",
        }
        for key, scheme_summary in summary.schemes.items():
            same = (key, scheme_summary.seeds, scheme_summary.goodput_kbps)
            if same in drawn:
                continue
            drawn.append(same)
            path = out / files.get(key, f"paper_{key}{suffix}.png")
            jobs.append((plot_study_run, (study, name, key, path)))
    if any("tdtp/trinomial" in r.ratios for r in study.readings.values()):
        jobs.append((plot_ratios, (study, out / "paper_ratios.png")))
    return jobs


def plot_study(study: PaperStudy, out_dir: str | Path) -> list[Path]:
    """Every figure of :func:`study_figure_jobs` into ``out_dir``, one after the other."""
    return [function(*args) for function, args in study_figure_jobs(study, out_dir)]


def plot_lockout(study: LockoutStudy, path: str | Path) -> Path:
    """Master-to-slave goodput of the 1 kHz flow and of TCP over the seeds, earlier and current
    controllers side by side."""
    plt = _pyplot()
    schemes = list(dict.fromkeys(o.scheme for o in study.outcomes))
    fig, axes = plt.subplots(
        len(schemes),
        2,
        figsize=(11.0, 3.2 * len(schemes)),
        sharex=True,
        sharey=True,
        squeeze=False,
    )
    params = study.params
    times = _bin_times(params)
    free = params["tcp_ms_paused"]
    for row, scheme in enumerate(schemes):
        for col, controllers in enumerate(("earlier", "current")):
            ax = axes[row, col]
            found = [
                o for o in study.outcomes if o.scheme == scheme and o.controllers == controllers
            ]
            if not found:  # a controller with no earlier variant (teleop)
                ax.set_axis_off()
                continue
            outcome = found[0]
            _band(
                ax, times, outcome.bands[MS], 1.0, _COLORS.get(scheme, "tab:blue"), f"{scheme} M->S"
            )
            _band(
                ax,
                times,
                outcome.bands[f"tcp {MS}"],
                1.0,
                "0.35",
                "TCP M->S",
                linestyle="--",
                alpha=0.2,
            )
            ax.axvspan(free[0], free[1], color="0.9", zorder=0)
            ax.grid(True, alpha=0.3)
            m = outcome.share_ratio
            ax.set_title(
                f"{scheme}, {controllers} controller: TCP starved in {len(outcome.starved_seeds)} "
                f"of {len(outcome.seeds)} seeds;\nshare after/before {m.median:.2f} "
                f"[{m.low:.2f}, {m.high:.2f}]",
                fontsize=9,
            )
            if col == 0:
                ax.set_ylabel("goodput (kbit/s)")
            if row == 0 and col == 1:
                ax.legend(fontsize=8, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("time (s); shaded: TCP paused")
    fig.suptitle(
        "Lock-out check, literal reading: median and 10-90 % band over the seeds", fontsize=10
    )
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_lockout_trace(study: LockoutStudy, path: str | Path) -> Path:
    """One seed that the earlier controller locked out, run by both: what the 1 kHz flow was allowed
    and what it sent (packets/s, left axis), and what TCP got (kbit/s, right axis)."""
    plt = _pyplot()
    schemes = [
        k for k in study.traces if "earlier" in study.traces[k] and "current" in study.traces[k]
    ]
    if not schemes:  # only controllers without an earlier variant: nothing to compare
        fig, ax = plt.subplots(figsize=(6.0, 1.0))
        ax.set_axis_off()
        ax.text(0.5, 0.5, "no earlier controller to compare with", ha="center", va="center")
        return _save(fig, Path(path))
    fig, axes = plt.subplots(
        len(schemes), 1, figsize=(10.0, 3.3 * max(1, len(schemes))), sharex=True, squeeze=False
    )
    params = study.params
    times = _bin_times(params)
    free = params["tcp_ms_paused"]
    shown = [t for t in times if free[0] - 5 <= t <= free[1] + 20]
    lo, hi = times.index(shown[0]), times.index(shown[-1]) + 1
    for ax, scheme in zip(axes[:, 0], schemes, strict=True):
        trace = study.traces[scheme]
        tcp_ax = ax.twinx()
        for controllers, style in (("earlier", "--"), ("current", "-")):
            series = trace[controllers]
            color = "tab:orange" if controllers == "earlier" else _COLORS.get(scheme, "tab:blue")
            ax.plot(
                shown,
                series["delivered_pps"][lo:hi],
                color=color,
                linestyle=style,
                label=f"{controllers}: sent",
            )
            ax.plot(
                shown,
                series["allowed_pps"][lo:hi],
                color=color,
                linestyle=":",
                linewidth=1,
                label=f"{controllers}: allowed",
            )
            tcp_ax.plot(
                shown,
                _nan(series["tcp_goodput_kbps"][lo:hi]),
                color="0.4",
                linestyle=style,
                linewidth=1.5,
                label=f"TCP, {controllers} {scheme}",
            )
        ax.axvspan(free[0], free[1], color="0.9", zorder=0)
        ax.set_ylabel(f"{scheme} M->S (packets/s)")
        tcp_ax.set_ylabel("TCP M->S goodput (kbit/s)")
        ax.set_ylim(0, 2200)
        tcp_ax.set_ylim(0, 1000)
        ax.grid(True, alpha=0.3)
        ax.set_title(f"{scheme}, seed {trace['seed']}", fontsize=9)
        lines = ax.get_legend_handles_labels()
        more = tcp_ax.get_legend_handles_labels()
        ax.legend(lines[0] + more[0], lines[1] + more[1], fontsize=7, loc="upper right", ncol=3)
    axes[-1, 0].set_xlabel("time (s); shaded: TCP paused")
    fig.suptitle(
        "The lock-out, one seed: allowed twice what it sends, the 1 kHz flow does not slow down on"
        " the earlier controller's halving",
        fontsize=10,
    )
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_friendliness(result: FriendlinessResult, path: str | Path) -> Path:
    """Measured tdtp/TCP packet-rate ratio per case (bars) next to eq. 2's prediction (markers)."""
    plt = _pyplot()
    by_scheme = result.by_scheme()
    fig, axes = plt.subplots(
        len(by_scheme), 1, figsize=(9.0, 2.8 * len(by_scheme)), sharex=True, squeeze=False
    )
    for ax, (key, cases) in zip(axes[:, 0], by_scheme.items(), strict=True):
        xs = list(range(len(cases)))
        ax.bar(
            xs, [c.ratio_pps for c in cases], color=_COLORS.get(key), alpha=0.7, label="measured"
        )
        ax.plot(
            xs,
            [c.eq2_ratio for c in cases],
            "k_",
            markersize=18,
            mew=2,
            label="eq. 2 at tdtp's p, RTT",
        )
        ax.axhline(1.0, color="0.3", linewidth=1, linestyle="--")
        ax.set_ylabel("tdtp / TCP (packets/s)")
        ax.set_title(SCHEMES[key].label, fontsize=9)
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
        ax.set_xticks(xs)
        ax.set_xticklabels(
            [f"{c.capacity_mbps:g} Mbit/s\n{c.rtt_ms:g} ms" for c in cases], fontsize=8
        )
    fig.suptitle("TCP-friendliness: one session and one TCP flow share the bottleneck")
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_fairness(result: FairnessResult, path: str | Path) -> Path:
    """Jain's index over time, one panel per number of flows, one line per scheme."""
    plt = _pyplot()
    counts = sorted({r.flows for r in result.runs})
    fig, axes = plt.subplots(len(counts), 1, figsize=(9.0, 2.6 * len(counts)), squeeze=False)
    for ax, n in zip(axes[:, 0], counts, strict=True):
        for run in (r for r in result.runs if r.flows == n):
            ax.plot(
                run.jain_times,
                _nan(run.jain_ms),
                color=_COLORS.get(run.scheme),
                label=f"{run.scheme}: mean {run.mean_jain_ms:.3f} after {run.converged_from:g} s",
            )
            for start in run.starts[1:]:
                ax.axvline(start, color="0.8", linewidth=0.8)
        ax.axhline(0.95, color="0.3", linestyle="--", linewidth=1)
        ax.set_ylim(0.5, 1.01)
        ax.set_ylabel(f"Jain, N={n}")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    axes[-1, 0].set_xlabel("time (s); grey lines: a flow starts")
    fig.suptitle("Fairness: N sessions on one bottleneck (master-to-slave goodput)")
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_best_effort(result: BestEffortResult, path: str | Path) -> Path:
    """tdtp's goodput and the UDP source's throughput while the capacity is freed and retaken."""
    plt = _pyplot()
    fig, axes = plt.subplots(
        len(result.runs), 1, figsize=(9.0, 2.8 * len(result.runs)), sharex=True, squeeze=False
    )
    on = result.params["cbr_on"]
    capacity = result.params["capacity_mbps"] * 1000
    for ax, run in zip(axes[:, 0], result.runs, strict=True):
        smooth = _moving(run.tdtp_kbps, 5)
        ax.plot(
            run.series_time,
            smooth,
            color=_COLORS.get(run.scheme),
            label="tdtp M->S goodput (0.5 s)",
        )
        ax.plot(run.series_time, _moving(run.cbr_kbps, 5), color="0.4", label="UDP CBR M->S")
        ax.axhline(capacity, color="0.3", linestyle="--", linewidth=1)
        for start, stop in on:
            ax.axvspan(start, stop, color="0.92", zorder=0)
        ax.set_ylabel("kbit/s")
        ax.set_title(
            f"{SCHEMES[run.scheme].label}: fills in {_fmt(run.fill_time_90)} (90 %), "
            f"gives back in {_fmt(run.give_back_time)}",
            fontsize=9,
        )
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("time (s); shaded: UDP source on")
    fig.suptitle("Best effort: capacity freed and retaken")
    fig.tight_layout()
    return _save(fig, Path(path))


def _fmt(value: float | None) -> str:
    return "never" if value is None else f"{value:.1f} s"


def _moving(values: Sequence[float], n: int) -> list[float]:
    out: list[float] = []
    acc = 0.0
    for i, v in enumerate(values):
        acc += v
        if i >= n:
            acc -= values[i - n]
        out.append(acc / min(i + 1, n))
    return out
