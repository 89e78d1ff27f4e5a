"""The same 100-byte samples as QUIC DATAGRAM frames (RFC 9221) through aioquic, next to tdtp.

Usage: ``python benchmarks/quic_peer.py [--seconds 1] [--repeat 3] [--json]``

Needs ``aioquic`` (the ``bench`` extra: ``pip install 'tdtp[bench]'``); without it the script says so and
exits 0. The TLS certificate is a self-signed ECDSA P-256 one for ``localhost``, generated at run time
with ``cryptography`` (an aioquic dependency); clients do not verify it.

Two measurements, both on uvloop, QUIC and tdtp in the same run, interleaved:

1. **Throughput**, one direction saturated: exactly throughput.py's method (two processes pinned to
   their own CPUs, the receive rate counted over ``--seconds`` after a 0.3 s warm-up). tdtp is
   throughput.py's ``tdtp uvloop`` variant. For QUIC the client offers each sample with
   ``send_datagram_frame`` followed by ``transmit()``, so that each sample leaves in its own UDP datagram
   as soon as congestion control lets it (a real-time sender does not wait to fill packets); a sample
   offered while 64 frames are still queued behind QUIC's congestion window is dropped at the sender
   (latest-value semantics, like tdtp's pacer; the queue length is read from aioquic's private
   ``_datagrams_pending``). The server counts ``DatagramFrameReceived`` events. As there, a run
   during which other processes used more than 20 % of a core is run again (at most ``--repeat``)
   and, if still contended, left out of the statistics while at least two runs are clean.
2. **Bytes on the wire per payload byte** at 1 kHz each way (wire_efficiency.py's load): one process,
   a QUIC pair and a tdtp pair (default config) each sending one 100-byte sample per 1 kHz tick from
   both ends for ``--seconds``. QUIC's datagrams are counted by a transport proxy installed in the
   client protocol's and the server's ``connection_made`` (every UDP datagram either side sends: data,
   ACK-only, everything), tdtp's by its connection counters (checked against a proxy in
   wire_efficiency.py). On the wire each datagram costs its UDP payload plus 28 bytes (IPv4 + UDP).
   Counting starts once both connections are up (the QUIC handshake's bytes are reported apart) and
   stops before they close.

No target in issue 6: this is what a user would pick instead, so the rows show where tdtp stands.
"""

from __future__ import annotations

import asyncio
import datetime
import ssl
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
import throughput
from _common import Json, Row, Stat

from tdtp import Ticker
from tdtp.aio.api import connect, listen
from tdtp.aio.timer import monotonic

PAYLOAD_SIZE = 100
UDP_IP = 28
RATE = 1000.0
MAX_PENDING = 64
ALPN = ["tdtp-bench"]


def aioquic_missing() -> str | None:
    try:
        import aioquic  # noqa: F401, PLC0415
        import cryptography  # noqa: F401, PLC0415
    except ImportError as exc:
        return f"{exc.name} is not installed (pip install 'tdtp[bench]'): QUIC benchmark skipped"
    return None


def make_certificate() -> tuple[bytes, bytes]:
    """A self-signed ECDSA P-256 certificate for localhost: (certificate PEM, private key PEM)."""
    from cryptography import x509  # noqa: PLC0415
    from cryptography.hazmat.primitives import hashes, serialization  # noqa: PLC0415
    from cryptography.hazmat.primitives.asymmetric import ec  # noqa: PLC0415
    from cryptography.x509.oid import NameOID  # noqa: PLC0415

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "localhost")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([x509.DNSName("localhost")]), critical=False)
        .sign(key, hashes.SHA256())
    )
    return (
        cert.public_bytes(serialization.Encoding.PEM),
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        ),
    )


# ---------------------------------------------------------------------------- QUIC plumbing


@dataclass
class ByteCount:
    datagrams: int = 0
    udp_payload: int = 0

    @property
    def wire(self) -> int:
        return self.udp_payload + UDP_IP * self.datagrams


class CountingTransport:
    """Counts what passes through ``sendto``; everything else goes to the real transport."""

    def __init__(self, transport: Any, count: ByteCount) -> None:
        self._transport = transport
        self._count = count

    def sendto(self, data: bytes, addr: Any = None) -> None:
        self._count.datagrams += 1
        self._count.udp_payload += len(data)
        self._transport.sendto(data, addr)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._transport, name)


def _configuration(is_client: bool, cert: bytes, key: bytes) -> Any:
    from aioquic.quic.configuration import QuicConfiguration  # noqa: PLC0415
    from cryptography import x509  # noqa: PLC0415
    from cryptography.hazmat.primitives import serialization  # noqa: PLC0415

    config = QuicConfiguration(
        is_client=is_client, alpn_protocols=ALPN, max_datagram_frame_size=65536
    )
    if is_client:
        config.verify_mode = ssl.CERT_NONE
        config.server_name = "localhost"
    else:
        config.certificate = x509.load_pem_x509_certificate(cert)
        config.private_key = serialization.load_pem_private_key(key, password=None)
    return config


def _protocol_classes(
    count: ByteCount, on_frame: Callable[[bytes], None], created: list[Any]
) -> tuple[type, type]:
    """A connection protocol and a server protocol that count their UDP datagrams into ``count``."""
    from aioquic.asyncio.protocol import QuicConnectionProtocol  # noqa: PLC0415
    from aioquic.asyncio.server import QuicServer  # noqa: PLC0415
    from aioquic.quic.events import DatagramFrameReceived  # noqa: PLC0415

    class Protocol(QuicConnectionProtocol):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            created.append(self)

        def connection_made(self, transport: Any) -> None:
            if not isinstance(transport, CountingTransport):
                transport = CountingTransport(transport, count)
            super().connection_made(transport)

        def quic_event_received(self, event: Any) -> None:
            if isinstance(event, DatagramFrameReceived):
                on_frame(event.data)
            super().quic_event_received(event)

        @property
        def quic(self) -> Any:
            return self._quic

    class Server(QuicServer):
        def connection_made(self, transport: Any) -> None:
            self.real_transport = transport
            super().connection_made(cast(Any, CountingTransport(transport, count)))

    return Protocol, Server


async def quic_server(
    cert: bytes, key: bytes, count: ByteCount, on_frame: Callable[[bytes], None], created: list[Any]
) -> tuple[Any, int]:
    protocol, server_cls = _protocol_classes(count, on_frame, created)
    loop = asyncio.get_running_loop()
    _, server = await loop.create_datagram_endpoint(
        lambda: server_cls(
            configuration=_configuration(False, cert, key), create_protocol=protocol
        ),
        local_addr=("127.0.0.1", 0),
    )
    return server, server.real_transport.get_extra_info("sockname")[1]


def quic_connect(
    port: int, cert: bytes, count: ByteCount, on_frame: Callable[[bytes], None], created: list[Any]
) -> Any:
    from aioquic.asyncio.client import connect as quic_client  # noqa: PLC0415

    protocol, _ = _protocol_classes(count, on_frame, created)
    return quic_client(
        "127.0.0.1",
        port,
        configuration=_configuration(True, cert, b""),
        create_protocol=protocol,
    )


def datagram_sender(protocol: Any) -> tuple[Callable[[bytes], None], list[int]]:
    """``send(payload)``: one DATAGRAM frame, transmitted at once; drops when 64 are queued."""
    quic = protocol.quic
    transmit = protocol.transmit
    pending = getattr(quic, "_datagrams_pending", None)  # private; None = cannot bound the queue
    dropped = [0]

    def send(payload: bytes) -> None:
        if pending is not None and len(pending) >= MAX_PENDING:
            dropped[0] += 1
            return
        quic.send_datagram_frame(payload)
        transmit()

    return send, dropped


# ---------------------------------------------------------------------------- throughput workers


async def _quic_peer(
    control: Any, role: str, port: int, seconds: float, warmup: float, cert: bytes, key: bytes
) -> Json:
    rx = throughput.RxCounter()
    count = ByteCount()
    created: list[Any] = []

    def on_frame(_: bytes) -> None:
        rx.count += 1

    report: Json = {"role": role}
    if role == "server":
        server, bound = await quic_server(cert, key, count, on_frame, created)
        control.conn.send({"port": bound})
        window = await throughput.receive_window(rx, warmup, seconds)
        report["window"] = window
        control.conn.send({"window": window})
        while not control.poll():
            await asyncio.sleep(0.01)
        report["datagrams_sent"] = count.datagrams
        server.close()
        return report
    async with quic_connect(port, cert, count, on_frame, created) as protocol:
        send, dropped = datagram_sender(protocol)
        control.conn.send({"window": None})
        b = await throughput.blast(send, control, warmup + seconds + 30.0)
        report["blast"] = {
            "sent": b.sent,
            "rate": b.sent / b.elapsed if b.elapsed else 0.0,
            "cpu_percent": 100.0 * b.cpu / b.elapsed if b.elapsed else 0.0,
            "stopped_by": b.stopped_by,
            "dropped_at_sender": dropped[0],
            "datagrams_sent": count.datagrams,
        }
    return report


def quic_worker(
    conn: Any,
    *,
    role: str,
    port: int,
    seconds: float,
    warmup: float,
    cert: bytes,
    key: bytes,
    cpu_slot: int,
) -> None:
    common.pin_to_cpu(cpu_slot)
    control = throughput.Control(conn)
    report = common.run_in_loop(
        "uvloop", lambda: _quic_peer(control, role, port, seconds, warmup, cert, key)
    )
    conn.send({"final": report})


def run_quic_pair(seconds: float, warmup: float, cert: bytes, key: bytes) -> Json:
    others = common.OthersMeter()
    (window, _), rx_final, tx_final = throughput.drive_pair(
        "quic", quic_worker, seconds, warmup, cert=cert, key=key
    )
    blast = tx_final["blast"]
    queued = 1.0 - blast["dropped_at_sender"] / blast["sent"] if blast["sent"] else 0.0
    return {
        "rate": window["rate"],
        "sender_rate": blast["rate"] * queued,  # frames handed to QUIC, not the dropped offers
        "rx_cpu_percent": window["cpu_percent"],
        "tx_cpu_percent": blast["cpu_percent"],
        "dropped_at_sender": blast["dropped_at_sender"],
        "others_percent": others.percent(),
        "server": rx_final,
        "client": tx_final,
    }


# ---------------------------------------------------------------------------- 1 kHz each way


async def _tick(send: Callable[[bytes], None], start: float, count: int) -> None:
    payload = bytes(PAYLOAD_SIZE)
    async for index in Ticker(RATE, start=start):
        send(payload)
        if index >= count - 1:
            return


async def _quic_1khz(seconds: float, cert: bytes, key: bytes) -> Json:
    count = ByteCount()
    frames = [0]
    created: list[Any] = []

    def on_frame(_: bytes) -> None:
        frames[0] += 1

    server, port = await quic_server(cert, key, count, on_frame, created)
    async with quic_connect(port, cert, count, on_frame, created) as client:
        server_side = next(p for p in created if p is not client)
        await asyncio.sleep(0.05)  # let the handshake's last packets (HANDSHAKE_DONE, tickets) go
        handshake = ByteCount(count.datagrams, count.udp_payload)
        count.datagrams = count.udp_payload = 0
        ticks = max(2, round(seconds * RATE))
        start = monotonic() + 0.02
        send_c, drop_c = datagram_sender(client)
        send_s, drop_s = datagram_sender(server_side)
        await asyncio.gather(_tick(send_c, start, ticks), _tick(send_s, start, ticks))
        await asyncio.sleep(0.05)
        measured = ByteCount(count.datagrams, count.udp_payload)
    server.close()
    payload_bytes = (2 * ticks - drop_c[0] - drop_s[0]) * PAYLOAD_SIZE
    return {
        "samples": 2 * ticks,
        "dropped_at_sender": drop_c[0] + drop_s[0],
        "frames_received": frames[0],
        "datagrams": measured.datagrams,
        "udp_payload_bytes": measured.udp_payload,
        "wire_bytes": measured.wire,
        "wire_per_payload_byte": measured.wire / payload_bytes,
        "udp_per_payload_byte": measured.udp_payload / payload_bytes,
        "datagrams_per_sample": measured.datagrams / (2 * ticks - drop_c[0] - drop_s[0]),
        "handshake_datagrams": handshake.datagrams,
        "handshake_wire_bytes": handshake.wire,
    }


async def _tdtp_1khz(seconds: float) -> Json:
    server = await listen("127.0.0.1", 0)
    master = await connect("127.0.0.1", server.port)
    slave = await server.accept()
    endpoints = (master, slave)
    before = [(ep.stats.sent.bytes, ep.stats.sent.datagrams) for ep in endpoints]
    ticks = max(2, round(seconds * RATE))
    start = monotonic() + 0.02
    await asyncio.gather(_tick(master.send, start, ticks), _tick(slave.send, start, ticks))
    await asyncio.sleep(0.05)
    udp = sum(ep.stats.sent.bytes - b for ep, (b, _) in zip(endpoints, before, strict=True))
    datagrams = sum(
        ep.stats.sent.datagrams - d for ep, (_, d) in zip(endpoints, before, strict=True)
    )
    data_packets = sum(ep.stats.sent.data_packets for ep in endpoints)
    await master.close()
    await server.close()
    payload_bytes = data_packets * PAYLOAD_SIZE
    wire = udp + UDP_IP * datagrams
    return {
        "samples": 2 * ticks,
        "data_packets": data_packets,
        "datagrams": datagrams,
        "udp_payload_bytes": udp,
        "wire_bytes": wire,
        "wire_per_payload_byte": wire / payload_bytes,
        "udp_per_payload_byte": udp / payload_bytes,
        "datagrams_per_sample": datagrams / data_packets,
    }


async def one_khz_pair(seconds: float, cert: bytes, key: bytes) -> tuple[Json, Json]:
    quic, tdtp = await asyncio.gather(_quic_1khz(seconds, cert, key), _tdtp_1khz(seconds))
    return quic, tdtp


# ---------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> int:
    p = common.parser(__doc__, seconds=1.0, repeat=3, help_seconds="window of each measurement")
    args = p.parse_args(argv)
    missing = aioquic_missing() or (None if common.have_uvloop() else "uvloop is not installed")
    if missing is not None:
        print(missing, file=sys.stderr)
        return common.emit("quic_peer", args, [], details={"skipped": missing}, text=missing)
    common.warn_if_loaded()
    cert, key = make_certificate()
    warmup = min(throughput.WARMUP, args.seconds)
    quic_runs: list[Json] = []
    tdtp_runs: list[Json] = []
    quic_1k: list[Json] = []
    tdtp_1k: list[Json] = []
    retrier = common.Retrier(args.repeat)
    for rep in range(args.repeat):
        label = f"rep {rep + 1}/{args.repeat}: QUIC throughput"
        print(f"{label} ...", file=sys.stderr, flush=True)
        quic_runs.append(retrier.run(label, lambda: run_quic_pair(args.seconds, warmup, cert, key)))
        label = f"rep {rep + 1}/{args.repeat}: tdtp throughput"
        print(f"{label} ...", file=sys.stderr, flush=True)
        tdtp_runs.append(
            retrier.run(label, lambda: throughput.run_pair("tdtp-uvloop", args.seconds, warmup))
        )
        print(f"rep {rep + 1}/{args.repeat}: 1 kHz each way ...", file=sys.stderr, flush=True)
        quic, tdtp = common.run_in_loop("uvloop", lambda: one_khz_pair(args.seconds, cert, key))
        quic_1k.append(quic)
        tdtp_1k.append(tdtp)
    q_pairs, t_pairs = common.clean_pairs(quic_runs, tdtp_runs)
    q_rate = [r["rate"] for r in common.clean(quic_runs)]
    t_rate = [r["rate"] for r in common.clean(tdtp_runs)]
    q_wire = [r["wire_per_payload_byte"] for r in quic_1k]
    t_wire = [r["wire_per_payload_byte"] for r in tdtp_1k]
    rows = [
        Row(
            "quic_peer",
            "tdtp uvloop, one way saturated, 100 B, received",
            "pkt/s",
            Stat.of(t_rate),
            baseline="aioquic DATAGRAM frames",
            baseline_value=Stat.of(q_rate),
            ratio=Stat.of(
                common.paired_ratios([r["rate"] for r in t_pairs], [r["rate"] for r in q_pairs])
            ),
            ratio_label="tdtp/QUIC",
            target="none (the alternative)",
            note=common.left_out(quic_runs, tdtp_runs),
        ),
        Row(
            "quic_peer",
            "tdtp wire bytes per payload byte, 1 kHz each way, 100 B",
            "B/B",
            Stat.of(t_wire),
            baseline="aioquic DATAGRAM frames",
            baseline_value=Stat.of(q_wire),
            ratio=Stat.of(common.paired_ratios(t_wire, q_wire)),
            ratio_label="tdtp/QUIC",
            target="none (the alternative)",
            digits=4,
        ),
    ]
    q, t = quic_1k[-1], tdtp_1k[-1]
    lines = [
        "Throughput (medians): "
        f"QUIC {Stat.of(q_rate).median:,.0f} frames/s received (sender queued "
        f"{Stat.of([r['sender_rate'] for r in common.clean(quic_runs)]).median:,.0f}/s, receiver "
        f"CPU {Stat.of([r['rx_cpu_percent'] for r in common.clean(quic_runs)]).median:.0f} %, "
        f"sender CPU {Stat.of([r['tx_cpu_percent'] for r in common.clean(quic_runs)]).median:.0f}"
        " %); tdtp "
        f"{Stat.of(t_rate).median:,.0f} samples/s.",
        "",
        "1 kHz each way, 100 B, last repetition, both directions together:",
        "",
        "| stack | samples offered | samples sent | UDP datagrams | datagrams per sample "
        "| UDP payload bytes | wire bytes | wire B per payload B | UDP B per payload B |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
        f"| QUIC (aioquic) | {q['samples']:,} | {q['samples'] - q['dropped_at_sender']:,} "
        f"| {q['datagrams']:,} | {q['datagrams_per_sample']:.3f} "
        f"| {q['udp_payload_bytes']:,} | {q['wire_bytes']:,} | {q['wire_per_payload_byte']:.4f} "
        f"| {q['udp_per_payload_byte']:.4f} |",
        f"| tdtp | {t['samples']:,} | {t['data_packets']:,} | {t['datagrams']:,} "
        f"| {t['datagrams_per_sample']:.3f} "
        f"| {t['udp_payload_bytes']:,} | {t['wire_bytes']:,} | {t['wire_per_payload_byte']:.4f} "
        f"| {t['udp_per_payload_byte']:.4f} |",
        "",
        f"QUIC's handshake before that: {q['handshake_datagrams']} datagrams, "
        f"{q['handshake_wire_bytes']:,} bytes on the wire "
        "(tdtp's: OPEN, COOKIE, OPEN, OPEN_ACK and a KEEPALIVE, 5 datagrams of 336 bytes unkeyed with "
        "UDP/IPv4; 402 keyed).",
    ]
    details = {
        "throughput": {"quic": quic_runs, "tdtp": tdtp_runs},
        "one_khz": {"quic": quic_1k, "tdtp": tdtp_1k},
    }
    return common.emit("quic_peer", args, rows, details=details, text="\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
