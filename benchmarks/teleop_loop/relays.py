"""The impairing relays in front of the transports that have no in-process netem, as worker processes.

* ``udp``: :func:`tdtp.aio.relay.start_relay`, the relay ``tdtp netem-relay`` runs, with the profile's
  spec both ways (each way its own seed);
* ``tcp``: :mod:`teleop_loop.tcp_link`, the same spec applied per TCP segment.

Protocol with the parent (a :func:`_common.start_worker` pipe): the worker sends ``{"port": N}`` when
it listens; then each ``"count"`` is answered with the datagrams (segments) that have entered each
way so far, and ``"stop"`` with the final counts, after which the worker exits.
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing.connection
from collections.abc import Callable
from typing import Any

from tdtp.aio.relay import start_relay

from teleop_loop import tcp_link

Counts = Callable[[], dict[str, Any]]


async def _serve_commands(conn: multiprocessing.connection.Connection, counts: Counts) -> None:
    while True:
        command = await asyncio.to_thread(conn.recv)
        conn.send(counts())
        if command == "stop":
            return


def udp_relay(
    conn: multiprocessing.connection.Connection, forward_port: int, spec: str, seed: int
) -> None:
    async def main() -> None:
        relay = await start_relay(("127.0.0.1", 0), ("127.0.0.1", forward_port), spec, seed=seed)

        def counts() -> dict[str, Any]:
            fwd, back = relay.forward.link.stats, relay.back.link.stats
            return {
                "forward": {"sent": fwd.sent, "lost": fwd.lost, "queue_dropped": fwd.queue_dropped},
                "return": {
                    "sent": back.sent,
                    "lost": back.lost,
                    "queue_dropped": back.queue_dropped,
                },
            }

        conn.send({"port": relay.address[1]})
        try:
            await _serve_commands(conn, counts)
        finally:
            await relay.close()

    asyncio.run(main())


def tcp_relay(
    conn: multiprocessing.connection.Connection, forward_port: int, spec: str, seed: int
) -> None:
    async def main() -> None:
        loop = asyncio.get_running_loop()
        ready: asyncio.Future[int] = loop.create_future()
        to_slave, to_master = tcp_link.paths(spec, seed)
        task = loop.create_task(tcp_link.serve(forward_port, (to_slave, to_master), ready))

        def counts() -> dict[str, Any]:
            return {"forward": _tcp_counts(to_slave), "return": _tcp_counts(to_master)}

        conn.send({"port": await ready})
        try:
            await _serve_commands(conn, counts)
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    asyncio.run(main())


def _tcp_counts(path: tcp_link.TcpPath) -> dict[str, int]:
    return {
        "sent": path.stats.segments,
        "retransmissions": path.stats.retransmissions,
        "lost": path.link.stats.lost,
        "queue_dropped": path.link.stats.queue_dropped,
    }


RELAYS = {"udp-relay": udp_relay, "tcp-relay": tcp_relay}
