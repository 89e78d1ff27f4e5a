"""Secure sessions on real loopback sockets: amplification, floods, the accept backlog, keyed
sessions and restarts. Counts are what the run recorded, never rates expected from the clock."""

from __future__ import annotations

import asyncio
import json
import os
import random
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tdtp import (
    CloseCause,
    ConnectionConfig,
    DataReceived,
    InvalidKeyError,
    PresharedKey,
    load_key,
    load_keys,
    write_key_file,
)
from tdtp.aio.api import ConnectError, connect, listen
from tdtp.wire import OpenBody, OpenFlags, encode_header, encode_open
from tdtp.wire.control import PROTOCOL_VERSION

KEY = PresharedKey.generate("station-1")


def _open(nonce: bytes | None = None, keyed: bool = False) -> bytes:
    flags = int(OpenFlags.KEYED | OpenFlags.ENCRYPTED) if keyed else 0
    datagram = encode_header(2, 7, 0, 0, 255) + encode_open(
        OpenBody(
            PROTOCOL_VERSION,
            flags,
            1 if keyed else 0,
            1200,
            0,
            nonce or os.urandom(16),
            bytes(8),
            bytes(16),
        )
    )
    return datagram + (os.urandom(16) if keyed else b"")


@contextmanager
def _victim(host: str = "127.0.0.1") -> Iterator[socket.socket]:
    """A socket whose address an attacker forges: it never answers, and counts what it gets."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((host, 0))
    sock.setblocking(False)
    try:
        yield sock
    finally:
        sock.close()


def _drain(sock: socket.socket) -> list[bytes]:
    got = []
    while True:
        try:
            got.append(sock.recv(65536))
        except BlockingIOError:
            return got


async def _reflected(victim: socket.socket, target: tuple[str, int], opens: list[bytes]) -> int:
    """Send the OPENs as if the victim did, wait for whatever comes back, return its bytes."""
    for datagram in opens:
        victim.sendto(datagram, target)
        await asyncio.sleep(0.001)
    await asyncio.sleep(0.5)  # anything the slave would stream at the victim would be here by now
    return sum(len(d) for d in _drain(victim))


@pytest.mark.asyncio
@pytest.mark.parametrize("keyed", [False, True])
async def test_amplification_of_the_library_slave_is_at_most_one(keyed: bool) -> None:
    async with await listen("127.0.0.1", 0, keys=[KEY] if keyed else None) as server:
        with _victim() as victim:
            opens = [_open(keyed=keyed) for _ in range(50)]
            back = await _reflected(victim, ("127.0.0.1", server.port), opens)
        sent = sum(len(d) for d in opens)
        assert back <= sent  # one COOKIE (39 bytes) per OPEN of 53 or 69: factor 0.74 or 0.57
        front_door = server.stats.admission
        # 40 at once, then 20 per second from one source: the rest get nothing at all.
        assert back == 39 * front_door.cookies_sent
        assert front_door.cookies_sent + front_door.drops["rate_limited"] == 50
        assert front_door.bytes_out <= front_door.bytes_in == sent
        assert server.endpoints == [] and front_door.admitted == 0


def test_amplification_of_the_cli_slave_is_at_most_one() -> None:
    """The shipped `tdtp slave` streamed 1 kHz at a forged source for 2 s (10,234x). Now: one
    COOKIE per OPEN, nothing else."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    slave = subprocess.Popen(
        [sys.executable, "-m", "tdtp", "slave", "--host", "127.0.0.1", "--port", str(port),
         "--duration", "5", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    sent = received = 0
    try:
        with _victim() as victim:
            answered = 0
            for _ in range(80):  # until the slave has bound and answered 10 OPENs (< 5 s)
                datagram = _open()
                victim.sendto(datagram, ("127.0.0.1", port))
                sent += len(datagram)
                time.sleep(0.05)
                replies = _drain(victim)
                answered += len(replies)
                received += sum(len(d) for d in replies)
                if answered >= 10:
                    break
            out, err = slave.communicate(timeout=30)
            received += sum(len(d) for d in _drain(victim))
    finally:
        slave.kill()
    assert slave.returncode == 0, err
    assert 0 < received <= sent
    summary = json.loads(out)
    assert summary["masters_served"] == 0
    front_door = summary["admission"]
    assert front_door["cookies_sent"] >= 1 and front_door["admitted"] == 0
    assert front_door["bytes_out"] <= front_door["bytes_in"]


@pytest.mark.asyncio
async def test_a_master_connects_while_forged_opens_flood_the_slave() -> None:
    """1,000 OPENs/s from 100 source addresses (127.0.0.2-101): they get cookies and no state; the
    real master's OPEN and cookie go through as if nothing happened."""
    async with await listen("127.0.0.1", 0) as server:
        target = ("127.0.0.1", server.port)
        attackers = []
        for index in range(100):
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind((f"127.0.0.{index + 2}", 0))
            sock.setblocking(False)
            attackers.append(sock)
        stop = asyncio.Event()

        async def flood() -> int:
            count = 0
            while not stop.is_set():
                for sock in attackers[count % 10 :: 10]:  # 10 sources per ms
                    sock.sendto(_open(), target)
                count += 1
                await asyncio.sleep(0.001)
            return count * 10

        flooding = asyncio.create_task(flood())
        try:
            await asyncio.sleep(0.2)
            master = await connect(*target)
            opens_sent = master.connection._handshake.open_attempt
            slave = await server.accept()
            master.send(b"command")
            sample = await asyncio.wait_for(slave.recv(), 5.0)
            assert sample.payload == b"command"
            await master.close()
        finally:
            stop.set()
            forged = await flooding
            for sock in attackers:
                sock.close()
        # (That it takes no more than the cookie round trip is shown in fake time:
        # tests/test_admission.py. Here: it connects, and the flood created nothing.)
        assert opens_sent >= 2
        assert server.stats.peers_accepted == 1
        assert server.stats.admission.admitted == 1
        assert server.stats.admission.opens >= forged // 2  # the flood did arrive


@pytest.mark.asyncio
async def test_nothing_is_kept_for_opens_nobody_accepts_beyond_the_backlog() -> None:
    """With on_data and nobody calling accept(), every session used to stay referenced forever.
    Forged OPENs now create nothing; real sessions are served, and freed when they end."""
    got: list[DataReceived] = []
    async with await listen("127.0.0.1", 0, on_data=got.append, backlog=4) as server:
        with _victim() as victim:
            for _ in range(3000):
                victim.sendto(_open(), ("127.0.0.1", server.port))
            await asyncio.sleep(0.3)
        assert server.endpoints == [] and len(server._pending) == 0
        masters = [await connect("127.0.0.1", server.port) for _ in range(10)]
        for index, master in enumerate(masters):
            master.send(b"%d" % index)
        for _ in range(1000):  # patience for a loaded machine, not a timing goal
            if len(got) >= 10:
                break
            await asyncio.sleep(0.01)
        assert sorted(sample.payload for sample in got) == sorted(b"%d" % i for i in range(10))
        assert len(server._pending) <= 4  # accept() would see the newest four
        for master in masters:
            await master.close()
        for _ in range(1000):
            if not server.endpoints:
                break
            await asyncio.sleep(0.01)
        assert server.endpoints == [] and len(server._pending) == 0


@pytest.mark.asyncio
async def test_a_full_backlog_refuses_at_once() -> None:
    async with await listen("127.0.0.1", 0, backlog=2) as server:
        first = await connect("127.0.0.1", server.port)
        second = await connect("127.0.0.1", server.port)
        with pytest.raises(ConnectError, match="backlog"):
            await connect("127.0.0.1", server.port)
        assert server.stats.peers_refused == 1
        await server.accept()  # room again
        third = await connect("127.0.0.1", server.port)
        for master in (first, second, third):
            await master.close()


@pytest.mark.asyncio
async def test_a_keyed_session_over_real_sockets() -> None:
    ring = {"station-1": KEY.secret, "station-2": PresharedKey.generate().secret}
    async with await listen("127.0.0.1", 0, keys=ring) as server:
        assert server.keyed
        async with await connect("127.0.0.1", server.port, key=KEY.secret) as master:
            slave = await server.accept()
            assert slave.connection.key is not None
            assert slave.connection.key.name == "station-1"
            assert master.connection.encrypted
            for index in range(20):
                master.send(b"cmd-%02d" % index)
                slave.send(b"fb-%02d" % index)
                await asyncio.sleep(0.002)
            for _ in range(1000):
                if master.stats.received.data_packets and slave.stats.received.data_packets >= 5:
                    break
                await asyncio.sleep(0.01)
            assert (await slave.recv()).payload.startswith(b"cmd-")
            # 18 bytes on every datagram after the OPEN, whose tag is 16.
            received = slave.stats.received
            assert received.protection_bytes == 18 * (received.datagrams - 1) + 16
        with pytest.raises(ConnectError, match="does not hold this key"):
            await connect("127.0.0.1", server.port, key=PresharedKey.generate())
        with pytest.raises(ConnectError, match="keyed sessions only"):
            await connect("127.0.0.1", server.port)


@pytest.mark.asyncio
async def test_key_files_fit_connect_and_listen(tmp_path: Path) -> None:
    """The slave takes its file's keys (load_keys), the master one key (load_key, or load_keys
    of a one-key file); several keys for key= are refused at the call, saying how to choose."""
    slave_file, master_file = tmp_path / "robot.keys", tmp_path / "station.keys"
    other = PresharedKey.generate("station-2")
    write_key_file(slave_file, [KEY, other])
    write_key_file(master_file, [KEY])
    with pytest.raises(InvalidKeyError, match=r"load_key\(path, name=NAME\)"):
        connect("127.0.0.1", 7000, key=load_keys(slave_file))  # checked before any await
    async with await listen("127.0.0.1", 0, keys=load_keys(slave_file)) as server:
        for key in (load_keys(master_file), load_key(slave_file, name="station-2")):
            async with await connect("127.0.0.1", server.port, key=key) as master:
                slave = await server.accept()
                assert slave.connection.key is not None
                assert master.connection.key is not None
                assert slave.connection.key.name == master.connection.key.name


@pytest.mark.asyncio
async def test_a_port_sweep_from_the_masters_host_gets_nothing_in() -> None:
    async with (
        await listen("127.0.0.1", 0, key=KEY) as server,
        await connect("127.0.0.1", server.port, key=KEY) as master,
    ):
        slave = await server.accept()
        rng = random.Random(5)
        sockets = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(200)]
        try:
            for sock in sockets:  # the master's IP, every other port: forged commands
                sock.bind(("127.0.0.1", 0))
                forged = encode_header(0, rng.randrange(4096), 0, 0, 255) + rng.randbytes(120)
                sock.sendto(forged, ("127.0.0.1", server.port))
        finally:
            for sock in sockets:
                sock.close()
        forged_from_master = encode_header(0, 5, 0, 0, 255) + bytes(2) + rng.randbytes(116)
        master._transport.sendto(forged_from_master)  # even from the master's own port
        master.send(b"real")
        sample = await asyncio.wait_for(slave.recv(), 5.0)
        assert sample.payload == b"real"
        for _ in range(100):
            if server.stats.datagrams_unattached == 200:
                break
            await asyncio.sleep(0.01)
        assert server.stats.datagrams_unattached == 200
        assert (
            slave.stats.drops.get("unauthenticated", 0) + slave.stats.drops.get("replayed", 0) == 1
        )
        assert slave.stats.samples_delivered == 1


@pytest.mark.asyncio
async def test_a_restarted_master_is_taken_back_without_waiting_for_the_old_session() -> None:
    """The master process dies without CLOSE and a new one binds the same address: the server ends
    the old session (REPLACED) at the new OPEN instead of after idle_timeout."""
    config = ConnectionConfig(idle_timeout=30.0)
    async with await listen("127.0.0.1", 0, config=config) as server:
        first = await connect("127.0.0.1", server.port, config=config)
        old = await server.accept()
        local = first._transport.get_extra_info("sockname")
        first._release()  # the process dies: no CLOSE...
        first._transport.close()  # ...and its socket goes away
        await asyncio.sleep(0.05)
        second = await connect("127.0.0.1", server.port, config=config, local_addr=local)
        new = await server.accept()
        closed = await asyncio.wait_for(old.wait_closed(), 1.0)
        assert closed.cause is CloseCause.REPLACED
        assert server.endpoints == [new] and server.stats.peers_accepted == 2
        await second.close()


@pytest.mark.asyncio
async def test_a_master_with_a_tiny_max_payload_is_refused_by_the_cli_slave() -> None:
    """An OPEN with max_payload 1 made `tdtp slave` log "Task exception was never retrieved ...
    PayloadTooLargeError". The slave now refuses it at the open, and the master hears why."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    slave = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "tdtp", "slave", "--host", "127.0.0.1", "--port", str(port),
        "--duration", "3", "--json",
        stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE,
    )  # fmt: skip
    try:
        refused = None
        for _ in range(50):  # until the slave has bound its port
            try:
                await connect("127.0.0.1", port, config=ConnectionConfig(max_payload=1))
            except ConnectError as exc:
                if "max_payload" in str(exc):
                    refused = exc
                    break
            await asyncio.sleep(0.1)
        assert refused is not None and "max_payload (1)" in str(refused)
        out, err = await asyncio.wait_for(slave.communicate(), 30)
    finally:
        if slave.returncode is None:
            slave.kill()
    assert slave.returncode == 0
    assert b"Traceback" not in err and b"exception" not in err.lower()
    assert json.loads(out)["admission"]["rejects_sent"] >= 1
