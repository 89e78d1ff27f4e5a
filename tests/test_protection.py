"""Packet protection: pinned key derivation and sealed bytes (docs/PROTOCOL.md section 6), the
replay window, packet-number expansion, key files."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tdtp import InvalidKeyError, PresharedKey, load_key, load_keys, write_key_file
from tdtp.protection.derivation import (
    derive_key_id,
    derive_open_secret,
    derive_session_secrets,
)
from tdtp.protection.key_file import parse_keys
from tdtp.protection.keys import as_key
from tdtp.protection.packet_protection import Direction, PacketOpener, PacketSealer
from tdtp.protection.replay_window import ReplayWindow
from tdtp.wire import (
    CipherSuite,
    OpenBody,
    PacketType,
    encode_header,
    encode_hold,
    encode_open,
)

PSK = bytes(range(32))
MASTER_NONCE = bytes.fromhex("00112233445566778899aabbccddeeff")
SLAVE_NONCE = bytes.fromhex("f0e1d2c3b4a5968778695a4b3c2d1e0f")
COOKIE = bytes.fromhex("0000abcd") + bytes([0x11] * 12)
SUITE = CipherSuite.AES_128_GCM
PROTOCOL_MD = Path(__file__).resolve().parents[1] / "docs" / "PROTOCOL.md"

# The keyed worked example of docs/PROTOCOL.md: the 5-byte header of section 7.1, packet number 1,
# payload "hello", master to slave.
HEADER = encode_header(PacketType.DATA, 0x0ABC, 0x0123, 0b101010, encode_hold(250e-6))
SEALED_DATA = "2a f0 48 ea 1f 00 01 51 93 f9 13 9c 89 52 5a fb 0b 37 64 e9 ef bd 3d 41 9d f9 92 24"
CLEAR_DATA = "2a f0 48 ea 1f 00 01 68 65 6c 6c 6f 64 e1 dc 5d 25 5e b6 b2 d0 20 f7 ac 2f d9 7d 80"
KEYED_OPEN = (
    "96 94 00 00 ff 01 04 06 01 04 b0 00 01 00 11 22 33 44 55 66 77 88 99 aa bb cc dd ee ff "
    "eb 49 4c 5f a4 4b 9c 55 00 00 ab cd 11 11 11 11 11 11 11 11 11 11 11 11 "
    "50 d3 2f c2 a2 cb 3d 78 2a 1a 3f 4a 6b 35 17 3a"
)


def _in_protocol_md(hexbytes: str) -> bool:
    return hexbytes in " ".join(PROTOCOL_MD.read_text(encoding="utf-8").split())


def test_key_derivation_is_pinned() -> None:
    assert derive_key_id(PSK).hex() == "eb494c5fa44b9c55"
    opening = derive_open_secret(PSK, MASTER_NONCE, SUITE)
    assert (opening.key.hex(), opening.iv.hex()) == (
        "f3fd4a5e1c64a745933dbf6b23295e64",
        "c2240f9e3edc19c515928c33",
    )
    session = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, SUITE)
    assert (session.master_to_slave.key.hex(), session.master_to_slave.iv.hex()) == (
        "86fd1bab9a3507979a17e3f7855bdd38",
        "202f682cb6f12fedeb42db06",
    )
    assert (session.slave_to_master.key.hex(), session.slave_to_master.iv.hex()) == (
        "c82faedd2d00437763505efb46ae4a8e",
        "6e98bfd5c8105d40fb9a92c8",
    )
    for value in (
        "eb494c5fa44b9c55",
        "86fd1bab9a3507979a17e3f7855bdd38",
        "6e98bfd5c8105d40fb9a92c8",
    ):
        assert _in_protocol_md(value)


@pytest.mark.parametrize(("encrypt", "expected"), [(True, SEALED_DATA), (False, CLEAR_DATA)])
def test_sealed_data_is_pinned_and_opens(encrypt: bool, expected: str) -> None:
    secret = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, SUITE).master_to_slave
    sealer = PacketSealer(SUITE, secret, encrypt=encrypt)
    sealer.next_number = 1
    datagram = sealer.seal(HEADER, b"hello")
    assert datagram.hex(" ") == expected
    assert _in_protocol_md(expected)
    opener = PacketOpener(SUITE, secret, encrypt=encrypt)
    assert opener.open(datagram, len(HEADER)) == b"hello"
    assert opener.open(datagram, len(HEADER)) is None and opener.failure == "replayed"


def test_keyed_open_is_pinned() -> None:
    body = OpenBody(4, 0x06, 1, 1200, 1, MASTER_NONCE, derive_key_id(PSK), COOKIE)
    datagram = encode_header(PacketType.CONTROL, 0x5A5, 0, 0, 255) + encode_open(body)
    tagger = Direction(SUITE, derive_open_secret(PSK, MASTER_NONCE, SUITE))
    datagram += tagger.tag(1, datagram)
    assert datagram.hex(" ") == KEYED_OPEN
    assert _in_protocol_md(KEYED_OPEN)


@given(st.integers(0, 2**40), st.integers(-30000, 30000))
def test_packet_numbers_expand_within_half_the_16_bit_space(highest: int, offset: int) -> None:
    secret = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, SUITE).master_to_slave
    opener = PacketOpener(SUITE, secret, encrypt=True)
    opener.window.accept(highest)
    number = highest + 1 + offset
    if number >= 0:
        assert opener.expand(number & 0xFFFF) == number


def test_replay_window() -> None:
    window = ReplayWindow()
    assert not window.seen(0)
    window.accept(0)
    assert window.seen(0)
    window.accept(10)
    assert [n for n in range(12) if not window.seen(n)] == [1, 2, 3, 4, 5, 6, 7, 8, 9, 11]
    window.accept(5)  # late but within the window
    assert window.seen(5)
    window.accept(200)
    assert window.seen(200 - 64) and not window.seen(200 - 63)  # older than 64: refused
    window.accept(1000)
    assert not window.seen(1000 - 63) and window.seen(1000 - 64) and window.seen(200)


def test_key_files_round_trip_and_refuse_bad_ones(tmp_path: Path) -> None:
    keys = [PresharedKey.generate("station-1"), PresharedKey.generate()]
    path = tmp_path / "keys"
    write_key_file(path, keys)
    assert os.stat(path).st_mode & 0o777 == 0o600
    assert load_keys(path) == keys
    with pytest.raises(InvalidKeyError, match="exists"):
        write_key_file(path, keys)
    os.chmod(path, 0o644)
    with pytest.raises(InvalidKeyError, match="chmod 600"):
        load_keys(path)
    with pytest.raises(InvalidKeyError, match="line 2: the key is not hexadecimal"):
        parse_keys("# comment\nmaster zz\n")
    with pytest.raises(InvalidKeyError, match=r"line 1: .*16\.\.64 random bytes"):
        parse_keys("abcd\n")
    with pytest.raises(InvalidKeyError, match="no key"):
        parse_keys("# nothing\n\n")
    with pytest.raises(InvalidKeyError, match="cannot read"):
        load_keys(tmp_path / "missing")
    secret, other = "11" * 32, "22" * 32
    # One key under two names would let either master open the other's sessions (issue 20, 9).
    with pytest.raises(InvalidKeyError, match="line 3: the same key as line 1"):
        parse_keys(f"a {secret}\nb {other}\nc {secret}\n")
    with pytest.raises(InvalidKeyError, match="line 2: the name 'a' is already used on line 1"):
        parse_keys(f"a {secret}\na {other}\n")
    assert [k.name for k in parse_keys(f"a {secret}\nb {other}\n")] == ["a", "b"]


def test_load_key_gives_what_key_takes_and_key_takes_a_one_key_file(tmp_path: Path) -> None:
    """A user's first try was connect(key=tdtp.load_keys(path)), refused with an error that said
    to use load_keys (issue 35): the file's one key is taken; of several, the error says how to
    choose, and load_key is the master's reader."""
    first, second = PresharedKey.generate("station-1"), PresharedKey.generate("station-2")
    one, two = tmp_path / "one.keys", tmp_path / "two.keys"
    write_key_file(one, [first])
    write_key_file(two, [first, second])
    assert load_key(two) == first and load_key(two, name="station-2") == second
    with pytest.raises(
        InvalidKeyError, match=r"no key named 'x' in .*two.keys \(it has: station-1, station-2\)"
    ):
        load_key(two, name="x")
    assert as_key(load_keys(one)) == first  # what connect(key=...) does with it
    assert as_key({"station-1": first.secret}) == first
    with pytest.raises(InvalidKeyError) as several:
        as_key(load_keys(two))
    message = str(several.value)
    assert "got 2 (station-1, station-2)" in message
    assert "key=tdtp.load_key(path)" in message and "listen(keys=tdtp.load_keys(path))" in message
    with pytest.raises(
        InvalidKeyError, match=r"not the path of a key file: pass key=tdtp.load_key\("
    ):
        as_key(str(one))  # type: ignore[arg-type]
    with pytest.raises(InvalidKeyError, match="empty collection"):
        as_key([])
    with pytest.raises(
        InvalidKeyError, match=r"got int \(read one from a key file with tdtp.load_key"
    ):
        as_key(7)  # type: ignore[arg-type]


# ---------------------------------------------------------------- long loss runs (issue 20, item 2)


def _pair(encrypt: bool = True) -> tuple[PacketSealer, PacketOpener]:
    secret = derive_session_secrets(PSK, MASTER_NONCE, SLAVE_NONCE, SUITE).master_to_slave
    return PacketSealer(SUITE, secret, encrypt=encrypt), PacketOpener(
        SUITE, secret, encrypt=encrypt
    )


def _run(sealer: PacketSealer, opener: PacketOpener, count: int, now: float, rate: float) -> int:
    """Seal ``count`` datagrams at ``rate`` per second from ``now`` and open them all: how many open."""
    opened = 0
    for i in range(count):
        if opener.open(sealer.seal(HEADER, b"x"), len(HEADER), now + i / rate) is not None:
            opened += 1
    return opened


@pytest.mark.parametrize("lost", [32_767, 32_768, 60_000, 65_536, 200_000, 1_000_000])
def test_a_keyed_receiver_recovers_from_any_loss_run(lost: int) -> None:
    """After 70,000 packets, the next 2000 open whatever ran before them: 32,768 lost in a row used
    to desynchronise the packet numbers for good (every later datagram refused as a replay)."""
    sealer, opener = _pair()
    assert _run(sealer, opener, 70_000, 0.0, 1000.0) == 70_000
    gap_start = 70.0
    sealer.next_number += lost  # the peer sent them; none arrived (1000/s, lost/1000 seconds)
    back = gap_start + lost / 1000.0
    assert _run(sealer, opener, 2000, back, 1000.0) == 2000
    assert opener.resyncs == (1 if lost >= 32_768 else 0)


def test_without_a_clock_the_search_still_spans_two_steps() -> None:
    sealer, opener = _pair(encrypt=False)
    for _ in range(10):
        opener.open(sealer.seal(HEADER, b"x"), len(HEADER))
    sealer.next_number += 100_000  # 1.5 steps of 65536
    assert opener.open(sealer.seal(HEADER, b"y"), len(HEADER)) == b"y"


def test_resynchronisation_keeps_the_replay_guarantee() -> None:
    sealer, opener = _pair()
    old = [sealer.seal(HEADER, b"old %d" % i) for i in range(100)]
    for i, datagram in enumerate(old):
        assert opener.open(datagram, len(HEADER), i / 1000) is not None
    sealer.next_number += 50_000
    assert opener.open(sealer.seal(HEADER, b"new"), len(HEADER), 60.0) == b"new"
    for datagram in old:  # replayed after the resync: every one refused
        assert opener.open(datagram, len(HEADER), 61.0) is None
    assert opener.failure in ("replayed", "unauthenticated")
    assert opener.window.highest == 100 + 50_000


def test_forgeries_cannot_buy_more_than_the_resync_budget() -> None:
    """A flood of forged datagrams during an outage: each failing datagram may start a search, but
    at most RESYNC_TRIES_PER_SECOND searches a second run, and none of them moves the window."""
    from tdtp.protection import packet_protection

    sealer, opener = _pair()
    assert _run(sealer, opener, 1000, 0.0, 1000.0) == 1000
    forged = bytearray(sealer.seal(HEADER, b"x" * 20))
    forged[-1] ^= 1  # a tag nobody can compute
    searches = 0
    real = opener.resyncs
    for i in range(10_000):  # 10,000 forgeries over one second of a 30-second silence
        before = opener._resync_budget
        assert opener.open(bytes(forged), len(HEADER), 31.0 + i / 10_000) is None
        searches += opener._resync_budget < before
    # What was saved up (one second's worth) plus one second of refill.
    assert searches <= 2 * packet_protection.RESYNC_TRIES_PER_SECOND + 1
    assert opener.resyncs == real and opener.window.highest == 999
