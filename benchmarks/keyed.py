"""What a keyed session costs: bytes per sample and CPU per packet, keyed against unkeyed.

Usage: ``python benchmarks/keyed.py [--seconds 1] [--repeat 3] [--json]``

Method. Two measurements, each keyed against unkeyed in the same run (repetition i of one right after
repetition i of the other; ratios are paired and their median reported):

- **Bytes per sample** on the wire, UDP/IPv4 included, at 1000 samples/s of 100 bytes each way for one
  second, counted from the connections' own statistics in fake time (``tests/pair.py``-style, no
  sockets): bytes do not depend on timing, so this figure is exact. Handshake included.
- **CPU per packet**: a master and a slave ``Connection`` driven back to back in this process with no
  sockets (send, ``datagrams_to_send``, ``receive_datagram``, ``next_event``, both ways), flow control
  out of the way (``fixed``, unlimited). Process CPU time (``time.process_time_ns``, robust to other
  tenants) over ``--seconds`` of work, divided by the packets carried: the protocol's own cost per
  packet and side, sender plus receiver. Beside it the AEAD alone (seal + open of one 100-byte sample)
  for AES-128-GCM and ChaCha20-Poly1305.

End to end, the keyed path is measured exactly like the unkeyed one, in the same runs: its round trip
(against raw uvloop and against unkeyed tdtp) in ``latency.py``, its one-way throughput and capacity
ratio in ``throughput.py``.

No target in issue 11: the figures say what security costs.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Row, Stat

from tdtp import Connection, ConnectionConfig, PresharedKey, Role
from tdtp.control.fixed import FixedConfig
from tdtp.protection.derivation import TrafficSecret
from tdtp.protection.packet_protection import PacketOpener, PacketSealer
from tdtp.wire import CipherSuite, encode_header

PAYLOAD = bytes(100)
UDP_IP = 28
KEY = PresharedKey(bytes(range(32)), "bench")
MASTER, SLAVE = ("192.0.2.1", 40001), ("192.0.2.2", 40002)
UNLIMITED = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))
PACED = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=1000.0))


def _pair(keyed: bool, config: ConnectionConfig) -> tuple[Connection, Connection]:
    """A master and a slave opened back to back at t = 0 (datagrams delivered instantly)."""
    master = Connection(config, role=Role.MASTER, key=KEY if keyed else None)
    slave = Connection(config, role=Role.SLAVE, keys=[KEY] if keyed else None)
    master.connect(SLAVE, now=0.0)
    for _ in range(4):
        _deliver(master, slave, MASTER, 0.0)
        _deliver(slave, master, SLAVE, 0.0)
    return master, slave


def _deliver(sender: Connection, receiver: Connection, source: tuple[str, int], now: float) -> int:
    count = 0
    for datagram, _ in sender.datagrams_to_send(now=now):
        receiver.receive_datagram(datagram, source, now=now)
        count += 1
    while receiver.next_event() is not None:
        pass
    return count


def bytes_per_sample(keyed: bool) -> float:
    """Wire bytes (UDP/IPv4 included) per sample delivered, 1 kHz each way for 1 s, handshake in."""
    master, slave = _pair(keyed, PACED)
    for tick in range(1, 1001):
        now = tick * 0.001
        master.send(PAYLOAD, now=now)
        slave.send(PAYLOAD, now=now)
        _deliver(master, slave, MASTER, now)
        _deliver(slave, master, SLAVE, now)
        for conn, other, source in ((master, slave, MASTER), (slave, master, SLAVE)):
            timer = conn.get_timer()
            if timer is not None and timer <= now:
                conn.handle_timer(now=now)
                _deliver(conn, other, source, now)
    wire = sum(c.stats.sent.bytes + UDP_IP * c.stats.sent.datagrams for c in (master, slave))
    delivered = master.stats.samples_delivered + slave.stats.samples_delivered
    assert delivered == 2000, delivered
    return wire / delivered


def cpu_per_packet(keyed: bool, seconds: float) -> float:
    """Process CPU ns per packet and side (one send plus one receive), back to back in memory."""
    master, slave = _pair(keyed, UNLIMITED)
    packets = 0
    now = 0.001
    start = time.process_time_ns()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        for _ in range(200):
            now += 0.001
            master.send(PAYLOAD, now=now)
            packets += _deliver(master, slave, MASTER, now)
            slave.send(PAYLOAD, now=now)
            packets += _deliver(slave, master, SLAVE, now)
    spent = time.process_time_ns() - start
    assert master.stats.packets_lost == 0 and slave.stats.dropped <= 1
    return spent / packets


def aead_ns(suite: CipherSuite, seconds: float) -> float:
    """ns to seal and open one 100-byte sample (with its header) under ``suite``."""
    size = 16 if suite is CipherSuite.AES_128_GCM else 32
    secret = TrafficSecret(bytes(size), bytes(12))
    sealer = PacketSealer(suite, secret, encrypt=True)
    opener = PacketOpener(suite, secret, encrypt=True)
    header = encode_header(0, 1, 2, 3, 4)
    count = 0
    start = time.process_time_ns()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        for _ in range(1000):
            assert opener.open(sealer.seal(header, PAYLOAD), 5) is not None
        count += 1000
    return (time.process_time_ns() - start) / count


def main(argv: list[str] | None = None) -> int:
    p = common.parser(__doc__, seconds=1.0, repeat=3, help_seconds="CPU time per run")
    args = p.parse_args(argv)
    common.warn_if_loaded()
    rows: list[Row] = []
    sizes = {keyed: bytes_per_sample(keyed) for keyed in (False, True)}
    rows.append(
        Row(
            "keyed",
            "wire bytes per 100 B sample, 1 kHz each way, UDP/IPv4 included (exact)",
            "B",
            Stat.of([sizes[True]]),
            baseline="unkeyed",
            baseline_value=Stat.of([sizes[False]]),
            ratio=Stat.of([sizes[True] / sizes[False]]),
            ratio_label="keyed/unkeyed",
            digits=2,
        )
    )
    cpu: dict[bool, list[float]] = {False: [], True: []}
    aead: dict[CipherSuite, list[float]] = {
        CipherSuite.AES_128_GCM: [],
        CipherSuite.CHACHA20_POLY1305: [],
    }
    for rep in range(args.repeat):
        print(f"rep {rep + 1}/{args.repeat}: CPU per packet ...", file=sys.stderr)
        for keyed in (False, True):
            cpu[keyed].append(cpu_per_packet(keyed, args.seconds / 2) / 1e3)
        for suite, values in aead.items():
            values.append(aead_ns(suite, args.seconds / 4) / 1e3)
    rows.append(
        Row(
            "keyed",
            "protocol CPU per packet (send + receive), in memory, AES-128-GCM",
            "us",
            Stat.of(cpu[True]),
            baseline="unkeyed",
            baseline_value=Stat.of(cpu[False]),
            ratio=Stat.of(common.paired_ratios(cpu[True], cpu[False])),
            ratio_label="keyed/unkeyed",
            digits=2,
        )
    )
    for suite, values in aead.items():
        rows.append(
            Row(
                "keyed",
                f"AEAD alone: seal + open one 100 B sample, {suite.name}",
                "us",
                Stat.of(values),
                digits=2,
            )
        )
    text = (
        f"Bytes per sample: unkeyed {sizes[False]:.2f}, keyed {sizes[True]:.2f} "
        f"(+{sizes[True] - sizes[False]:.2f}: packet number 2 + tag 16, handshake amortised)."
    )
    details = {
        "bytes_per_sample": {"unkeyed": sizes[False], "keyed": sizes[True]},
        "cpu_us": {"unkeyed": cpu[False], "keyed": cpu[True]},
        "aead_us": {suite.name: values for suite, values in aead.items()},
    }
    return common.emit("keyed", args, rows, details=details, text=text)


if __name__ == "__main__":
    sys.exit(main())
