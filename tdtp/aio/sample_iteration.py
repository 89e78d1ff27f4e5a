"""``async for`` over an endpoint's samples, until the association ends.

Kept apart from :mod:`tdtp.aio.endpoint` because that module is compiled with mypyc, which does not
compile asynchronous generators.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable
from typing import TypeVar

from tdtp.errors import EndpointClosedError

_Item = TypeVar("_Item")  # a sample (DataReceived) or a control message (ControlReceived)


async def samples_until_closed(
    read: Callable[[], Awaitable[_Item]],
) -> AsyncIterator[_Item]:
    """Yield ``await read()`` until it raises :class:`~tdtp.errors.EndpointClosedError`."""
    while True:
        try:
            sample = await read()
        except EndpointClosedError:
            return
        yield sample
