"""User-space instructions per echo: what a datagram costs from the loop's wake-up to its answer.

Usage: ``python benchmarks/instructions.py [--echoes 2000] [--variants raw-uvloop tdtp tdtp-pure]
[--json]`` (needs valgrind: ``apt install valgrind``)

Why. This machine's timings move with its neighbours and with how late the host wakes an idle
virtual CPU: the suite's RTT ratio of tdtp over raw uvloop moved between 1.25 and 1.33 from run to
run with the same code. An instruction count barely does. Valgrind's callgrind runs the echo side
of a ping-pong on a synthetic CPU and counts every user-space instruction it executes; the count
moves by a few per cent at most from run to run (what little depends on timing: a receive that finds
a second datagram, a collection of the cyclic garbage collector), so a change to the per-packet path
shows up as a number, not as a shift in a noisy distribution. Kernel work (the system calls
themselves) is not counted: it is the same for every variant here.

Method. Two processes on loopback: an **echo** under callgrind, which sends back every datagram it
receives, and a **client** outside it, which sends a 100-byte payload, waits for the answer, sends the
next (``--echoes`` round trips). Callgrind counts only inside the loop's callback for the echo's
socket (``--toggle-collect``): everything the echo does for a datagram, from the wake-up's callback to
the answer's system call and the bookkeeping after it, and nothing of the loop's idle turns or the
start-up.

- ``raw-uvloop``: ``DatagramProtocol`` on uvloop answering from ``datagram_received`` with
  ``transport.sendto`` (callback: libuv's ``uv__udp_io``).
- ``tdtp``: ``tdtp.listen`` on uvloop, the echo answering from its ``on_data`` callback with
  ``ep.send``, flow control out of the way (``controller="fixed"``, ``rate=inf``), as in
  ``latency.py``; the compiled build on the batched datagram layer (callback: uvloop's poll handler,
  which calls the layer's C engine).
- ``tdtp-pure``: the same on the pure-Python build (``TDTP_PURE_PYTHON=1``: the datagram layer's
  Python engine).

Reported: instructions per echo, counted over the echoes after a warm-up tenth (``ZERO_MARK``), and
tdtp's over raw uvloop's.
"""

from __future__ import annotations

import asyncio
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tdtp import ConnectionConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _common as common
from _common import Json, Row, Stat

VARIANTS = ("raw-uvloop", "tdtp", "tdtp-pure")
ENTRIES = ("uv__udp_io", "__pyx_f_6uvloop_4loop___on_uvpoll_event")
"""The loop's callbacks for a socket: libuv's for a UDP handle (raw uvloop, and tdtp on the loop's
own transport) and uvloop's for a polled descriptor (tdtp's datagram layer, whose reader is
registered with the loop). Callgrind counts inside them only."""
ZERO_MARK = "getppid"
"""The echo calls ``os.getppid()`` (nothing else on its path does) once the warm-up echoes are done:
callgrind zeroes its counts there (``--zero-before``), so first-use costs (imports on first call,
caches filling, the opening handshake) stay out of the figure."""
PAYLOAD = bytes(100)
CLIENT_TIMEOUT = 600.0


class UsageError(Exception):
    """A command-line mistake: one line on stderr, exit status 2."""


# ---------------------------------------------------------------------------- the two sides


async def _echo(variant: str, port_file: Path, echoes: int) -> None:
    loop = asyncio.get_running_loop()
    done: asyncio.Future[None] = loop.create_future()
    count = 0
    warm = warmup(echoes)

    def counted() -> None:
        nonlocal count
        count += 1
        if count == warm:
            os.getppid()  # callgrind zeroes its counts here (ZERO_MARK)
        if count >= echoes and not done.done():
            done.set_result(None)

    if variant == "raw-uvloop":

        class Echo(asyncio.DatagramProtocol):
            def connection_made(self, transport: asyncio.BaseTransport) -> None:
                self.transport = transport

            def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
                self.transport.sendto(data, addr)  # type: ignore[attr-defined]
                counted()

        transport, _ = await loop.create_datagram_endpoint(Echo, local_addr=("127.0.0.1", 0))
        port = transport.get_extra_info("sockname")[1]
        _publish(port_file, port)
        await done
        transport.close()
        return
    from tdtp import DataReceived  # noqa: PLC0415 - after TDTP_PURE_PYTHON is set
    from tdtp.aio.api import listen  # noqa: PLC0415

    async with await listen("127.0.0.1", 0, config=_unlimited()) as server:
        _publish(port_file, server.port)
        endpoint = await server.accept()

        def echo(sample: DataReceived) -> None:
            endpoint.send(sample.payload)
            counted()

        endpoint.set_data_callback(echo)
        await done
        await asyncio.sleep(0.05)  # the last answer leaves before the session closes


async def _client(variant: str, port_file: Path, echoes: int) -> None:
    deadline = time.monotonic() + CLIENT_TIMEOUT
    while not port_file.exists():  # the echo starts slowly under callgrind
        if time.monotonic() > deadline:
            raise TimeoutError("the echo never started")
        await asyncio.sleep(0.05)
    port = int(port_file.read_text())
    loop = asyncio.get_running_loop()
    done: asyncio.Future[None] = loop.create_future()
    answered = 0
    send: Callable[[bytes], object]

    def answer() -> None:
        nonlocal answered
        answered += 1
        if answered >= echoes:
            if not done.done():
                done.set_result(None)
            return
        send(PAYLOAD)

    if variant == "raw-uvloop":

        class Client(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
                answer()

        transport, _ = await loop.create_datagram_endpoint(Client, remote_addr=("127.0.0.1", port))
        send = transport.sendto
        transport.sendto(PAYLOAD)
        await asyncio.wait_for(done, CLIENT_TIMEOUT)
        transport.close()
        return
    from tdtp.aio.api import connect  # noqa: PLC0415

    endpoint = await connect(
        "127.0.0.1", port, config=_unlimited(), on_data=lambda _sample: answer()
    )
    send = endpoint.send
    send(PAYLOAD)
    await asyncio.wait_for(done, CLIENT_TIMEOUT)
    await endpoint.close()


def warmup(echoes: int) -> int:
    """Echoes before the counts start: a tenth, at least 20."""
    return max(20, echoes // 10)


def _unlimited() -> ConnectionConfig:
    from tdtp import ConnectionConfig  # noqa: PLC0415 - after TDTP_PURE_PYTHON is set
    from tdtp.control.fixed import FixedConfig  # noqa: PLC0415

    return ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))


def _publish(port_file: Path, port: int) -> None:
    part = port_file.with_suffix(".part")
    part.write_text(str(port))
    part.rename(port_file)


def _run_side(side: str, variant: str, port_file: Path, echoes: int) -> int:
    import uvloop  # noqa: PLC0415

    main = _echo if side == "echo" else _client
    uvloop.run(main(variant, port_file, echoes))
    return 0


# ---------------------------------------------------------------------------- measuring


def collected(callgrind_out: Path) -> int:
    """The instructions a callgrind output file counted (its ``totals:`` or ``summary:`` line)."""
    text = callgrind_out.read_text(errors="replace")
    match = re.search(r"^(?:totals|summary):\s+(\d+)", text, re.M)
    if match is None:
        raise RuntimeError(f"{callgrind_out.name}: no instruction total in callgrind's output")
    return int(match.group(1))


def measure(variant: str, echoes: int, valgrind: str) -> float:
    """Instructions per echo of one variant."""
    env = dict(os.environ)
    env.pop(common.PURE_ENV, None)
    if variant == "tdtp-pure":
        env[common.PURE_ENV] = "1"
    me = str(Path(__file__).resolve())
    with tempfile.TemporaryDirectory(prefix="tdtp-instructions-") as tmp:
        port_file = Path(tmp) / "port"
        out = Path(tmp) / "callgrind.out"
        side = [me, "--side", "echo", variant, str(port_file), str(echoes)]
        echo = subprocess.Popen(
            [
                valgrind,
                "--tool=callgrind",
                f"--callgrind-out-file={out}",
                *(f"--toggle-collect={entry}" for entry in ENTRIES),
                f"--zero-before={ZERO_MARK}",
                sys.executable,
                *side,
            ],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        client = subprocess.run(
            [sys.executable, me, "--side", "client", variant, str(port_file), str(echoes)],
            env=env,
            capture_output=True,
            text=True,
            timeout=CLIENT_TIMEOUT + 60,
            check=False,
        )
        try:
            _, stderr = echo.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            echo.kill()
            raise RuntimeError(f"{variant}: the echo under callgrind did not finish") from None
        if client.returncode != 0 or echo.returncode != 0:
            tail = (client.stderr or stderr or "").strip().splitlines()[-3:]
            raise RuntimeError(f"{variant}: a side failed: {' | '.join(tail)}")
        return collected(out) / (echoes - warmup(echoes))


def rows_of(per_echo: dict[str, float], echoes: int) -> list[Row]:
    rows = []
    raw = per_echo.get("raw-uvloop")
    for variant, value in per_echo.items():
        label = {
            "raw-uvloop": "raw uvloop DatagramProtocol",
            "tdtp": "tdtp uvloop, compiled build",
            "tdtp-pure": "tdtp uvloop, pure-Python build",
        }[variant]
        row = Row(
            "instructions",
            f"{label}, user-space instructions per echo (wake-up to answer and after), "
            f"100 B, {echoes:,} echoes",
            "instr",
            Stat.of([value]),
            digits=0,
        )
        if variant != "raw-uvloop" and raw:
            row.baseline = "raw uvloop"
            row.baseline_value = Stat.of([raw])
            row.ratio = Stat.of([value / raw])
            row.ratio_label = "tdtp/raw"
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    args_list = sys.argv[1:] if argv is None else argv
    if args_list[:1] == ["--side"]:  # one side of the ping-pong (the echo runs under callgrind)
        side, variant, port_file, echoes = args_list[1:5]
        return _run_side(side, variant, Path(port_file), int(echoes))
    doc = __doc__ or ""
    p = common.OneLineParser(prog="instructions.py", description=doc.splitlines()[0])
    p.add_argument("--echoes", type=int, default=2000, help="round trips per variant (2000)")
    p.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS))
    p.add_argument("--json", action="store_true", help="one JSON report on stdout")
    args = p.parse_args(args_list)
    args.seconds, args.repeat = 0.0, 1  # (what every report carries; a count needs neither)
    try:
        if args.echoes < 100:
            raise UsageError("--echoes must be at least 100 (the first tenth warms up)")
        valgrind = shutil.which("valgrind")
        if valgrind is None:
            raise UsageError("valgrind is not installed (Debian: apt install valgrind)")
    except UsageError as exc:
        print(f"instructions.py: {exc}", file=sys.stderr)
        return 2
    per_echo: dict[str, float] = {}
    for variant in args.variants:
        print(f"  {variant}: {args.echoes} echoes under callgrind ...", file=sys.stderr, flush=True)
        per_echo[variant] = measure(variant, args.echoes, valgrind)
    details: Json = {
        "echoes": args.echoes,
        "warmup": warmup(args.echoes),
        "per_echo": per_echo,
        "entries": ENTRIES,
    }
    text = (
        "User-space instructions the echo side of a ping-pong executes per datagram, counted by "
        "callgrind inside the loop's callback for its socket (from the wake-up to the answer's "
        "system call and the bookkeeping after it). Within a few per cent from run to run, "
        "unlike the timings of this shared machine."
    )
    return common.emit(
        "instructions", args, rows_of(per_echo, args.echoes), details=details, text=text
    )


if __name__ == "__main__":
    raise SystemExit(main())
