"""Packets per second through the datagram layer (tdtp.aio.datagram) against raw uvloop and the kernel.

Usage: ``python benchmarks/datagram.py [--seconds 1] [--repeat 3] [--json] [--variants NAME ...]``

Method. Every variant is a pair of peers on 127.0.0.1, each its own process pinned to its own CPU,
100-byte payloads, each socket bound to a port the coordinator picked and connected to the other's.
**One way**: the first peer sends as fast as it can, the second counts what arrives. **Both ways**:
each does both. The figure is the receive rate, datagrams the receiving code saw per second over a
window of ``--seconds`` that opens 0.3 s after the first one arrived (both ways: the sum of both
directions). A sender faster than its receiver overflows the receive buffer (the kernel default, the
same for every variant): the receive rate is what the pair carries. Beside it, each side's CPU time
(``getrusage``) per packet handled in the window; the larger is the pair's bottleneck.

Variants, interleaved (repetition i runs each once):

- ``raw uvloop`` (the baseline of the ratios): ``DatagramProtocol`` on uvloop, 64 ``transport.sendto``
  then ``await asyncio.sleep(0)``; a counter in ``datagram_received``. No batching.
- ``layer C``: :func:`tdtp.aio.datagram.open_datagram_endpoint` on uvloop, compiled engine: one
  ``send_batch`` of 64 (one ``sendmmsg``) then ``await asyncio.sleep(0)``; the receive callback adds
  ``len(datagrams)`` per ``recvmmsg`` batch (64). Coalescing, as by default: the 64 leave as one
  ``UDP_SEGMENT`` message and arrive as one ``UDP_GRO`` buffer that the engine cuts back into 64.
- ``layer C, coalesce=False``: the same, one message per datagram each way.
- ``layer pure``: the same with ``engine="pure"`` (``recvfrom``/``sendto`` per datagram, one
  callback per batch).
- ``C limit``: a C program written for this benchmark (the source is in this file), compiled with the
  system's ``cc -O2`` into a temporary directory at run time: blocking ``sendmmsg`` of 64 in a loop,
  and ``recvmmsg`` of 64 (both ways: non-blocking, alternating). No Python, no event loop: what this
  machine's kernel carries, the physical limit the others are measured against. ``C limit,
  UDP_SEGMENT + UDP_GRO``: the same program sending the 64 as one segmented message and receiving
  with ``UDP_GRO``: the limit of the coalescing layer (its ratio is taken against this one).

This measures the I/O layer alone, not tdtp's protocol (throughput.py and latency.py measure tdtp on
it: its endpoints run on the layer by default where the C engine is built).
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat

BATCH = 64
PAYLOAD = b"\x5a" * 100
WARMUP = 0.3
VARIANTS: dict[str, tuple[str, bool]] = {
    "raw-uvloop": ("raw", False),
    "layer-c": ("compiled", False),
    "layer-c-plain": ("compiled-plain", False),
    "layer-pure": ("pure", False),
    "c-limit": ("c", False),
    "c-limit-seg": ("c-seg", False),
    "raw-uvloop-both": ("raw", True),
    "layer-c-both": ("compiled", True),
    "layer-c-plain-both": ("compiled-plain", True),
    "layer-pure-both": ("pure", True),
    "c-limit-both": ("c", True),
    "c-limit-seg-both": ("c-seg", True),
}
LABELS = {
    "raw-uvloop": "raw uvloop DatagramProtocol, one way",
    "layer-c": "datagram layer, C engine, coalescing (uvloop), one way",
    "layer-c-plain": "datagram layer, C engine, coalesce=False (uvloop), one way",
    "layer-pure": "datagram layer, pure engine (uvloop), one way",
    "c-limit": "C recvmmsg/sendmmsg (no Python), one way",
    "c-limit-seg": "C recvmmsg/sendmmsg, UDP_SEGMENT + UDP_GRO (no Python), one way",
    "raw-uvloop-both": "raw uvloop DatagramProtocol, both ways",
    "layer-c-both": "datagram layer, C engine, coalescing (uvloop), both ways",
    "layer-c-plain-both": "datagram layer, C engine, coalesce=False (uvloop), both ways",
    "layer-pure-both": "datagram layer, pure engine (uvloop), both ways",
    "c-limit-both": "C recvmmsg/sendmmsg (no Python), both ways",
    "c-limit-seg-both": "C recvmmsg/sendmmsg, UDP_SEGMENT + UDP_GRO (no Python), both ways",
}
C_IMPLS = ("c", "c-seg")

C_PEER = r"""
/* The kernel's limit for this benchmark: a UDP peer with recvmmsg/sendmmsg and nothing else.
 * usage: peer CPU LOCAL_PORT REMOTE_PORT SEND RECV WARMUP SECONDS SEGMENT
 * SEGMENT 1: the 64 datagrams of a send are one message with UDP_SEGMENT, and the socket receives
 * with UDP_GRO (a coalesced buffer counts as the datagrams it holds).
 * Prints one JSON line: received in the window, window length, sent, CPU seconds in the window. */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <time.h>
#define B 64
#ifndef SOL_UDP
#define SOL_UDP 17
#endif
#define UDP_SEGMENT_OPT 103
#define UDP_GRO_OPT 104
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + t.tv_nsec / 1e9; }
static double cpu(void) { struct rusage u; getrusage(RUSAGE_SELF, &u);
    return u.ru_utime.tv_sec + u.ru_utime.tv_usec / 1e6 + u.ru_stime.tv_sec + u.ru_stime.tv_usec / 1e6; }
int main(int argc, char **argv) {
    if (argc != 9) return 2;
    int cpu_id = atoi(argv[1]), lport = atoi(argv[2]), rport = atoi(argv[3]);
    int do_send = atoi(argv[4]), do_recv = atoi(argv[5]);
    double warmup = atof(argv[6]), seconds = atof(argv[7]);
    int segment = atoi(argv[8]);
    if (cpu_id >= 0) { cpu_set_t s; CPU_ZERO(&s); CPU_SET(cpu_id, &s); sched_setaffinity(0, sizeof(s), &s); }
    int fd = socket(AF_INET, SOCK_DGRAM, 0);
    struct sockaddr_in a = {0}; a.sin_family = AF_INET; a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = htons(lport); if (bind(fd, (void *)&a, sizeof(a))) return 3;
    a.sin_port = htons(rport); if (connect(fd, (void *)&a, sizeof(a))) return 4;
    struct timeval tv = {0, 200000}; setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
    static char out[100], in[B][65536], rc[B][64], sc[64]; memset(out, 0x5a, sizeof(out));
    struct mmsghdr sm[B], rm[B]; struct iovec si[B], ri[B];
    memset(sm, 0, sizeof(sm)); memset(rm, 0, sizeof(rm));
    for (int i = 0; i < B; i++) {
        si[i].iov_base = out; si[i].iov_len = sizeof(out); sm[i].msg_hdr.msg_iov = &si[i]; sm[i].msg_hdr.msg_iovlen = 1;
        ri[i].iov_base = in[i]; ri[i].iov_len = segment ? sizeof(in[i]) : 2048; rm[i].msg_hdr.msg_iov = &ri[i]; rm[i].msg_hdr.msg_iovlen = 1;
    }
    int sends = B;
    if (segment) {
        int on = 1; setsockopt(fd, SOL_UDP, UDP_GRO_OPT, &on, sizeof(on));
        sm[0].msg_hdr.msg_iovlen = B; sm[0].msg_hdr.msg_control = sc;
        sm[0].msg_hdr.msg_controllen = CMSG_SPACE(sizeof(unsigned short));
        struct cmsghdr *cm = CMSG_FIRSTHDR(&sm[0].msg_hdr);
        cm->cmsg_level = SOL_UDP; cm->cmsg_type = UDP_SEGMENT_OPT; cm->cmsg_len = CMSG_LEN(sizeof(unsigned short));
        unsigned short gso = sizeof(out); memcpy(CMSG_DATA(cm), &gso, sizeof(gso));
        sends = 1;
    }
    long long received = 0, sent = 0, win_rx = 0, win_tx = 0; double start = now(), first = -1, t0 = -1, c0 = 0, t1 = -1, c1 = 0;
    double cap = warmup + seconds + 30;
    int flags = (do_send && do_recv) ? MSG_DONTWAIT : 0;
    for (;;) {
        double t = now();
        if (t - start > cap) break;
        if (do_send) { int n = sendmmsg(fd, sm, sends, flags); if (n > 0) sent += segment ? (long long)n * B : n; }
        if (do_recv) {
            for (int i = 0; i < B; i++) { rm[i].msg_hdr.msg_control = rc[i]; rm[i].msg_hdr.msg_controllen = segment ? sizeof(rc[i]) : 0; }
            int n = recvmmsg(fd, rm, B, flags ? MSG_DONTWAIT : MSG_WAITFORONE, NULL);
            if (n > 0) {
                for (int i = 0; i < n; i++) {
                    int seg = 0;
                    if (segment)
                        for (struct cmsghdr *cm = CMSG_FIRSTHDR(&rm[i].msg_hdr); cm; cm = CMSG_NXTHDR(&rm[i].msg_hdr, cm))
                            if (cm->cmsg_level == SOL_UDP && cm->cmsg_type == UDP_GRO_OPT) memcpy(&seg, CMSG_DATA(cm), sizeof(int));
                    received += seg > 0 ? (rm[i].msg_len + seg - 1) / seg : 1;
                }
                if (first < 0) first = t;
            }
        }
        if (first >= 0 && t0 < 0 && t - first >= warmup) { t0 = t; c0 = cpu(); win_rx = received; win_tx = sent; }
        if (t0 >= 0 && t - t0 >= seconds) { t1 = t; c1 = cpu(); break; }
        if (!do_recv && t - start > warmup + seconds + 1.5) break;
    }
    if (t1 < 0) { t1 = now(); c1 = cpu(); if (t0 < 0) { t0 = start; } }
    printf("{\"received\": %lld, \"sent\": %lld, \"elapsed\": %.6f, \"cpu\": %.6f}\n",
           received - win_rx, sent - win_tx, t1 - t0, c1 - c0);
    return 0;
}
"""


def _free_ports() -> tuple[int, int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return socks[0].getsockname()[1], socks[1].getsockname()[1]
    finally:
        for s in socks:
            s.close()


# ---------------------------------------------------------------------------- Python peers


class Counter:
    def __init__(self) -> None:
        self.received = 0
        self.sent = 0


async def _python_peer(
    ready: Any,
    impl: str,
    lport: int,
    rport: int,
    send: bool,
    recv: bool,
    warmup: float,
    seconds: float,
) -> Json:
    loop = asyncio.get_running_loop()
    count = Counter()
    cap = warmup + seconds + 30.0
    closer: Any
    if impl == "raw":

        class Proto(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: Any) -> None:
                count.received += 1

        transport, _ = await loop.create_datagram_endpoint(
            Proto, local_addr=("127.0.0.1", lport), remote_addr=("127.0.0.1", rport)
        )
        sendto = transport.sendto

        def burst() -> None:
            for _ in range(BATCH):
                sendto(PAYLOAD)
            count.sent += BATCH

        closer = transport.close
    else:
        from tdtp.aio.datagram import open_datagram_endpoint  # noqa: PLC0415

        def on_receive(datas: list[bytes], *_: object) -> None:
            count.received += len(datas)

        layer = await open_datagram_endpoint(
            on_receive,
            local_addr=("127.0.0.1", lport),
            remote_addr=("127.0.0.1", rport),
            engine="pure" if impl == "pure" else "compiled",
            batch=BATCH,
            coalesce=impl == "compiled",
        )
        items: list[tuple[bytes, Any]] = [(PAYLOAD, None)] * BATCH
        send_batch = layer.send_batch

        def burst() -> None:
            count.sent += send_batch(items)

        closer = layer.close

    async def blast() -> None:
        end = time.monotonic() + (cap if recv else warmup + seconds + 1.5)
        while time.monotonic() < end:
            burst()
            await asyncio.sleep(0)

    ready()
    task = asyncio.create_task(blast()) if send else None
    report: Json = {}
    if recv:
        while count.received == 0:
            await asyncio.sleep(0.002)
        await asyncio.sleep(warmup)
        n0, s0, t0, c0 = count.received, count.sent, time.monotonic(), common.cpu_seconds()
        await asyncio.sleep(seconds)
        n1, s1, t1, c1 = count.received, count.sent, time.monotonic(), common.cpu_seconds()
        report = {"received": n1 - n0, "sent": s1 - s0, "elapsed": t1 - t0, "cpu": c1 - c0}
        if task is not None:
            task.cancel()
    elif task is not None:
        t0, c0 = time.monotonic(), common.cpu_seconds()
        await task
        report = {
            "received": 0,
            "sent": count.sent,
            "elapsed": time.monotonic() - t0,
            "cpu": common.cpu_seconds() - c0,
        }
    closer()
    return report


def python_worker(conn: Any, *, impl: str, cpu_slot: int, **kwargs: Any) -> None:
    common.pin_to_cpu(cpu_slot)
    report = common.run_in_loop(
        "uvloop", lambda: _python_peer(lambda: conn.send({"ready": True}), impl, **kwargs)
    )
    conn.send({"final": report})


# ---------------------------------------------------------------------------- coordinator


def _compile_c_peer(workdir: Path) -> Path | None:
    return common.compile_c(C_PEER, workdir, "peer")


def _per_packet(r: Json) -> float:
    handled = r["received"] + r["sent"]
    return 1e6 * r["cpu"] / handled if handled else float("nan")


def run_pair(variant: str, seconds: float, binary: Path | None) -> Json:
    impl, both = VARIANTS[variant]
    a_port, b_port = _free_ports()
    others = common.OthersMeter()
    cpus = common.usable_cpus()
    sides = [(a_port, b_port, True, both), (b_port, a_port, both, True)]  # (sender, receiver)
    if impl in C_IMPLS:
        assert binary is not None
        procs: list[subprocess.Popen[str]] = []
        for slot, (lp, rp, send, recv) in reversed(list(enumerate(sides))):  # receiver first
            cpu = cpus[slot % len(cpus)] if len(cpus) >= 2 else -1
            args = [str(binary), str(cpu), str(lp), str(rp), str(int(send)), str(int(recv))]
            procs.append(
                subprocess.Popen(
                    [*args, str(WARMUP), str(seconds), str(int(impl == "c-seg"))],
                    stdout=subprocess.PIPE,
                    text=True,
                )
            )
            time.sleep(0.1)
        reports = [json.loads(p.communicate(timeout=60 + seconds)[0]) for p in procs]
        reports.reverse()  # started receiver first: back to side order
    else:
        handles: list[common.WorkerHandle] = []
        try:
            for slot, (lp, rp, send, recv) in reversed(list(enumerate(sides))):  # receiver first
                handles.append(
                    common.start_worker(
                        f"{variant}-{slot}",
                        python_worker,
                        impl=impl,
                        cpu_slot=slot,
                        lport=lp,
                        rport=rp,
                        send=send,
                        recv=recv,
                        warmup=WARMUP,
                        seconds=seconds,
                    )
                )
                handles[-1].recv(60)  # bound: "ready"
            reports = [h.recv(60 + seconds)["final"] for h in handles]
            reports.reverse()
        finally:
            for h in handles:
                h.finish()
    receivers = [r for r, side in zip(reports, sides, strict=True) if side[3]]
    rate = sum(r["received"] / r["elapsed"] for r in receivers)
    return {
        "variant": variant,
        "rate": rate,
        "bottleneck_us": max(_per_packet(r) for r in reports),
        "reports": reports,
        "others_percent": others.percent(),
    }


def build_rows(runs: dict[str, list[Json]]) -> list[Row]:
    rows: list[Row] = []
    for variant, results in runs.items():
        both = VARIANTS[variant][1]
        base = "raw-uvloop-both" if both else "raw-uvloop"
        limit = ("c-limit-seg" if VARIANTS[variant][0] == "compiled" else "c-limit") + (
            "-both" if both else ""
        )
        good = common.clean(results)
        row = Row("datagram", LABELS[variant], "pkt/s", Stat.of([r["rate"] for r in good]))
        row.note = common.left_out(results)
        rows.append(row)
        for other, label in ((base, "x raw uvloop"), (limit, "x C limit")):
            if other == variant or not runs.get(other):
                continue
            mine, theirs = common.clean_pairs(results, runs[other])
            extra = Row(
                "datagram",
                f"{LABELS[variant]}: against {LABELS[other]}",
                "pkt/s",
                row.value,
                baseline=LABELS[other],
                baseline_value=Stat.of([r["rate"] for r in common.clean(runs[other])]),
                ratio=Stat.of(
                    common.paired_ratios([r["rate"] for r in mine], [r["rate"] for r in theirs])
                ),
                ratio_label=label,
            )
            rows.append(extra)
        rows.append(
            Row(
                "datagram",
                f"{LABELS[variant]}: bottleneck CPU per packet handled",
                "us",
                Stat.of([r["bottleneck_us"] for r in good]),
                digits=2,
            )
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    p = common.parser(__doc__, seconds=1.0, repeat=3, help_seconds="measurement window per run")
    p.add_argument("--variants", nargs="+", choices=sorted(VARIANTS), help="run only these")
    args = p.parse_args(argv)
    common.warn_if_loaded()
    variants = args.variants or list(VARIANTS)
    if not common.have_uvloop():
        print("uvloop is not installed: skipping the Python variants", file=sys.stderr)
        variants = [v for v in variants if VARIANTS[v][0] in C_IMPLS]
    from tdtp.aio.datagram import datagram_build_info  # noqa: PLC0415

    if not datagram_build_info().compiled:
        print(
            f"datagram layer: {datagram_build_info().describe()}: no C engine rows", file=sys.stderr
        )
        variants = [v for v in variants if not VARIANTS[v][0].startswith("compiled")]
    with tempfile.TemporaryDirectory(prefix="tdtp-dgbench-") as tmp:
        binary = (
            _compile_c_peer(Path(tmp)) if any(VARIANTS[v][0] in C_IMPLS for v in variants) else None
        )
        if binary is None:
            variants = [v for v in variants if VARIANTS[v][0] not in C_IMPLS]
        runs = common.Retrier(args.repeat).interleaved(
            args.repeat, variants, LABELS.__getitem__, lambda v: run_pair(v, args.seconds, binary)
        )
    rows = build_rows(runs)
    others = max((r["others_percent"] for rs in runs.values() for r in rs), default=0.0)
    text = (
        f"Other tenants used at most {others:.0f} % of a core during a run; load average at the end "
        f"{os.getloadavg()[0]:.2f}."
    )
    return common.emit("datagram", args, rows, details={"runs": runs}, text=text)


if __name__ == "__main__":
    sys.exit(main())
