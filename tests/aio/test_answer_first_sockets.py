"""Answer first, on real sockets: a sample sent from ``on_data`` leaves with the acknowledgement it
owes riding on it (no ACK packet of its own), and what the application reads in that callback already
counts the acknowledgement the sample it answers carried."""

from __future__ import annotations

import asyncio
import math

import pytest

from tdtp import ConnectionConfig, DataReceived
from tdtp.aio.api import connect, listen
from tdtp.control.fixed import FixedConfig

CONFIG = ConnectionConfig(controller="fixed", controller_config=FixedConfig(rate=math.inf))
ROUND_TRIPS = 300


@pytest.mark.asyncio
async def test_a_ping_pong_sends_no_ack_packet_and_reads_every_ack_in_the_callback() -> None:
    loop = asyncio.get_running_loop()
    server = await listen("127.0.0.1", 0, config=CONFIG)
    done = loop.create_future()
    unacked_seen: list[int] = []
    answers = 0
    acks_at_end: tuple[int, int] | None = None

    def on_answer(sample: DataReceived) -> None:
        nonlocal answers, acks_at_end
        answers += 1
        stats = client.stats  # read inside the callback: the ACK the answer carried counts
        unacked_seen.append(stats.sent.data_packets - stats.packets_acked)
        if answers == ROUND_TRIPS:
            # Taken here: once the exchange stops, the last answer's ACK is owed on its own.
            acks_at_end = (client.stats.sent.ack_packets, echo.stats.sent.ack_packets)
            if not done.done():
                done.set_result(None)
            return
        client.send(bytes(100))

    client = await connect("127.0.0.1", server.port, config=CONFIG, on_data=on_answer)
    try:
        echo = await server.accept()
        echo.set_data_callback(lambda sample: echo.send(sample.payload))
        acks_before = (client.stats.sent.ack_packets, echo.stats.sent.ack_packets)
        client.send(bytes(100))
        await asyncio.wait_for(done, timeout=30.0)  # a correctness bound, not a timing goal
        # Loopback loses nothing here, so each answer acknowledges the one sample in flight.
        assert echo.stats.dropped == 0 and client.stats.dropped == 0
        assert unacked_seen == [0] * ROUND_TRIPS
        # Both sides always had a sample to carry their ACK: no ACK packet during the exchange.
        assert acks_at_end == acks_before
    finally:
        await client.close()
        await server.close()
