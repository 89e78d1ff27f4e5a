"""CPU per packet of the real endpoints' one-way send and receive paths, in one process, no sockets.

Usage: ``python benchmarks/endpoint_per_packet.py [--rounds 5] [--chunks 600] [--keep 27]
[--reduce rx|tx]`` (``TDTP_PURE_PYTHON=1`` for the pure-Python build)

``throughput.py`` measures a pair end to end, where the kernel, uvloop and the other tenants of the
machine share each process's CPU; this measures the library's own share of it. A master
(``tdtp.connect``) and a slave (``tdtp.listen``) open a session over loopback on uvloop (``fixed``
controller, ``rate=inf``, on the loop's own transport: ``TDTP_DATAGRAM_LAYER=0``), then each
endpoint's transport is swapped for a list, and in chunks:

- ``tx``: the master's ``Endpoint.send`` of 64 samples of 100 bytes, then the ACKs the slave sent
  handed to the master (``Endpoint.datagram_received``), as ``throughput.py``'s sender does between
  two yields to the loop;
- ``rx``: the first ``--keep`` (27) of those 64 datagrams handed to the server
  (``Server._datagram_received``, what the socket's protocol calls): the rest are lost, as a
  receiver that cannot keep up loses them when its socket buffer overflows (``throughput.py``'s
  pure-Python receiver takes about 40 % of what its sender offers), so every chunk has a gap.

Between chunks the loop runs once (timers). Figures: CPU microseconds per sample sent and per
datagram received (``time.process_time``), the best round of ``--rounds`` and the first quartile
of the chunks (another tenant on the machine inflates some chunks, not most).

``--reduce rx`` (or ``tx``) runs that side's chunks inside ``functools.reduce``, so that
``valgrind --tool=callgrind --toggle-collect=functools_reduce`` counts the instructions of that side
alone: a figure the other tenants do not move (benchmarks/HISTORY.md, "Third round on the pure path").
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import sys
import time
from functools import reduce
from pathlib import Path
from typing import Any

os.environ.setdefault("TDTP_DATAGRAM_LAYER", "0")  # before tdtp is imported: the loop's transport

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common

from tdtp import ConnectionConfig, DataReceived, build_info
from tdtp.aio.api import connect, listen
from tdtp.control.fixed import FixedConfig

UNLIMITED = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))
PAYLOAD = bytes(range(100))
BATCH = 64


class _Counter:
    def __init__(self) -> None:
        self.count = 0

    def on_data(self, _: DataReceived) -> None:
        self.count += 1


class _ListTransport:
    """A transport that keeps what is sent."""

    def __init__(self) -> None:
        self.out: list[bytes] = []

    def sendto(self, data: bytes, addr: object = None) -> None:
        self.out.append(data)


async def measure(rounds: int, chunks: int, keep: int, reduce_side: str | None) -> dict[str, Any]:
    received = _Counter()
    server = await listen("127.0.0.1", 0, config=UNLIMITED, on_data=received.on_data)
    master = await connect("127.0.0.1", server.port, config=UNLIMITED, on_data=_Counter().on_data)
    while not server.endpoints:
        await asyncio.sleep(0.001)
    slave = server.endpoints[0]
    for _ in range(20):  # established both ways, through the real sockets
        master.send(PAYLOAD)
        await asyncio.sleep(0.002)
    master_addr = slave.connection.peer
    slave_addr = master.connection.peer
    assert master_addr is not None and slave_addr is not None
    to_slave, to_master = _ListTransport(), _ListTransport()
    master._transport = to_slave  # type: ignore[assignment]
    slave._transport = to_master  # type: ignore[assignment]
    receive = server._datagram_received
    send = master.send
    ack_received = master.datagram_received
    clock = time.process_time

    def tx(_: object, __: object) -> None:
        for _ in range(BATCH):
            send(PAYLOAD)
        acks, to_master.out = to_master.out, []
        for data in acks:
            ack_received(data, slave_addr)

    def rx(batch: list[bytes]) -> None:
        for data in batch:
            receive(data, master_addr)

    best_tx = best_rx = math.inf
    tx_chunks: list[float] = []
    rx_chunks: list[float] = []
    for _ in range(rounds):
        tx_time = rx_time = 0.0
        tx_count = rx_count = 0
        for _ in range(chunks):
            start = clock()
            if reduce_side == "tx":
                reduce(tx, [None], None)
            else:
                tx(None, None)
            elapsed = clock() - start
            tx_time += elapsed
            tx_chunks.append(elapsed / BATCH)
            tx_count += BATCH
            batch, to_slave.out = to_slave.out[:keep], []
            start = clock()
            if reduce_side == "rx":
                reduce(lambda _, data: receive(data, master_addr), batch, None)
            else:
                rx(batch)
            elapsed = clock() - start
            rx_time += elapsed
            if batch:
                rx_chunks.append(elapsed / len(batch))
            rx_count += len(batch)
            await asyncio.sleep(0)
        best_tx = min(best_tx, tx_time / tx_count * 1e6)
        best_rx = min(best_rx, rx_time / max(rx_count, 1) * 1e6)
    stats = slave.stats
    report = {
        "build": build_info().describe(),
        "tx_us": best_tx,
        "rx_us": best_rx,
        "tx_us_q1": sorted(tx_chunks)[len(tx_chunks) // 4] * 1e6,
        "rx_us_q1": sorted(rx_chunks)[len(rx_chunks) // 4] * 1e6,
        "samples_delivered": received.count,
        "acks_sent": stats.sent.ack_packets,
        "peer_gaps": stats.peer_gaps,
    }
    await master.close()
    await server.close()
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--chunks", type=int, default=600)
    parser.add_argument("--keep", type=int, default=27, help="datagrams of each 64 received")
    parser.add_argument("--reduce", choices=["rx", "tx"], help="for callgrind --toggle-collect")
    args = parser.parse_args()
    report = common.run_in_loop(
        "uvloop", lambda: measure(args.rounds, args.chunks, args.keep, args.reduce)
    )
    print(
        f"{report['build']}: send {report['tx_us']:.2f} us per sample (q1 {report['tx_us_q1']:.2f}),"
        f" receive {report['rx_us']:.2f} us per datagram (q1 {report['rx_us_q1']:.2f});"
        f" {report['samples_delivered']} delivered, {report['acks_sent']} ACKs,"
        f" {report['peer_gaps']} gaps"
    )


if __name__ == "__main__":
    main()
