"""Figures of the simulated scenarios (matplotlib, imported only when a figure is drawn).

matplotlib is an optional dependency: ``pip install 'tdtp[plot]'``. Without it every function here
raises :class:`PlotUnavailableError` (an :class:`ImportError`) saying so.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tdtp.sim.scenarios import (
    MS,
    SCHEMES,
    SM,
    BestEffortResult,
    FairnessResult,
    FriendlinessResult,
    PaperResult,
    PaperRun,
)

__all__ = [
    "PlotUnavailableError",
    "plot_best_effort",
    "plot_fairness",
    "plot_friendliness",
    "plot_paper",
    "plot_paper_comparison",
    "plot_paper_run",
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


def _nan(values: Sequence[float | None], scale: float = 1.0) -> list[float]:
    return [math.nan if v is None else v * scale for v in values]


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path


def plot_paper_run(
    result: PaperResult, scheme: str, path: str | Path, *, title: str | None = None
) -> Path:
    """Figures 7/8: throughput, packet loss and delay vs time, both directions, for one scheme."""
    plt = _pyplot()
    run: PaperRun = result.runs[scheme]
    free = result.params["tcp_ms_paused"]
    fig, axes = plt.subplots(3, 1, figsize=(9.0, 8.0), sharex=True)
    for direction in (MS, SM):
        series = run.series[direction]
        t = series["time"]
        color = _COLORS[direction]
        axes[0].plot(t, _nan(series["goodput_kbps"]), color=color, label=f"{direction} goodput")
        axes[1].plot(t, _nan(series["loss_ratio"], 100), color=color, label=direction)
        axes[2].plot(t, _nan(series["mean_delay"], 1000), color=color, label=direction)
    for direction, style in (("tcp M->S", ":"), ("tcp S->M", "--")):
        series = run.series[direction]
        axes[0].plot(
            series["time"],
            _nan(series["goodput_kbps"]),
            color="0.55",
            linestyle=style,
            linewidth=1,
            label=f"TCP {direction[4:]}",
        )
    for ax in axes:
        ax.axvspan(free[0], free[1], color="0.9", zorder=0)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("goodput (kbit/s)")
    axes[1].set_ylabel("packet loss (%)")
    axes[2].set_ylabel("one-way delay (ms)")
    axes[2].set_xlabel("time (s)")
    axes[0].legend(loc="upper right", fontsize=8, ncol=2)
    axes[1].legend(loc="upper right", fontsize=8)
    axes[0].text(
        (free[0] + free[1]) / 2,
        0.97,
        "no TCP M->S",
        transform=axes[0].get_xaxis_transform(),
        ha="center",
        va="top",
        fontsize=8,
    )
    fig.suptitle(title or f"{run.label}: figure 6 topology, 1 Mbit/s bottleneck, TCP both ways")
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_paper_comparison(result: PaperResult, path: str | Path) -> Path:
    """Goodput of every scheme, one panel per direction."""
    plt = _pyplot()
    free = result.params["tcp_ms_paused"]
    fig, axes = plt.subplots(2, 1, figsize=(9.0, 6.0), sharex=True)
    for ax, direction in zip(axes, (MS, SM), strict=True):
        for key, run in result.runs.items():
            series = run.series[direction]
            mean_kbps = run.summaries[direction]["all"].goodput_kbps
            ax.plot(
                series["time"],
                _nan(series["goodput_kbps"]),
                color=_COLORS.get(key),
                label=f"{SCHEMES[key].label}: mean {mean_kbps:.0f} kbit/s",
            )
        ax.axvspan(free[0], free[1], color="0.9", zorder=0)
        ax.set_ylabel(f"{direction} goodput (kbit/s)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    axes[-1].set_xlabel("time (s)")
    fig.suptitle("Samples delivered (100-byte payloads): TDTP vs Trinomial vs TDTP+TFRC")
    fig.tight_layout()
    return _save(fig, Path(path))


def plot_paper(result: PaperResult, out_dir: str | Path) -> list[Path]:
    """Every figure of the paper scenario into ``out_dir``."""
    out = Path(out_dir)
    paths = []
    names = {
        "tdtp": "figure7_tdtp.png",
        "trinomial": "figure8_trinomial.png",
        "tfrc": "paper_tfrc.png",
    }
    for key in result.runs:
        paths.append(plot_paper_run(result, key, out / names.get(key, f"paper_{key}.png")))
    paths.append(plot_paper_comparison(result, out / "paper_comparison.png"))
    return paths


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
