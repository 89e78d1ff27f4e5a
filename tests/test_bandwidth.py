"""The paper's bandwidth model (eqs. 5-8, figure 5) against its worked example and docs/PROTOCOL.md."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import pytest

from tdtp.analysis.bandwidth import (
    FIGURE5_SIZES,
    PAPER_APP_RATE,
    Encapsulation,
    PlotUnavailableError,
    eq7_total,
    eq8_separate_ack_factor,
    figure5_table,
    format_csv,
    format_markdown,
    packet_rate,
    plot_figure5,
    scheme,
    schemes,
    wire_bandwidth,
    wire_bandwidth_from_data_rate,
)
from tdtp.wire import HEADER_SIZE

NATIVE = Encapsulation.NATIVE
UDP = Encapsulation.UDP


def test_paper_worked_example_100_bytes_500_packets_per_second_each_way() -> None:
    """The paper: 100-byte data, 400 kbit/s (500 pkt/s) each way: TDTP 1.000, UDP 1.024,
    Trinomial 1.200, TCP 1.440 Mbit/s, both directions together."""
    assert packet_rate(PAPER_APP_RATE, 100) == 500.0
    (row,) = figure5_table([100], encapsulations=[NATIVE])
    assert row.packet_rate == 500.0
    assert row.tdtp == pytest.approx(1.000e6)
    assert row.udp == pytest.approx(1.024e6)
    assert row.trinomial == pytest.approx(1.200e6)
    assert row.tcp == pytest.approx(1.440e6)


def test_header_sizes_per_encapsulation() -> None:
    native = {s.name: (s.header, s.ack) for s in schemes(NATIVE)}
    assert native == {"TCP": (40, 40), "UDP": (28, 0), "Trinomial": (25, 25), "TDTP": (25, 0)}
    ours = {s.name: (s.header, s.ack) for s in schemes(UDP)}
    assert ours == {"TCP": (40, 40), "UDP": (28, 0), "Trinomial": (33, 33), "TDTP": (33, 0)}
    assert scheme("tdtp", UDP).header == 20 + 8 + HEADER_SIZE
    # Over IPv6 every scheme carries the 40-byte IPv6 header, TCP and UDP included.
    six = {s.name: (s.header, s.ack) for s in schemes(Encapsulation.UDP6)}
    assert six == {"TCP": (60, 60), "UDP": (48, 0), "Trinomial": (53, 53), "TDTP": (53, 0)}
    assert [e.label for e in Encapsulation] == ["IPv4", "UDP/IPv4", "UDP/IPv6"]


def test_protocol_md_example_over_udp_at_1000_packets_per_second() -> None:
    """docs/PROTOCOL.md section 6: 100-byte payload, 1000 pkt/s each way, over UDP."""
    rate = 1000 * 100 * 8.0  # 1000 packets/s of 100 bytes, bit/s per direction
    assert wire_bandwidth(scheme("udp", UDP), 100, rate) == pytest.approx(2.048e6)
    assert wire_bandwidth(scheme("tdtp", UDP), 100, rate) == pytest.approx(2.128e6)
    assert wire_bandwidth(scheme("trinomial", UDP), 100, rate) == pytest.approx(2.656e6)
    assert wire_bandwidth(scheme("tdtp", NATIVE), 100, rate) == pytest.approx(2.000e6)
    assert wire_bandwidth(scheme("trinomial", NATIVE), 100, rate) == pytest.approx(2.400e6)
    # 40-byte ACK packets over UDP (ack_size 12): eq. 7 with SA = 7.
    assert eq7_total(2000, 100, 33, ack_data=7) == pytest.approx(2.768e6)
    assert wire_bandwidth(scheme("udp", UDP), 100, rate, directions=1) == pytest.approx(1.024e6)


@pytest.mark.parametrize("encapsulation", [NATIVE, UDP])
@pytest.mark.parametrize("size", [1, 20, 100, 333, 1000])
def test_eq8_relates_separate_acks_to_piggybacked(encapsulation: Encapsulation, size: int) -> None:
    trinomial, tdtp = scheme("trinomial", encapsulation), scheme("tdtp", encapsulation)
    factor = eq8_separate_ack_factor(size, tdtp.header)
    assert wire_bandwidth(trinomial, size) == pytest.approx(factor * wire_bandwidth(tdtp, size))
    packets = 2 * packet_rate(PAPER_APP_RATE, size)
    assert eq7_total(packets, size, tdtp.header) == pytest.approx(wire_bandwidth(trinomial, size))


def test_wire_rate_from_a_measured_data_rate() -> None:
    tdtp = scheme("tdtp", UDP)
    assert wire_bandwidth_from_data_rate(tdtp, 1.6e6, 100) == pytest.approx(2.128e6)
    trinomial = scheme("trinomial", UDP)
    assert wire_bandwidth_from_data_rate(trinomial, 1.6e6, 100) == pytest.approx(2.656e6)


def test_figure5_curves_are_ordered_and_converge() -> None:
    rows = figure5_table()
    assert len(rows) == 2 * len(FIGURE5_SIZES) == 2000
    for row in rows:
        # Always TCP > Trinomial > TDTP and UDP >= TDTP natively (UDP's 28 bytes vs 25).
        assert row.tcp > row.trinomial > row.tdtp
        if row.encapsulation is NATIVE:
            assert row.udp > row.tdtp
        else:
            assert row.udp < row.tdtp  # over UDP, TDTP pays its 5 bytes on top
    small = next(r for r in rows if r.data_size == 1 and r.encapsulation is NATIVE)
    large = next(r for r in rows if r.data_size == 1000 and r.encapsulation is NATIVE)
    assert small.tcp / small.tdtp == pytest.approx(81 / 26)
    assert large.tcp / large.tdtp < 1.06  # big data fields: headers hardly matter
    assert large.tdtp > 2 * PAPER_APP_RATE


def test_tables_render_every_row() -> None:
    rows = figure5_table([1, 100, 1000])
    markdown = format_markdown(rows)
    assert "| native | 100 | 500.0 | 1.440 | 1.024 | 1.200 | 1.000 |" in markdown
    assert markdown.count("\n") == 1 + len(rows)
    csv = format_csv(rows).splitlines()
    assert csv[0] == "encapsulation,data_size,packets_per_s,tcp_bps,udp_bps,trinomial_bps,tdtp_bps"
    assert len(csv) == 1 + len(rows)
    fields = csv[2].split(",")
    assert fields[:2] == ["native", "100"] and math.isclose(float(fields[6]), 1e6)


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="data_size"):
        packet_rate(PAPER_APP_RATE, 0)
    with pytest.raises(ValueError, match="directions"):
        wire_bandwidth(scheme("tdtp"), 100, directions=3)
    with pytest.raises(ValueError, match="unknown scheme"):
        scheme("sctp")


def test_plot_figure5_writes_a_png_or_explains_what_is_missing(tmp_path: Path) -> None:
    target = tmp_path / "figure5.png"
    if importlib.util.find_spec("matplotlib") is None:
        with pytest.raises(PlotUnavailableError, match=r"tdtp\[plot\]"):
            plot_figure5(target)
        return
    path = plot_figure5(target, data_sizes=range(1, 1001, 37))
    assert path == target
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
