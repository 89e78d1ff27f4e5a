"""Issue 31's forgery attacks, on real loopback sockets at 1 kHz: what each costs the operator.

    nice -n 5 .venv/bin/python benchmarks/attacks.py [--only NAME ...] [--seconds 4] [--json]

Every session runs through a small UDP relay (:class:`Relay`): the master connects to the relay's
port, the relay forwards to the slave and back. To the slave the relay's address *is* the master's,
to the master it *is* the slave's, so a datagram the script sends from the relay's socket is one
forged from that address, and the datagrams the relay forwards are what an observer on the path
sees. The attacks (docs/SECURITY.md, PROTOCOL.md 5.7, 5.8, 5.10):

* ``baseline``: unkeyed, 1 kHz both ways, no attack: the samples per second this machine delivers
  in the same run, to compare the others with.
* ``reset_oracle``: keyed, the master at 100 Hz (its session goes quiet between datagrams). Every
  50 ms the attacker takes the master's newest datagram, replays it from a fresh address to the
  same slave (``same``) or to a second slave holding the same key (``second``), and forwards any
  RESET it gets back to the master as if from the slave. Reported: RESETs obtained, whether the
  master's session ended, and how.
* ``message_sweep``: unkeyed, 1 kHz both ways. The attacker, off path (it knows the addresses and
  ports, not the nonce nor the message numbers), sends a forged MESSAGE for every 16-bit message
  number from the master's address, while the master sends 20 real messages; then the master
  sends an emergency stop. Reported: forged messages delivered, real ones delivered, whether the
  stop arrived.
* ``data_ahead``: unkeyed, 1 kHz both ways; 20 forged DATA a second from the master's address,
  each numbered 63 above the master's newest (the attacker reads it off the path: stronger than
  off path). Reported: samples per second each way while it lasts.
* ``quiet_master``: unkeyed, the master sends no samples (acknowledgements only), the slave 1 kHz.
  An on-path attacker (it saw the master's nonce in a KEEPALIVE and sees the slave's
  PATH_CHALLENGEs) replays that KEEPALIVE from a victim's address every 50 ms and answers each
  challenge to the victim with a PATH_RESPONSE carrying the nonce. Reported: bytes the victim
  received over bytes sent as the victim, and the samples per second the operator still gets.

Figures depend on the machine only through timing (a loaded machine sends fewer samples a second);
compare the ratios and the yes/no rows.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import random
import socket
import struct
import sys
from collections import deque
from typing import Any

import tdtp
from tdtp import ConnectionConfig
from tdtp.protection import PresharedKey
from tdtp.wire import PROTOCOL_VERSION, ControlCode, encode_header

KEY = PresharedKey(bytes(range(32)), name="operator")
LOCAL = "127.0.0.1"
_CONTROL_HEADER = encode_header(2, 0, 0, 0, 255)
Address = tuple[str, int]


class Relay(asyncio.DatagramProtocol):
    """Forwards between one master and one slave; remembers what passed; can forge from itself."""

    def __init__(self, slave: Address) -> None:
        self.slave = slave
        self.master: Address | None = None
        self.transport: asyncio.DatagramTransport | None = None
        self.to_slave: deque[bytes] = deque(maxlen=64)
        self.to_master: deque[bytes] = deque(maxlen=64)
        self.keepalive: bytes | None = None
        """The master's newest KEEPALIVE (it carries the master's nonce)."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: Address) -> None:
        assert self.transport is not None
        if addr[:2] == self.slave[:2]:
            self.to_master.append(data)
            if self.master is not None:
                self.transport.sendto(data, self.master)
        else:
            self.master = addr
            self.to_slave.append(data)
            if len(data) == 22 and data[5] == ControlCode.KEEPALIVE:
                self.keepalive = data
            self.transport.sendto(data, self.slave)

    def forge_to_slave(self, data: bytes) -> None:
        """A datagram from the master's address (as the slave sees it)."""
        assert self.transport is not None
        self.transport.sendto(data, self.slave)

    def forge_to_master(self, data: bytes) -> None:
        """A datagram from the slave's address (as the master sees it)."""
        assert self.transport is not None and self.master is not None
        self.transport.sendto(data, self.master)

    @property
    def port(self) -> int:
        assert self.transport is not None
        return int(self.transport.get_extra_info("sockname")[1])


async def _relay(slave_port: int) -> Relay:
    loop = asyncio.get_running_loop()
    _, relay = await loop.create_datagram_endpoint(
        lambda: Relay((LOCAL, slave_port)), local_addr=(LOCAL, 0)
    )
    return relay


class Catcher(asyncio.DatagramProtocol):
    """A socket of the attacker's (or the victim's): what arrives, and bytes in and out."""

    def __init__(self) -> None:
        self.transport: asyncio.DatagramTransport | None = None
        self.arrived: deque[bytes] = deque(maxlen=1024)
        self.bytes_in = 0
        self.bytes_out = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: Address) -> None:
        self.arrived.append(data)
        self.bytes_in += len(data)

    def send(self, data: bytes, addr: Address) -> None:
        assert self.transport is not None
        self.bytes_out += len(data)
        self.transport.sendto(data, addr)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


async def _catcher() -> Catcher:
    loop = asyncio.get_running_loop()
    _, catcher = await loop.create_datagram_endpoint(Catcher, local_addr=(LOCAL, 0))
    return catcher


async def _ticker(rate: float, action: Any, stop: asyncio.Event) -> None:
    async for _ in tdtp.Ticker(rate):
        if stop.is_set():
            return
        action()


def _safe(send: Any) -> Any:
    def act(*args: Any) -> None:
        with contextlib.suppress(tdtp.TdtpError):  # the session ended: the figures say so
            send(*args)

    return act


async def _session(
    *,
    keyed: bool,
    master_rate: float,
    slave_rate: float,
    seconds: float,
    attack: Any,
    second_slave: bool = False,
) -> dict[str, Any]:
    """A master and a slave through a relay; ``attack(relay, ctx)`` runs beside them for
    ``seconds``. Returns what both ends received, and the attack's own figures in ctx."""
    config = ConnectionConfig()
    keys = [KEY] if keyed else None
    async with tdtp.listen(LOCAL, 0, keys=keys, config=config) as server:
        second = await tdtp.listen(LOCAL, 0, keys=keys) if second_slave else None
        relay = await _relay(server.port)
        master = await tdtp.connect(LOCAL, relay.port, key=KEY if keyed else None, config=config)
        slave = await asyncio.wait_for(server.accept(), 5.0)
        received = {"master": 0, "slave": 0}
        master.set_data_callback(lambda _: received.__setitem__("master", received["master"] + 1))
        slave.set_data_callback(lambda _: received.__setitem__("slave", received["slave"] + 1))
        stop = asyncio.Event()
        payload = bytes(100)
        tasks = []
        if master_rate:
            tasks.append(asyncio.create_task(_ticker(master_rate, _safe(lambda: master.send(payload)), stop)))  # fmt: skip
        if slave_rate:
            tasks.append(asyncio.create_task(_ticker(slave_rate, _safe(lambda: slave.send(payload)), stop)))  # fmt: skip
        await asyncio.sleep(0.5)  # settled
        ctx: dict[str, Any] = {
            "master": master,
            "slave": slave,
            "server": server,
            "second": second,
            "stop": stop,
        }
        before = dict(received)
        started = asyncio.get_running_loop().time()
        attacker = asyncio.create_task(attack(relay, ctx))
        await asyncio.sleep(seconds)
        elapsed = asyncio.get_running_loop().time() - started
        during = {side: (received[side] - before[side]) / elapsed for side in received}
        stop.set()
        await attacker
        await asyncio.gather(*tasks)
        result = {
            "master_samples_per_s": round(during["master"]),
            "slave_samples_per_s": round(during["slave"]),
            "master_ended": master.is_closed,
            "master_close": None if master.close_event is None else master.close_event.cause.value,
            "master_drops": dict(master.stats.drops),
            "slave_drops": dict(slave.stats.drops),
        }
        result.update({k: v for k, v in ctx.items() if k not in ("master", "slave", "server", "second", "stop")})  # fmt: skip
        await master.close()
        if second is not None:
            await second.close()
        assert relay.transport is not None
        relay.transport.close()
        return result


# ---------------------------------------------------------------------- the attacks


def _reset_oracle(target: str) -> Any:
    async def attack(relay: Relay, ctx: dict[str, Any]) -> None:
        attacker = await _catcher()
        slave_port = ctx["second"].port if target == "second" else relay.slave[1]
        resets = 0
        while not ctx["stop"].is_set():
            sniffed = [d for d in relay.to_slave if len(d) > 60]
            if sniffed:
                attacker.arrived.clear()
                attacker.send(sniffed[-1], (LOCAL, slave_port))
                await asyncio.sleep(0.02)
                for answer in list(attacker.arrived):
                    if len(answer) > 5 and answer[5] == ControlCode.RESET:
                        resets += 1
                        relay.forge_to_master(answer)
            await asyncio.sleep(0.03)
        ctx["resets_obtained"] = resets
        attacker.close()

    return attack


def _message(seq: int, ack: int, data: bytes, nonce: bytes) -> bytes:
    """A MESSAGE as an off-path forger writes it (version 3 had no nonce field)."""
    body = struct.pack(">HH", seq, ack) + data
    if PROTOCOL_VERSION >= 4:
        body = nonce + body
    return _CONTROL_HEADER + bytes((ControlCode.MESSAGE,)) + body


async def _message_sweep(relay: Relay, ctx: dict[str, Any]) -> None:
    master, slave = ctx["master"], ctx["slave"]
    rng = random.Random(31)
    delivered: list[bytes] = []
    slave.set_control_callback(
        lambda event: delivered.append(bytes(getattr(event, "payload", b"")))
    )
    for index in range(20):
        master.send_control(b"real %d" % index)
    for seq in range(65536):
        # Two acknowledgements half the space apart: one of them acknowledges nothing new.
        ack = rng.randrange(65536)
        for guess in (ack, ack ^ 0x8000):
            relay.forge_to_slave(_message(seq, guess, b"FORGED", rng.randbytes(16)))
        if seq % 128 == 127:
            await asyncio.sleep(0.002)
    master.send_control(b"E-STOP")
    for _ in range(300):
        if b"E-STOP" in delivered:
            break
        await asyncio.sleep(0.01)
    ctx["forged_delivered"] = sum(1 for m in delivered if m == b"FORGED")
    ctx["real_delivered"] = sum(1 for m in delivered if m.startswith(b"real"))
    ctx["stop_delivered"] = b"E-STOP" in delivered
    await ctx["stop"].wait()


async def _data_ahead(relay: Relay, ctx: dict[str, Any]) -> None:
    forged = 0
    while not ctx["stop"].is_set():
        data = [d for d in relay.to_slave if d[0] >> 6 == 0]
        if data:
            header = int.from_bytes(data[-1][:5], "big")
            seq = (header >> 26) & 0xFFF
            relay.forge_to_slave(encode_header(0, (seq + 63) & 0xFFF, 0, 0, 255) + bytes(100))
            forged += 1
        await asyncio.sleep(0.05)
    ctx["forged_data"] = forged


async def _quiet_master(relay: Relay, ctx: dict[str, Any]) -> None:
    victim = await _catcher()
    slave_addr = relay.slave
    responses = 0
    while not ctx["stop"].is_set():
        keepalive = relay.keepalive
        if keepalive is not None:
            nonce = keepalive[6:22]
            victim.send(keepalive, slave_addr)
            await asyncio.sleep(0.005)
            for answer in list(victim.arrived):
                if len(answer) == 22 and answer[5] == ControlCode.PATH_CHALLENGE:
                    response = (
                        _CONTROL_HEADER + bytes((ControlCode.PATH_RESPONSE,)) + answer[6:22] + nonce
                    )
                    victim.send(response, slave_addr)
                    responses += 1
            victim.arrived.clear()
        await asyncio.sleep(0.045)
    ctx["victim_bytes_in"] = victim.bytes_in
    ctx["bytes_sent_as_victim"] = victim.bytes_out
    ctx["victim_ratio"] = round(victim.bytes_in / max(1, victim.bytes_out), 2)
    ctx["responses"] = responses
    victim.close()


async def _no_attack(relay: Relay, ctx: dict[str, Any]) -> None:
    """The baseline: the same session through the relay, nobody attacking (what the machine's load
    leaves of 1000 samples/s in this run)."""
    await ctx["stop"].wait()


ATTACKS = {
    "baseline": dict(keyed=False, master_rate=1000, slave_rate=1000, attack=_no_attack),
    "reset_oracle_same": dict(
        keyed=True, master_rate=100, slave_rate=0, attack=_reset_oracle("same")
    ),
    "reset_oracle_second": dict(
        keyed=True, master_rate=100, slave_rate=0, attack=_reset_oracle("second"), second_slave=True
    ),
    "message_sweep": dict(keyed=False, master_rate=1000, slave_rate=1000, attack=_message_sweep),
    "data_ahead": dict(keyed=False, master_rate=1000, slave_rate=1000, attack=_data_ahead),
    "quiet_master": dict(keyed=False, master_rate=0, slave_rate=1000, attack=_quiet_master),
}


async def _run(names: list[str], seconds: float) -> dict[str, Any]:
    results = {}
    for name in names:
        print(f"  {name} ...", file=sys.stderr)
        results[name] = await _session(seconds=seconds, **ATTACKS[name])
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", nargs="*", choices=sorted(ATTACKS), default=list(ATTACKS))
    parser.add_argument("--seconds", type=float, default=4.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results = asyncio.run(_run(args.only, args.seconds))
    info = {
        "protocol_version": PROTOCOL_VERSION,
        "core": tdtp.build_info().describe(),
        "load": round(os.getloadavg()[0], 2),
    }
    if args.json:
        print(json.dumps({"info": info, "results": results}, indent=2))
        return
    print(
        f"attacks: protocol version {info['protocol_version']}, {info['core']}, load {info['load']}"
    )
    for name, result in results.items():
        print(f"\n{name}")
        for key, value in result.items():
            print(f"  {key}: {value}")


if __name__ == "__main__":
    socket.setdefaulttimeout(5.0)
    main()
