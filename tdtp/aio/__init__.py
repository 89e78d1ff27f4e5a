"""The asyncio layer of tdtp: drives the sans-IO :class:`~tdtp.Connection` over real sockets.

Runs on the stock event loop and on uvloop. :mod:`tdtp.aio.timer` holds the precise one-shot
deadline timer that paces data packets at 1 kHz (a Linux ``timerfd`` read through
``loop.add_reader``, with a portable ``loop.call_at`` fallback).
"""

from tdtp.aio.api import ConnectError, Opener, Server, ServerStats, connect, listen
from tdtp.aio.endpoint import Endpoint, EndpointClosedError
from tdtp.aio.ticker import Ticker
from tdtp.aio.timer import DeadlineTimer, create_timer, monotonic

__all__ = [
    "ConnectError",
    "DeadlineTimer",
    "Endpoint",
    "EndpointClosedError",
    "Opener",
    "Server",
    "ServerStats",
    "Ticker",
    "connect",
    "create_timer",
    "listen",
    "monotonic",
]
