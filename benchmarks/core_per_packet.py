"""CPU microseconds per packet of the sans-IO core alone: no sockets, no event loop.

Usage: ``python benchmarks/core_per_packet.py`` (``TDTP_PURE_PYTHON=1`` for the pure-Python build)

A master and a slave connection (``fixed`` controller, ``rate=inf``) opened against each other in
fake time, then, five rounds each, the figure being the round with the least CPU time
(``time.process_time``, which another tenant on the machine moves less than the wall clock):

- ``send``: the master's ``send_direct`` of 40,000 samples of 100 bytes, one way;
- ``recv``: the slave's ``receive_datagram`` of half of them, its events and datagrams taken every 64;
- ``recv+flush``: the other half as an endpoint on the loop's transport takes them: after every
  datagram ``datagrams_to_send``, the events drained, ``timer_hint`` read;
- ``both ways``: each side sends 8 samples, then each takes the other's 8 (every data packet carries
  an acknowledgement) with ``datagrams_to_send`` and the events after each; CPU per packet sent and
  received (both sides' work for it).

No target: it is the profile's yardstick for the per-packet paths (benchmarks/HISTORY.md, "The
per-packet paths of the core").
"""

from __future__ import annotations

import math
import random
import time

from tdtp import Connection, ConnectionConfig, Role, build_info
from tdtp.control.fixed import FixedConfig

MASTER, SLAVE = ("127.0.0.1", 40001), ("127.0.0.1", 40002)
ROUNDS = 5
PAYLOAD = bytes(100)


def _pair() -> tuple[Connection, Connection, float]:
    config = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))
    master = Connection(config, role=Role.MASTER, rng=random.Random(1))
    slave = Connection(config, role=Role.SLAVE, rng=random.Random(2))
    now = 1.0
    master.connect(SLAVE, now=now)
    for _ in range(6):
        for data, _addr in master.datagrams_to_send(now=now):
            slave.receive_datagram(data, MASTER, now=now)
        for data, _addr in slave.datagrams_to_send(now=now):
            master.receive_datagram(data, SLAVE, now=now)
        now += 0.001
    return master, slave, now


def one_way(samples: int = 40_000) -> dict[str, float]:
    master, slave, now = _pair()
    best = {"send": math.inf, "recv": math.inf, "recv+flush": math.inf}
    clock = time.process_time
    wire: list[bytes] = []

    def transmit(data: bytes, addr: object) -> None:
        wire.append(data)

    for _ in range(ROUNDS):
        wire.clear()
        start = clock()
        for _ in range(samples):
            now += 1e-5
            if not master.send_direct(PAYLOAD, transmit, connected=True, now=now):
                wire.extend(d for d, _ in master.datagrams_to_send(now=now))
        best["send"] = min(best["send"], (clock() - start) / samples * 1e6)
        half = len(wire) // 2
        receive = slave.receive_datagram
        start = clock()
        for count, data in enumerate(wire[:half], 1):
            now += 1e-5
            receive(data, MASTER, now=now)
            if count % 64 == 0:
                while slave.next_event() is not None:
                    pass
                slave.datagrams_to_send(now=now)
        best["recv"] = min(best["recv"], (clock() - start) / half * 1e6)
        start = clock()
        for data in wire[half:]:
            now += 1e-5
            receive(data, MASTER, now=now)
            slave.datagrams_to_send(now=now)
            if slave.pending_events:
                while slave.next_event() is not None:
                    pass
            _ = slave.timer_hint
        best["recv+flush"] = min(best["recv+flush"], (clock() - start) / (len(wire) - half) * 1e6)
    return best


def both_ways(steps: int = 20_000, burst: int = 8) -> float:
    master, slave, now = _pair()
    best = math.inf
    clock = time.process_time
    to_slave: list[bytes] = []
    to_master: list[bytes] = []

    def from_master(data: bytes, addr: object) -> None:
        to_slave.append(data)

    def from_slave(data: bytes, addr: object) -> None:
        to_master.append(data)

    for _ in range(ROUNDS):
        start = clock()
        for _ in range(steps):
            now += 2e-5
            for _ in range(burst):
                if not master.send_direct(PAYLOAD, from_master, connected=True, now=now):
                    to_slave.extend(d for d, _ in master.datagrams_to_send(now=now))
                if not slave.send_direct(PAYLOAD, from_slave, connected=False, now=now):
                    to_master.extend(d for d, _ in slave.datagrams_to_send(now=now))
            for conn, inbox, source, outbox in (
                (slave, to_slave, MASTER, to_master),
                (master, to_master, SLAVE, to_slave),
            ):
                for data in inbox:
                    conn.receive_datagram(data, source, now=now)
                    outbox.extend(d for d, _ in conn.datagrams_to_send(now=now))
                    while conn.next_event() is not None:
                        pass
                inbox.clear()
        best = min(best, (clock() - start) / (steps * 2 * burst) * 1e6)
    return best


def main() -> int:
    figures = one_way()
    print(f"tdtp core: {build_info().describe()}")
    print("  ".join(f"{name} {value:.3f}" for name, value in figures.items()), end="  ")
    print(f"both ways {both_ways():.3f}  (CPU us per packet, best of {ROUNDS} rounds)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
