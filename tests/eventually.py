"""Waiting on real sockets for something the run itself will record (a correctness bound, not a
timing goal: the patience only trips on a bug)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

PATIENCE = 10.0


async def eventually(condition: Callable[[], bool], within: float = PATIENCE) -> None:
    """Return once ``condition()`` holds; fail after ``within`` seconds of patience."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + within
    while not condition():
        if loop.time() > deadline:
            raise AssertionError("condition not reached within the patience window")
        await asyncio.sleep(0.005)
