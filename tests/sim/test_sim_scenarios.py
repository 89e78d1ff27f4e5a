"""Each scenario, run briefly: the direction of its headline result, valid JSON, and the CLI."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
from pathlib import Path

import pytest

from tdtp.cli.simulate import simulate_main
from tdtp.config import AckMode
from tdtp.sim.readings import READINGS
from tdtp.sim.scenarios import (
    SCHEMES,
    best_effort,
    connection_config,
    fairness,
    friendliness,
    paper,
)
from tdtp.wire.header import HEADER_SIZE


def test_scheme_configs_match_the_paper() -> None:
    trinomial = connection_config(SCHEMES["trinomial"])
    assert trinomial.ack_mode is AckMode.SEPARATE
    assert trinomial.ack_size + 20 == 40  # 40-byte ACK packets on the wire, TDTP right on IP
    assert connection_config(SCHEMES["trinomial"], "udp").ack_size + 28 == 40
    assert connection_config(SCHEMES["trinomial"], plain_acks=True).plain_acks
    tdtp = connection_config(SCHEMES["tdtp"], plain_acks=True)
    assert tdtp.ack_mode is AckMode.BIDIRECTIONAL and tdtp.ack_size == HEADER_SIZE
    assert not tdtp.plain_acks  # nothing to make plain: no stand-alone ACKs
    assert tdtp.controller == trinomial.controller == "trinomial"
    assert tdtp.controller_config is None and trinomial.controller_config is None  # same parameters
    assert connection_config(SCHEMES["tfrc"]).controller == "tfrc"


def test_paper_literal_reading_briefly() -> None:
    result = paper(duration=12.0, schemes=("tdtp", "trinomial"))
    assert result.params["reading"]["name"] == "literal"
    assert result.params["tcp"]["variant"] == "tahoe"
    tdtp, trinomial = result.runs["tdtp"], result.runs["trinomial"]
    for run in (tdtp, trinomial):
        for side in ("master", "slave"):
            assert run.connection[side]["closed"] is None
        ms = run.summaries["M->S"]["all"]
        assert 20 < ms.delivered_pps < 900  # alive under TCP cross traffic, and held back by it
        assert 0.013 < ms.mean_delay < 0.3  # 12 ms of propagation, up to 15 queued packets
        # TCP congests the master-to-slave direction only: no TCP flow the other way.
        assert set(run.tcp_outcome) == {"M->S"}
        assert run.tcp["S->M"].sent_packets == 0
        assert run.tcp_outcome["M->S"].goodput_kbps > 200
        assert not run.starved
    # The slave's samples cross no TCP, so TDTP's run free; Trinomial's slave is told of a loss for
    # every ACK the congested master-to-slave queue drops (plain ACKs), and backs off.
    assert tdtp.summaries["S->M"]["all"].delivered_pps > 600
    assert (
        trinomial.connection["slave"]["packets_lost"]
        > trinomial.connection["slave"]["spurious_losses"]
    )
    # The master's data, held back by TCP, is too sparse to carry every report on the slave's
    # 1000 samples/s: stand-alone ACKs fill in (section 3.2 of docs/PROTOCOL.md).
    assert tdtp.connection["master"]["ack_packets_sent"] > 0
    received = trinomial.summaries["S->M"]["all"].delivered_packets
    assert trinomial.connection["master"]["ack_packets_sent"] >= 0.95 * received
    data = json.loads(result.to_json())
    assert data["scenario"] == "paper" and set(data["runs"]) == {"tdtp", "trinomial"}
    assert set(data["ratios"]["tdtp/trinomial"]) == {"all", "tcp_on", "tcp_off"}


def test_paper_both_ways_and_other_readings() -> None:
    both = READINGS["both-ways"]
    result = paper(duration=10.0, schemes=("trinomial",), reading=both)
    run = result.runs["trinomial"]
    assert set(run.tcp_outcome) == {"M->S", "S->M"}
    assert all(o.goodput_kbps > 200 for o in run.tcp_outcome.values())
    # Readings are data: any field can be changed, and bad values are refused.
    bytes_queue = dataclasses.replace(both, name="bytes", queue_unit="bytes", tcp_variant="reno")
    result = paper(duration=6.0, schemes=("tdtp",), reading=bytes_queue)
    assert "7500 bytes" in result.params["bottleneck"]
    assert result.params["tcp"]["variant"] == "reno"
    assert "queues in bytes" in result.params["reading"]["description"]
    with pytest.raises(ValueError, match="tcp_variant"):
        dataclasses.replace(both, tcp_variant="vegas")
    with pytest.raises(ValueError, match="unknown reading"):
        paper(duration=5.0, reading="fig9")
    with pytest.raises(ValueError, match="pause"):
        paper(duration=5.0, pause=(4.0, 6.0))


def test_friendliness_tracks_equation_2() -> None:
    result = friendliness(
        duration=20.0, warmup=5.0, capacities_mbps=(1.0,), rtts_ms=(40.0,), schemes=("tdtp", "tfrc")
    )
    for case in result.cases:
        assert case.tcp_pps > 30 and case.tdtp_pps > 10
        # tdtp stays within a small factor of TCP in packets/s (eq. 2 equalises packets, not bytes)...
        assert 0.3 < case.ratio_pps < 3.0
        # ...and its bytes are a fraction of TCP's: 125-byte packets against 1040-byte segments.
        assert case.ratio_bytes < 0.5
    tdtp = result.by_scheme()["tdtp"][0]
    # it sits at its eq. 2 cap
    assert tdtp.eq2_ratio / tdtp.ratio_pps == pytest.approx(1.0, abs=0.5)
    assert json.loads(result.to_json())["cases"][0]["scheme"] == "tdtp"


def test_fairness_two_flows_converge() -> None:
    result = fairness(
        flow_counts=(2,), schemes=("tdtp",), stagger=3.0, settle=15.0, convergence=6.0
    )
    (run,) = result.runs
    assert run.mean_jain_ms >= 0.95
    assert run.jain_of_means_ms >= 0.95
    assert all(v > 100 for v in run.per_flow_kbps)
    assert run.jain_ms[0] is None  # one flow alone: no index


def test_best_effort_fills_freed_capacity_and_gives_it_back() -> None:
    result = best_effort(duration=18.0, schemes=("tdtp", "trinomial"))
    tdtp, trinomial = result.runs
    assert tdtp.free_level_kbps > 1.5 * tdtp.congested_level_kbps
    assert tdtp.free_level_kbps > 700  # 800 kbit/s of samples offered, 1 Mbit/s link
    assert tdtp.fill_time_90 is not None and tdtp.fill_time_90 < 4.0
    assert tdtp.give_back_time is not None and tdtp.give_back_time < 3.0
    # Against unresponsive traffic the ACKs' bytes are what Trinomial loses: it carries less.
    assert tdtp.congested_level_kbps > 1.3 * trinomial.congested_level_kbps
    assert tdtp.free_level_kbps > trinomial.free_level_kbps
    assert json.loads(result.to_json())["headline"]["tdtp"]["fill_time_90_s"] is not None


def test_cli_writes_json_and_figures(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = simulate_main(
        ["best-effort", "--out", str(tmp_path), "--duration", "6", "--schemes", "tdtp", "--json"]
    )
    printed = json.loads(capsys.readouterr().out)
    stored = json.loads((tmp_path / "best_effort.json").read_text())
    assert stored["params"]["duration"] == 6.0
    assert printed["headline"]["tdtp"]["free_level_kbps"] == pytest.approx(
        stored["headline"]["tdtp"]["free_level_kbps"]
    )
    if importlib.util.find_spec("matplotlib") is None:
        assert code == 1
    else:
        assert code == 0
        assert (tmp_path / "best_effort.png").stat().st_size > 10_000


def test_cli_paper_over_seeds_reports_ratios_with_intervals(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = simulate_main(
        [
            "paper",
            "--out",
            str(tmp_path),
            "--duration",
            "5",
            "--seeds",
            "3",
            "--schemes",
            "tdtp,trinomial",
            "--jobs",
            "2",
            "--no-plots",
            "--json",
        ]
    )
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    literal = printed["headline"]["literal"]
    assert "TCP master-to-slave, tahoe; Trinomial ACKs plain" in literal["parameters"]
    ratio = literal["goodput ratio tdtp/trinomial"]["M->S"]["all"]
    assert ratio["n"] == 3 and ratio["low"] <= ratio["median"] <= ratio["high"]
    assert 0 < ratio["coverage"] < 1
    stored = json.loads((tmp_path / "paper.json").read_text())
    assert stored["params"]["seeds"] == [1, 2, 3]
    assert len(stored["runs"]) == 6
    summary = stored["readings"]["literal"]["schemes"]["tdtp"]
    assert len(summary["bands"]["M->S"]["goodput_kbps"]["median"]) == 5  # 1 s bins
    assert not list(tmp_path.glob("*.png"))


def test_cli_reading_overrides_and_text(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = simulate_main(
        [
            "paper",
            "--out",
            str(tmp_path),
            "--duration",
            "4",
            "--seeds",
            "1",
            "--schemes",
            "tdtp",
            "--tcp-variant",
            "newreno",
            "--send-jitter",
            "0.5",
            "--no-plots",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "reading 'literal[tcp-variant=newreno,send-jitter=0.5ms]'" in out
    assert "TCP master-to-slave, newreno" in out and "send jitter 0-0.5 ms" in out
    assert "paper.json" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["paper", "--schemes", "quic"], "unknown scheme"),
        (["paper", "--readings", "figure9"], "unknown reading"),
        (["paper", "--seeds", "0"], "--seeds"),
        (["paper", "--send-jitter", "50"], "send_jitter"),
        (["fairness", "--seeds", "3"], "runs once"),
        (["lockout", "--duration", "-1"], "--duration"),
        (["lockout", "--earlier-seeds", "0"], "--earlier-seeds"),
    ],
)
def test_cli_refuses_bad_arguments_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    assert simulate_main([*argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not list(tmp_path.iterdir())
