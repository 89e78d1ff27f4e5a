"""``tdtp bandwidth``: the figure-5 model as a table, CSV, JSON and PNG; bad arguments are one line and
exit status 2."""

from __future__ import annotations

import csv
import importlib.util
import io
import json
from pathlib import Path

import pytest

from tdtp.cli.bandwidth import bandwidth_main
from tdtp.cli.main import main


def test_default_table_has_the_papers_worked_example(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bandwidth"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.split()[:2] == ["IPv4", "100"])
    # 100-byte data, 400 kbit/s each way: 500 pkt/s; TCP 1.440, UDP 1.024, Trinomial 1.200, TDTP 1.000
    assert row.split()[2:7] == ["500.0", "1.440", "1.024", "1.200", "1.000"]
    assert row.split()[7] == "16.7%"  # eq. 8: 1 - 1 / (1 + 25 / 125)
    assert "400 kbit/s of data each way" in out


def test_size_rate_and_encapsulation(capsys: pytest.CaptureFixture[str]) -> None:
    assert bandwidth_main(["--size", "100", "--rate", "0.8mbit", "--encapsulation", "all"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[3:6]]
    assert [r[0] for r in rows] == ["IPv4", "UDP/IPv4", "UDP/IPv6"]
    assert all(r[2] == "1000.0" for r in rows)  # 800 kbit/s in 100-byte samples
    # TDTP: 1000 pkt/s x 2 directions x (100 + 25 | 33 | 53) bytes
    assert [r[6] for r in rows] == ["2.000", "2.128", "2.448"]


def test_csv_and_json_give_every_row_in_bit_per_second(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert bandwidth_main(["--size", "1-10,100", "--csv", "--encapsulation", "udp6"]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert [int(r["data_size"]) for r in rows] == [*range(1, 11), 100]
    assert {r["encapsulation"] for r in rows} == {"udp6"}
    assert float(rows[-1]["tdtp_bps"]) == pytest.approx(2 * 500 * 153 * 8)
    assert bandwidth_main(["--size", "100", "--json", "--rate", "400"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["app_rate_bps"] == 400_000.0
    assert data["rows"][0]["trinomial_bps"] == pytest.approx(1.2e6)


def test_png(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "figure5.png"
    code = bandwidth_main(["--png", str(target), "--encapsulation", "all", "--csv"])
    captured = capsys.readouterr()
    assert captured.out.startswith("encapsulation,data_size")  # the CSV stays clean on stdout
    if importlib.util.find_spec("matplotlib") is None:
        assert code == 1 and "matplotlib" in captured.err
    else:
        assert code == 0 and target.stat().st_size > 10_000
        assert f"wrote {target}" in captured.err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--size", "0"], "data sizes must be"),
        (["--size", "100-10"], "backwards"),
        (["--size", "ten"], "not a size"),
        (["--rate", "fast"], "not a rate"),
        (["--rate", "0"], "positive"),
        (["--encapsulation", "ipx"], "invalid choice"),
        (["--csv", "--json"], "not allowed with"),
        (["--frobnicate"], "unrecognized"),
    ],
)
def test_bad_arguments_are_one_line_and_status_2(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["bandwidth", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and err.startswith("tdtp bandwidth: ")


def test_unwritable_png_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if importlib.util.find_spec("matplotlib") is None:
        pytest.skip("needs matplotlib to get as far as writing")
    target = tmp_path / "missing-dir-is-a-file"
    target.write_text("")
    assert bandwidth_main(["--png", str(target / "f.png")]) == 2
    assert capsys.readouterr().err.startswith("tdtp bandwidth: cannot write")
