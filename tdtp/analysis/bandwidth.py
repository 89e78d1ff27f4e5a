"""The paper's bandwidth model (eqs. 3-8 and figure 5): what a teleoperation flow costs on the wire.

A bilateral teleoperation session sends supermedia data both ways at the same application rate. On the
wire every data packet costs its data field ``SD`` plus the headers below it ``SH``; a scheme with
*separate* acknowledgements also sends one ACK packet per data packet in the opposite direction, which
costs ``SA + SH`` (ACK data plus headers). With ``SA = 0`` (an ACK is a bare header) the paper's eq. 8
gives the cost of separate ACKs relative to piggybacked ones::

    C_total(separate ACKs) = (1 + SH / (SD + SH)) * C_total(bidirectional)

This module computes the on-wire bandwidth of the four schemes of the paper's figure 5, each in three
encapsulations:

=========  ===================================  ====================================  ================
scheme     native (the paper: TDTP right on     UDP/IPv4 (this implementation)        UDP/IPv6
           IPv4)
=========  ===================================  ====================================  ================
TCP        IPv4 20 + TCP 20, 40-byte ACKs       same                                  IPv6 40 + 20
UDP        IPv4 20 + UDP 8, no ACKs             same                                  IPv6 40 + 8
Trinomial  IPv4 20 + 5, separate 25-byte ACKs   IPv4 20 + UDP 8 + 5, 33-byte ACKs     40 + 8 + 5
TDTP       IPv4 20 + 5, ACKs piggybacked        IPv4 20 + UDP 8 + 5, piggybacked      40 + 8 + 5
=========  ===================================  ====================================  ================

Over IPv6 every scheme pays the 40-byte IPv6 header, TCP and UDP included: the comparison is between
transports on the same network.

Rates are in bits per second on the wire (IP packets: link-layer framing is not counted), for both
directions together unless a function says otherwise. The paper's worked example (100-byte data at its
400 kbit/s per direction, i.e. 500 packets/s each way) comes out as TDTP 1.000 Mbit/s, UDP 1.024,
Trinomial 1.200 and TCP 1.440.

:func:`figure5_table` and :func:`plot_figure5` reproduce figure 5 (data sizes 1..1000 bytes);
:func:`format_markdown` and :func:`format_csv` print a table. Plotting needs matplotlib, which is an
optional dependency (``pip install 'tdtp[plot]'``); it is imported only when :func:`plot_figure5` runs.
"""

from __future__ import annotations

import enum
import importlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tdtp.errors import InvalidArgumentError

__all__ = [
    "FIGURE5_SIZES",
    "IPV6_HEADER",
    "IP_HEADER",
    "PAPER_APP_RATE",
    "TCP_HEADER",
    "TDTP_HEADER",
    "UDP_HEADER",
    "Encapsulation",
    "Figure5Row",
    "PlotUnavailableError",
    "Scheme",
    "eq7_total",
    "eq8_separate_ack_factor",
    "figure5_table",
    "format_csv",
    "format_markdown",
    "packet_rate",
    "plot_figure5",
    "scheme",
    "schemes",
    "wire_bandwidth",
    "wire_bandwidth_from_data_rate",
]

IP_HEADER = 20
"""IPv4 header without options, bytes."""
IPV6_HEADER = 40
"""IPv6 header without extension headers, bytes."""
TCP_HEADER = 20
"""TCP header without options, bytes."""
UDP_HEADER = 8
"""UDP header, bytes."""
TDTP_HEADER = 5
"""TDTP base header, bytes (``tdtp.wire.HEADER_SIZE``)."""
PAPER_APP_RATE = 400_000.0
"""Figure 5's application data rate in each direction, bits per second (400 kbit/s)."""

FIGURE5_SIZES: tuple[int, ...] = tuple(range(1, 1001))
"""Figure 5's x axis: data field sizes 1..1000 bytes."""


class Encapsulation(enum.Enum):
    """Where the TDTP (and Trinomial) header sits. TCP and UDP are the same in both."""

    NATIVE = "native"
    """The paper's: the 5-byte header directly on IP (20 + 5 = 25 bytes per packet)."""
    UDP = "udp"
    """This implementation's: over UDP over IPv4 (20 + 8 + 5 = 33 bytes per packet)."""
    UDP6 = "udp6"
    """Over UDP over IPv6 (40 + 8 + 5 = 53 bytes per packet); TCP and UDP over IPv6 too."""

    @property
    def ip_header(self) -> int:
        """Bytes of the IP header every packet carries in this encapsulation."""
        return IPV6_HEADER if self is Encapsulation.UDP6 else IP_HEADER

    @property
    def label(self) -> str:
        """What sits under the 5-byte header, for tables and figures."""
        return {"native": "IPv4", "udp": "UDP/IPv4", "udp6": "UDP/IPv6"}[self.value]


@dataclass(frozen=True, slots=True)
class Scheme:
    """A transport scheme's per-packet cost on the wire."""

    name: str
    """``"TCP"``, ``"UDP"``, ``"Trinomial"`` or ``"TDTP"``."""
    header: int
    """``SH``: bytes below the data field in every data packet (IP header included)."""
    ack: int
    """Bytes on the wire of the separate ACK packet sent back for every data packet; 0 when the scheme
    sends none (UDP) or piggybacks its acknowledgements on the reverse data (TDTP)."""

    def __post_init__(self) -> None:
        if self.header < 0 or self.ack < 0:
            raise InvalidArgumentError(f"header and ack sizes must be >= 0 bytes, got {self!r}")

    def bytes_per_sample(self, data_size: int) -> int:
        """Wire bytes one data packet costs, its own ACK (travelling the other way) included."""
        return data_size + self.header + self.ack


def schemes(encapsulation: Encapsulation = Encapsulation.NATIVE) -> tuple[Scheme, ...]:
    """The four schemes of figure 5, in the paper's order: TCP, UDP, Trinomial, TDTP.

    Trinomial and TDTP carry the 5-byte header on IPv4 (``NATIVE``), on UDP over IPv4 (``UDP``) or on
    UDP over IPv6 (``UDP6``); TCP and UDP use the encapsulation's IP version. Trinomial's separate ACK
    is a bare header (``SA = 0``, as in eq. 8).
    """
    ip = encapsulation.ip_header
    tdtp = ip + TDTP_HEADER
    if encapsulation is not Encapsulation.NATIVE:
        tdtp += UDP_HEADER
    tcp = ip + TCP_HEADER
    return (
        Scheme("TCP", tcp, tcp),
        Scheme("UDP", ip + UDP_HEADER, 0),
        Scheme("Trinomial", tdtp, tdtp),
        Scheme("TDTP", tdtp, 0),
    )


def scheme(name: str, encapsulation: Encapsulation = Encapsulation.NATIVE) -> Scheme:
    """One of :func:`schemes` by name (case-insensitive): ``tcp``, ``udp``, ``trinomial``, ``tdtp``."""
    for candidate in schemes(encapsulation):
        if candidate.name.lower() == name.lower():
            return candidate
    known = ", ".join(s.name for s in schemes(encapsulation))
    raise InvalidArgumentError(f"unknown scheme {name!r}; known: {known}")


def _check_size(data_size: int) -> None:
    if data_size <= 0:
        raise InvalidArgumentError(
            f"data_size must be a positive number of bytes, got {data_size!r}"
        )


def packet_rate(app_rate: float, data_size: int) -> float:
    """Data packets per second one direction sends to carry ``app_rate`` bit/s in ``data_size``-byte
    data fields (the paper's figure 5: 400 kbit/s in 100-byte fields is 500 packets/s)."""
    _check_size(data_size)
    if not app_rate >= 0:
        raise InvalidArgumentError(f"app_rate must be >= 0 bit/s, got {app_rate!r}")
    return app_rate / (8.0 * data_size)


def wire_bandwidth(
    scheme: Scheme,
    data_size: int,
    app_rate: float = PAPER_APP_RATE,
    *,
    directions: int = 2,
) -> float:
    """Bits per second on the wire for ``directions`` (1 or 2) symmetric flows of ``app_rate`` bit/s each.

    Each direction sends ``packet_rate(app_rate, data_size)`` data packets of ``data_size + header``
    bytes and, for a scheme with separate ACKs, as many ACK packets back. With two symmetric directions
    every link direction carries one data flow and the other flow's ACKs: eq. 6.
    """
    if directions not in (1, 2):
        raise InvalidArgumentError(f"directions must be 1 or 2, got {directions!r}")
    return directions * packet_rate(app_rate, data_size) * 8.0 * scheme.bytes_per_sample(data_size)


def wire_bandwidth_from_data_rate(scheme: Scheme, data_rate: float, data_size: int) -> float:
    """Eq. 5-8 written as the paper writes them: the wire rate for a total application data rate.

    ``data_rate`` is ``C_data`` in bit/s, all directions together (e.g. as measured), carried in
    ``data_size``-byte data fields. Returns ``C_total`` in bit/s: the data packets' headers scale it by
    ``(SD + SH) / SD`` and separate ACKs add ``C_ack = C_data_packets * ACK / (SD + SH)`` (eq. 5).
    """
    _check_size(data_size)
    return data_rate * scheme.bytes_per_sample(data_size) / data_size


def eq8_separate_ack_factor(data_size: int, header: int) -> float:
    """Eq. 8: ``1 + SH / (SD + SH)``, how much more separate bare-header ACKs cost than piggybacked ones."""
    _check_size(data_size)
    return 1.0 + header / (data_size + header)


def eq7_total(data_packet_rate: float, data_size: int, header: int, ack_data: int = 0) -> float:
    """Eq. 7: ``C_total = (1 + (SA + SH) / (SD + SH)) * C_data``, in bit/s.

    ``C_data`` is the data packets' own wire rate, ``data_packet_rate * (SD + SH) * 8``, where
    ``data_packet_rate`` counts the data packets per second of all directions together. One ACK of
    ``SA + SH`` bytes (``ack_data + header``) goes back for every data packet; ``ack_data = 0`` is eq. 8.
    """
    _check_size(data_size)
    data_wire = data_packet_rate * (data_size + header) * 8.0
    return (1.0 + (ack_data + header) / (data_size + header)) * data_wire


@dataclass(frozen=True, slots=True)
class Figure5Row:
    """One x value of figure 5: the wire bandwidth of each scheme at one data size, bit/s."""

    encapsulation: Encapsulation
    data_size: int
    packet_rate: float
    """Data packets per second in each direction."""
    tcp: float
    udp: float
    trinomial: float
    tdtp: float

    def by_scheme(self) -> dict[str, float]:
        """The row's four bandwidths (bits/s) by scheme name, in the figure's order."""
        return {"TCP": self.tcp, "UDP": self.udp, "Trinomial": self.trinomial, "TDTP": self.tdtp}


def figure5_table(
    data_sizes: Iterable[int] = FIGURE5_SIZES,
    *,
    app_rate: float = PAPER_APP_RATE,
    encapsulations: Sequence[Encapsulation] = (Encapsulation.NATIVE, Encapsulation.UDP),
) -> list[Figure5Row]:
    """Figure 5 as rows: for each encapsulation, then each data size, the four schemes' bit/s on the
    wire for ``app_rate`` bit/s in each direction (both directions together).

    ``figure5_table([100], encapsulations=[Encapsulation.NATIVE])`` is the paper's worked example.
    """
    sizes = list(data_sizes)
    rows: list[Figure5Row] = []
    for encapsulation in encapsulations:
        tcp, udp, trinomial, tdtp = schemes(encapsulation)
        for size in sizes:
            rows.append(
                Figure5Row(
                    encapsulation=encapsulation,
                    data_size=size,
                    packet_rate=packet_rate(app_rate, size),
                    tcp=wire_bandwidth(tcp, size, app_rate),
                    udp=wire_bandwidth(udp, size, app_rate),
                    trinomial=wire_bandwidth(trinomial, size, app_rate),
                    tdtp=wire_bandwidth(tdtp, size, app_rate),
                )
            )
    return rows


_SCHEME_NAMES = ("TCP", "UDP", "Trinomial", "TDTP")


def format_markdown(rows: Iterable[Figure5Row]) -> str:
    """A Markdown table of :func:`figure5_table` rows, in Mbit/s."""
    lines = [
        "| encapsulation | data (bytes) | packets/s each way | "
        + " | ".join(f"{name} (Mbit/s)" for name in _SCHEME_NAMES)
        + " |",
        "| --- | ---: | ---: | " + " | ".join("---:" for _ in _SCHEME_NAMES) + " |",
    ]
    for row in rows:
        values = row.by_scheme()
        lines.append(
            f"| {row.encapsulation.value} | {row.data_size} | {row.packet_rate:.1f} | "
            + " | ".join(f"{values[name] / 1e6:.3f}" for name in _SCHEME_NAMES)
            + " |"
        )
    return "\n".join(lines)


def format_csv(rows: Iterable[Figure5Row]) -> str:
    """CSV of :func:`figure5_table` rows (bit/s, full precision), with a header line."""
    lines = [
        "encapsulation,data_size,packets_per_s,"
        + ",".join(f"{name.lower()}_bps" for name in _SCHEME_NAMES)
    ]
    for row in rows:
        values = row.by_scheme()
        lines.append(
            f"{row.encapsulation.value},{row.data_size},{row.packet_rate!r},"
            + ",".join(repr(values[name]) for name in _SCHEME_NAMES)
        )
    return "\n".join(lines) + "\n"


class PlotUnavailableError(ImportError):
    """matplotlib is not installed: ``pip install 'tdtp[plot]'`` (or ``pip install matplotlib``)."""


def _pyplot() -> Any:
    try:
        matplotlib = importlib.import_module("matplotlib")
    except ImportError as exc:
        raise PlotUnavailableError(
            "plotting figure 5 needs matplotlib, an optional dependency: "
            "pip install 'tdtp[plot]' (or pip install matplotlib)"
        ) from exc
    matplotlib.use("Agg")  # files only, no display needed
    return importlib.import_module("matplotlib.pyplot")


def plot_figure5(
    path: str | Path,
    *,
    data_sizes: Iterable[int] = FIGURE5_SIZES,
    app_rate: float = PAPER_APP_RATE,
    encapsulations: Sequence[Encapsulation] = (Encapsulation.NATIVE, Encapsulation.UDP),
    log_y: bool = True,
) -> Path:
    """Draw figure 5 (wire bandwidth vs data field size, one panel per encapsulation) into ``path``.

    The format follows the file name's suffix (``.png``, ``.svg``, ``.pdf``). Returns the path. Raises
    :class:`PlotUnavailableError` (an :class:`ImportError`) when matplotlib is not installed.
    """
    plt = _pyplot()
    sizes = list(data_sizes)
    target = Path(path)
    fig, axes = plt.subplots(
        1, len(encapsulations), figsize=(6.0 * len(encapsulations), 4.5), squeeze=False
    )
    titles = {
        Encapsulation.NATIVE: "native: TDTP/Trinomial header on IPv4 (20 + 5)",
        Encapsulation.UDP: "ours: TDTP/Trinomial over UDP/IPv4 (20 + 8 + 5)",
        Encapsulation.UDP6: "over UDP/IPv6 (40 + 8 + 5), TCP and UDP on IPv6",
    }
    for ax, encapsulation in zip(axes[0], encapsulations, strict=True):
        rows = figure5_table(sizes, app_rate=app_rate, encapsulations=[encapsulation])
        for name in _SCHEME_NAMES:
            ax.plot(
                [r.data_size for r in rows],
                [r.by_scheme()[name] / 1e6 for r in rows],
                label=name,
            )
        if 100 in sizes:
            example = figure5_table([100], app_rate=app_rate, encapsulations=[encapsulation])[0]
            values = example.by_scheme()
            ax.plot([100] * len(values), [v / 1e6 for v in values.values()], "k.", markersize=4)
            ax.text(
                0.03,
                0.04,
                "at 100 bytes (Mbit/s):\n"
                + "\n".join(f"{name} {values[name] / 1e6:.3f}" for name in _SCHEME_NAMES),
                transform=ax.transAxes,
                fontsize=8,
                family="monospace",
                bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.8},
            )
        ax.set_xscale("log")
        if log_y:
            ax.set_yscale("log")
        ax.set_xlabel("data field size (bytes)")
        ax.set_ylabel("bandwidth on the wire, both directions (Mbit/s)")
        ax.set_title(titles[encapsulation], fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle(
        f"Figure 5: {app_rate / 1e3:g} kbit/s of application data in each direction", fontsize=11
    )
    fig.tight_layout()
    target.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(target, dpi=120)
    plt.close(fig)
    return target
