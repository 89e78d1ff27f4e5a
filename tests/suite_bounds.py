"""Every test ends: a bound on each asyncio test that works on both event loops, and a last resort.

A hung test must fail with its name within a bound instead of spending CI's whole time limit. Two
layers, because one is not enough:

* **Async tests** (the real-socket tests) run inside ``asyncio.timeout(async_test_timeout)``, set
  here around the test's coroutine before pytest-asyncio runs it. When it expires, the test's task
  is cancelled at the ``await`` it hung on (so the traceback shows where), its ``async with``
  blocks close their sockets, and the test fails with its name and the bound. This works on uvloop
  too, where pytest-timeout's ``signal`` method does not: the exception its SIGALRM handler raises
  is swallowed inside uvloop's loop, and a test once waited 14 minutes at an ``await``.
* **Everything else** (a loop blocked by synchronous code, a sync test stuck in a call) is caught by
  pytest-timeout with ``timeout_method = "thread"`` (pyproject.toml): a watchdog thread dumps every
  thread's stack, the hung test's frames among them, and ends the process; pytest-xdist reports the
  test as failed ("worker crashed") and goes on with a fresh worker.

``tests/test_suite_bounds.py`` proves both in a subprocess, on both loops, with hangs made on purpose.
"""

from __future__ import annotations

import asyncio
import functools
import inspect
from collections.abc import Callable, Coroutine
from typing import Any

import pytest

DEFAULT_ASYNC_TEST_TIMEOUT = 60.0
"""Seconds an asyncio test may take. Real-socket tests finish in seconds even with both cores
busy; this only trips on a hang. It is half of pytest-timeout's bound (pyproject.toml), so an async
hang is reported by the gentler layer, with the await it hung at."""

_BOUNDED = "_tdtp_bounded"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addini(
        "async_test_timeout",
        "seconds an asyncio test may run before it is cancelled and fails (0: no bound)",
        default=str(DEFAULT_ASYNC_TEST_TIMEOUT),
    )


def _bounded(
    test: Callable[..., Coroutine[Any, Any, Any]], seconds: float, name: str
) -> Callable[..., Coroutine[Any, Any, Any]]:
    @functools.wraps(test)
    async def run(*args: Any, **kwargs: Any) -> Any:
        bound = asyncio.timeout(seconds)
        try:
            async with bound:
                return await test(*args, **kwargs)
        except TimeoutError:
            if not bound.expired():
                raise  # the test's own timeout, not ours
            pytest.fail(
                f"{name} did not finish within {seconds:g} s (async_test_timeout, "
                "tests/suite_bounds.py): it was cancelled at the await shown above",
                pytrace=True,
            )

    setattr(run, _BOUNDED, True)
    return run


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    """Wrap an async test's coroutine function in the bound (pytest-asyncio then runs the wrapper
    on the test's loop, whichever loop that is)."""
    if not isinstance(item, pytest.Function):
        return
    test = item.obj
    if not inspect.iscoroutinefunction(test) or getattr(test, _BOUNDED, False):
        return
    seconds = float(item.config.getini("async_test_timeout"))
    if seconds > 0:
        item.obj = _bounded(test, seconds, item.nodeid)
