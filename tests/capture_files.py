"""Reading the pcap files tdtp writes, in Python and through tshark (when it is installed)."""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
from pathlib import Path
from typing import Any, NamedTuple

import pytest

TSHARK = shutil.which("tshark")
needs_tshark = pytest.mark.skipif(
    TSHARK is None,
    reason="tshark is not installed (Debian: apt-get install tshark; CI's .ci/run installs it)",
)
DISSECTOR = Path(__file__).resolve().parents[1] / "tools" / "wireshark" / "tdtp.lua"


class Record(NamedTuple):
    seconds: int
    micros: int
    packet: bytes


def read_pcap(path: Path) -> tuple[int, list[Record]]:
    """The link type and the records of a classic little-endian microsecond pcap file."""
    data = path.read_bytes()
    magic, major, minor, _, _, snaplen, linktype = struct.unpack_from("<IHHiIII", data)
    assert (magic, major, minor, snaplen) == (0xA1B2C3D4, 2, 4, 65535)
    records = []
    offset = 24
    while offset < len(data):
        seconds, micros, captured, length = struct.unpack_from("<IIII", data, offset)
        assert captured == length
        offset += 16
        records.append(Record(seconds, micros, data[offset : offset + captured]))
        offset += captured
    assert offset == len(data)
    return linktype, records


def udp_payload(packet: bytes) -> bytes:
    """The UDP payload of a raw IPv4 or IPv6 packet."""
    header = 20 if packet[0] >> 4 == 4 else 40
    return packet[header + 8 :]


def _environment(home: Path) -> dict[str, str]:
    # A private home: tshark reads and may write preferences there, never the user's.
    env = dict(os.environ)
    env["HOME"] = str(home)
    env.pop("WIRESHARK_CONFIG_DIR", None)
    return env


def tshark(
    pcap: Path,
    *args: str,
    home: Path,
    lua: bool = True,
) -> str:
    assert TSHARK is not None
    command = [TSHARK, "-n", "-r", str(pcap)]
    if lua:
        command += ["-X", f"lua_script:{DISSECTOR}"]
    done = subprocess.run(
        [*command, *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env=_environment(home),
    )
    assert done.returncode == 0, done.stderr
    assert "Lua: Error" not in done.stderr, done.stderr
    return done.stdout


def tshark_fields(pcap: Path, fields: list[str], *args: str, home: Path) -> list[list[str]]:
    """One row per packet: the values of ``fields`` (several occurrences joined with commas)."""
    command = ["-T", "fields", "-E", "separator=\t", "-E", "occurrence=a", "-E", "aggregator=,"]
    for field in fields:
        command += ["-e", field]
    out = tshark(pcap, *command, *args, home=home)
    return [line.split("\t") for line in out.splitlines()]


def tshark_json(pcap: Path, *args: str, home: Path) -> list[dict[str, Any]]:
    packets: list[dict[str, Any]] = json.loads(tshark(pcap, "-T", "json", *args, home=home))
    return packets
