"""A server with several masters and datagrams from addresses it does not know (PROTOCOL.md 5.1,
issue 14, points 5 and 6), on real loopback sockets."""

from __future__ import annotations

import asyncio
import socket

import pytest

from tdtp.aio.api import connect, listen
from tdtp.wire import ControlCode, OpenBody, PacketType, encode_header, encode_open
from tdtp.wire.control import PROTOCOL_VERSION

NONCE = bytes(range(16))


def _open(max_payload: int = 1200, nonce: bytes = NONCE) -> bytes:
    return encode_header(PacketType.CONTROL, 7, 0, 0, 255) + encode_open(
        OpenBody(PROTOCOL_VERSION, 0, 0, max_payload, 0, nonce, bytes(8), bytes(16))
    )


async def _recv(sock: socket.socket) -> bytes:
    loop = asyncio.get_running_loop()
    return await asyncio.wait_for(loop.sock_recv(sock, 2048), 5.0)


@pytest.mark.asyncio
async def test_an_unknown_address_gets_state_only_through_an_admitted_open() -> None:
    async with (
        await listen("127.0.0.1", 0) as server,
        await connect("127.0.0.1", server.port) as master,
    ):
        slave = await server.accept()
        admission = server.stats.admission
        opens, cookies, admitted = admission.opens, admission.cookies_sent, admission.admitted
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger:
            stranger.setblocking(False)
            stranger.connect(("127.0.0.1", server.port))
            stranger.send(encode_header(PacketType.DATA, 1, 0, 0, 255) + b"command")  # unattached
            stranger.send(encode_header(PacketType.ACK, 1, 0, 0, 0))  # unattached
            stranger.send(_open(max_payload=0))  # admission: bad_control, no answer
            stranger.send(_open())  # admission: no cookie yet, answered with a COOKIE
            # Loopback keeps the order and the server handles datagrams in order: the first
            # answer being the COOKIE means nothing answered the three before it.
            reply = await _recv(stranger)
        assert reply[0] >> 6 == PacketType.CONTROL and reply[5] == ControlCode.COOKIE
        assert len(reply) == 39
        assert server.stats.datagrams_unattached == 2
        assert admission.drops == {"bad_control": 1}  # dropped without an answer
        assert admission.opens == opens + 2
        assert (admission.cookies_sent, admission.admitted) == (cookies + 1, admitted)
        assert server.endpoints == [slave]  # nothing kept for the stranger
        # From the master's own address, the OPEN reaches its session, and admission drops it.
        master._transport.sendto(
            _open(max_payload=0, nonce=slave.connection._handshake.master_nonce)
        )
        for _ in range(500):
            if slave.stats.drops.get("bad_control"):
                break
            await asyncio.sleep(0.01)
        assert slave.stats.drops == {"bad_control": 1}
        assert server.stats.datagrams_unattached == 2
