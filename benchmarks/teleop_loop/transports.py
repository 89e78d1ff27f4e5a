"""The transports under test, behind one small interface: a :class:`Channel` at each end of the loop.

Each side's control loop calls ``channel.send(payload)`` once per tick and reads ``channel.latest()``,
the newest sample received so far (by the sample counter the payload carries, so a datagram that a
jittery link reorders behind a newer one never replaces it). A transport is a pair of async factories
(one for the master, one for the slave) in :data:`TRANSPORTS`, plus the impairment it goes through:

* ``tdtp``: tdtp's endpoints, default controller, impaired by their own in-process netem (each end
  impairs what it sends, with the profile's spec and its own seed).
* ``udp``: plain datagrams at the loop's fixed 1 kHz, no control, through ``tdtp netem-relay``.
* ``tcp``: asyncio streams with TCP_NODELAY, fixed-size frames, the reader keeps the newest frame;
  through :mod:`teleop_loop.tcp_link`, a TCP relay that applies the same netem spec per segment.
* ``zenoh``: eclipse-zenoh peers, best-effort express publications over its UDP link, through
  ``tdtp netem-relay``; loopback only, no scouting.

* ``tdtp-deadband``: tdtp as above, each side's samples through a perceptual deadband
  (:mod:`teleop_loop.deadband_channel`; ``deadband_k``, the Weber fraction, is its option).
"""

from __future__ import annotations

import asyncio
import json
import math
import socket
import struct
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import tdtp

_INDEX = struct.Struct(">I")
_INDEX_OFFSET = 8  # HapticSample: sent_at f64, then the u32 counter
FRAME = 100
"""Payload size of every sample (bytes), the demo's default: room for a 7-joint arm's state."""


class Channel(Protocol):
    def send(self, payload: bytes) -> None: ...
    def latest(self) -> bytes | None: ...
    def packets_sent(self) -> int | None:
        """Datagrams (or segments) this end put on the wire, when the transport can tell."""
        ...

    def details(self) -> dict[str, Any]:
        """What the transport knows about the run (its own counters), for the JSON; may be empty."""
        ...

    async def close(self) -> None: ...


class NewestSample:
    """Keeps the received payload with the highest sample counter (wrap-around aware)."""

    def __init__(self) -> None:
        self.payload: bytes | None = None
        self._index = -1
        self.received = 0

    def offer(self, payload: bytes) -> None:
        self.received += 1
        if len(payload) < _INDEX_OFFSET + 4:
            return
        (index,) = _INDEX.unpack_from(payload, _INDEX_OFFSET)
        if self._index < 0 or 0 < (index - self._index) % (1 << 32) < (1 << 31):
            self._index = index
            self.payload = payload


# --- tdtp --------------------------------------------------------------------------------------


class TdtpChannel:
    def __init__(self, ep: tdtp.Endpoint, server: tdtp.Server | None = None) -> None:
        self.ep = ep
        self._server = server

    def send(self, payload: bytes) -> None:
        self.ep.send(payload)

    def latest(self) -> bytes | None:
        sample = self.ep.latest()
        return None if sample is None else sample.payload

    def packets_sent(self) -> int | None:
        return self.ep.stats.sent.datagrams

    def details(self) -> dict[str, Any]:
        return tdtp_details(self.ep)

    async def close(self) -> None:
        await self.ep.close()
        if self._server is not None:
            await self._server.close()


async def tdtp_slave(port: int, spec: str, seed: int, **options: Any) -> tuple[Channel, int]:
    server = await tdtp.listen("127.0.0.1", port, netem=spec, netem_seed=seed, **options)
    port = server.port
    ready: asyncio.Future[Channel] = asyncio.get_running_loop().create_future()

    async def accept() -> None:
        ready.set_result(TdtpChannel(await server.accept(), server))

    task = asyncio.get_running_loop().create_task(accept())
    return _Deferred(ready, task), port


async def tdtp_master(port: int, spec: str, seed: int, **options: Any) -> Channel:
    ep = await tdtp.connect("127.0.0.1", port, netem=spec, netem_seed=seed, **options)
    return TdtpChannel(ep)


def tdtp_details(ep: tdtp.Endpoint) -> dict[str, Any]:
    """An endpoint's counters, its controller's view of the path, and its emulated link's counters."""
    stats = ep.stats.as_dict()
    out: dict[str, Any] = {
        key: stats[key]
        for key in (
            "samples_offered",
            "samples_superseded",
            "samples_blocked",
            "samples_delivered",
            "samples_skipped",
            "packets_acked",
            "packets_lost",
            "packets_reordered",
            "loss_events",
            "reordered",
            "reorder_held",
            "reorder_wait",
            "drops",
            "srtt",
            "rttvar",
            "min_rtt",
            "loss_event_rate",
            "rate",
            "rate_limit",
        )
    }
    controller = getattr(ep.connection, "_controller", None)
    for name in (
        "queue_delay",
        "base_rtt",
        "ceiling",
        "delay_decrease_count",
        "loss_decrease_count",
        "losses_ignored",
        "increase_count",
    ):
        value = getattr(controller, name, None)
        if isinstance(value, int | float):
            out[f"controller_{name}"] = None if value in (math.inf, -math.inf) else value
    line = getattr(getattr(ep, "_transport", None), "line", None)  # an ImpairedTransport's
    if line is not None:
        out["netem"] = line.link.stats.as_dict()
    return out


class _Deferred:
    """A slave's channel before the master has connected: sends nothing, has read nothing."""

    def __init__(self, ready: asyncio.Future[Channel], task: asyncio.Task[None]) -> None:
        self._ready = ready
        self._task = task

    def _channel(self) -> Channel | None:
        return self._ready.result() if self._ready.done() else None

    def send(self, payload: bytes) -> None:
        channel = self._channel()
        if channel is not None:
            channel.send(payload)

    def latest(self) -> bytes | None:
        channel = self._channel()
        return None if channel is None else channel.latest()

    def packets_sent(self) -> int | None:
        channel = self._channel()
        return 0 if channel is None else channel.packets_sent()

    def details(self) -> dict[str, Any]:
        channel = self._channel()
        return {} if channel is None else channel.details()

    async def close(self) -> None:
        channel = self._channel()
        self._task.cancel()
        if channel is not None:
            await channel.close()


# --- raw UDP -----------------------------------------------------------------------------------


class _UdpProtocol(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.newest = NewestSample()
        self.peer: tuple[str, int] | None = None

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.peer = addr  # the slave answers whoever wrote last (the relay's socket)
        self.newest.offer(data)

    def error_received(self, exc: Exception) -> None:
        pass  # ICMP unreachable while the peer starts or stops: nothing to do at 1 kHz


class UdpChannel:
    def __init__(self, transport: asyncio.DatagramTransport, proto: _UdpProtocol) -> None:
        self._transport = transport
        self._proto = proto
        self._sent = 0

    def send(self, payload: bytes) -> None:
        if self._proto.peer is not None:
            self._transport.sendto(payload, self._proto.peer)
            self._sent += 1

    def latest(self) -> bytes | None:
        return self._proto.newest.payload

    def packets_sent(self) -> int | None:
        return self._sent

    def details(self) -> dict[str, Any]:
        return {"datagrams_received": self._proto.newest.received}

    async def close(self) -> None:
        self._transport.close()


async def udp_slave(port: int, spec: str, seed: int) -> tuple[Channel, int]:
    loop = asyncio.get_running_loop()
    transport, proto = await loop.create_datagram_endpoint(
        _UdpProtocol, local_addr=("127.0.0.1", port)
    )
    return UdpChannel(transport, proto), transport.get_extra_info("sockname")[1]


async def udp_master(port: int, spec: str, seed: int) -> Channel:
    loop = asyncio.get_running_loop()
    transport, proto = await loop.create_datagram_endpoint(
        _UdpProtocol, local_addr=("127.0.0.1", 0)
    )
    proto.peer = ("127.0.0.1", port)
    return UdpChannel(transport, proto)


# --- TCP ---------------------------------------------------------------------------------------


class TcpChannel:
    """Fixed-size frames on a TCP_NODELAY stream; a reader task keeps the newest complete frame."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.get_extra_info("socket").setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._writer = writer
        self.newest = NewestSample()
        self._sent = 0
        self._reader = asyncio.get_running_loop().create_task(self._read(reader))

    async def _read(self, reader: asyncio.StreamReader) -> None:
        buffered = b""
        while True:
            chunk = await reader.read(65536)
            if not chunk:
                return
            buffered += chunk
            whole = len(buffered) - len(buffered) % FRAME
            if whole:
                self.newest.offer(buffered[whole - FRAME : whole])  # the newest complete frame
                buffered = buffered[whole:]

    def send(self, payload: bytes) -> None:
        if not self._writer.is_closing():
            self._writer.write(payload)  # TCP never drops: a backlog waits in the socket buffers
            self._sent += 1

    def latest(self) -> bytes | None:
        return self.newest.payload

    def packets_sent(self) -> int | None:
        return None  # segments are counted by the relay, where the impairment sees them

    def details(self) -> dict[str, Any]:
        return {"frames_read": self.newest.received}

    async def close(self) -> None:
        self._reader.cancel()
        self._writer.close()


async def tcp_slave(port: int, spec: str, seed: int) -> tuple[Channel, int]:
    ready: asyncio.Future[Channel] = asyncio.get_running_loop().create_future()

    async def accepted(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if not ready.done():
            ready.set_result(TcpChannel(reader, writer))

    server = await asyncio.start_server(accepted, "127.0.0.1", port)
    port = server.sockets[0].getsockname()[1]
    task = asyncio.get_running_loop().create_task(_serve_until_closed(server))
    return _Deferred(ready, task), port


async def _serve_until_closed(server: asyncio.Server) -> None:
    async with server:
        await server.serve_forever()


async def tcp_master(port: int, spec: str, seed: int) -> Channel:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    return TcpChannel(reader, writer)


# --- Zenoh -------------------------------------------------------------------------------------

_CMD_KEY = "tdtp-bench/closed-loop/command"
_FORCE_KEY = "tdtp-bench/closed-loop/force"


def zenoh_config(*, listen: str | None = None, connect: str | None = None) -> Any:
    """A peer on loopback only: UDP endpoints given here, no multicast or gossip scouting."""
    import zenoh  # noqa: PLC0415 - optional (the loop extra)

    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
    config.insert_json5("connect/endpoints", json.dumps([connect] if connect else []))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    return config


class ZenohChannel:
    def __init__(self, session: Any, publish: str, subscribe: str) -> None:
        import zenoh  # noqa: PLC0415 - optional (the loop extra)

        self._session = session
        self.newest = NewestSample()
        self._publisher = session.declare_publisher(
            publish,
            reliability=zenoh.Reliability.BEST_EFFORT,
            congestion_control=zenoh.CongestionControl.DROP,
            express=True,  # no batching: each sample leaves at once
        )
        self._subscriber = session.declare_subscriber(
            subscribe, lambda sample: self.newest.offer(bytes(sample.payload.to_bytes()))
        )
        self._sent = 0

    def send(self, payload: bytes) -> None:
        self._publisher.put(payload)
        self._sent += 1

    def latest(self) -> bytes | None:
        return self.newest.payload

    def packets_sent(self) -> int | None:
        return None  # zenoh's datagrams (with its keep-alives) are counted by the relay

    def details(self) -> dict[str, Any]:
        return {"samples_received": self.newest.received}

    async def close(self) -> None:
        await asyncio.to_thread(self._session.close)


async def zenoh_slave(port: int, spec: str, seed: int) -> tuple[Channel, int]:
    import zenoh  # noqa: PLC0415 - optional (the loop extra)

    if port == 0:
        port = _free_udp_port()
    config = zenoh_config(listen=f"udp/127.0.0.1:{port}")
    session = await asyncio.to_thread(zenoh.open, config)
    return ZenohChannel(session, _FORCE_KEY, _CMD_KEY), port


async def zenoh_master(port: int, spec: str, seed: int) -> Channel:
    import zenoh  # noqa: PLC0415 - optional (the loop extra)

    session = await asyncio.to_thread(zenoh.open, zenoh_config(connect=f"udp/127.0.0.1:{port}"))
    return ZenohChannel(session, _CMD_KEY, _FORCE_KEY)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


# --- tdtp with perceptual deadband --------------------------------------------------------------


async def tdtp_deadband_slave(
    port: int, spec: str, seed: int, *, deadband_k: float = 0.1
) -> tuple[Channel, int]:
    from teleop_loop.deadband_channel import DeadbandChannel  # noqa: PLC0415 - it imports this module

    channel, port = await tdtp_slave(port, spec, seed)
    return DeadbandChannel(channel, sends="force", k=deadband_k), port


async def tdtp_deadband_master(
    port: int, spec: str, seed: int, *, deadband_k: float = 0.1
) -> Channel:
    from teleop_loop.deadband_channel import DeadbandChannel  # noqa: PLC0415 - it imports this module

    return DeadbandChannel(await tdtp_master(port, spec, seed), sends="command", k=deadband_k)


# --- the registry ------------------------------------------------------------------------------

Impairment = Literal["in-process", "udp-relay", "tcp-relay"]


@dataclass(frozen=True)
class Transport:
    slave: Callable[..., Awaitable[tuple[Channel, int]]]
    """``slave(port, spec, seed, **options)``: listen on the port (0: any), impaired by the spec
    when in-process; the channel and the port."""
    master: Callable[..., Awaitable[Channel]]
    """``master(port, spec, seed, **options)``: connect to the port (the slave's, or the relay's in
    front of it)."""
    impairment: Impairment
    needs: str | None = None
    """The module it imports (its extra), for a clear message when it is missing."""
    options: tuple[str, ...] = ()
    """The keyword options both factories take (the benchmark's flags that tune this transport)."""

    def pick(self, options: dict[str, Any]) -> dict[str, Any]:
        """The options that apply to this transport."""
        return {key: value for key, value in options.items() if key in self.options}


TRANSPORTS: dict[str, Transport] = {
    "tdtp": Transport(tdtp_slave, tdtp_master, "in-process"),
    "tdtp-deadband": Transport(
        tdtp_deadband_slave, tdtp_deadband_master, "in-process", options=("deadband_k",)
    ),
    "udp": Transport(udp_slave, udp_master, "udp-relay"),
    "tcp": Transport(tcp_slave, tcp_master, "tcp-relay"),
    "zenoh": Transport(zenoh_slave, zenoh_master, "udp-relay", needs="zenoh"),
}
"""Every transport the benchmark can run, in the order the table shows them. ``partial`` fixes
options: e.g. ``Transport(partial(tdtp_slave, config=...), partial(tdtp_master, config=...), ...)``."""
