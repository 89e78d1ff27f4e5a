"""The suite's bounds work: a test that hangs on purpose fails with its name instead of hanging.

Each case runs pytest in a subprocess on a test written to hang, with small bounds, and checks that
the run ends (``subprocess.run``'s own timeout is the proof's bound: without tests/suite_bounds.py
the asyncio case waits forever on uvloop) and says which test hung.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

TESTS = Path(__file__).parent

CONFTEST = """
import asyncio

from suite_bounds import pytest_addoption, pytest_runtest_setup


def pytest_asyncio_loop_factories(config, item):
    factories = {"asyncio": asyncio.new_event_loop}
    try:
        import uvloop
    except ImportError:
        return factories
    factories["uvloop"] = uvloop.new_event_loop
    return factories
"""

HANGS = """
import asyncio
import time

import pytest


@pytest.mark.asyncio
async def test_waits_forever_at_an_await():
    await asyncio.Event().wait()


@pytest.mark.asyncio
async def test_own_timeout_is_its_own():
    with pytest.raises(TimeoutError):
        await asyncio.wait_for(asyncio.Event().wait(), 0.01)


def test_blocks_forever_in_a_call():
    time.sleep(3600)
"""

PATIENCE = 120.0
"""How long the subprocess may take before the bound is judged not to work (it needs ~2 s)."""


def _run(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    (tmp_path / "conftest.py").write_text(textwrap.dedent(CONFTEST))
    (tmp_path / "test_hangs.py").write_text(textwrap.dedent(HANGS))
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])
    )
    command = [
        sys.executable,
        "-m",
        "pytest",
        "-p",
        "no:cacheprovider",
        "-q",
        "--rootdir",
        str(tmp_path),
    ]
    try:
        return subprocess.run(  # the exit status is what the tests check
            [
                *command,
                *("-o", "asyncio_mode=strict", "-o", "asyncio_default_fixture_loop_scope=function"),
                *args,
                str(tmp_path / "test_hangs.py"),
            ],
            check=False,
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=PATIENCE,
        )
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"a test made to hang was not stopped by its bound ({exc.cmd})")


def test_a_hung_async_test_fails_with_its_name_on_both_loops(tmp_path: Path) -> None:
    done = _run(tmp_path, "-o", "async_test_timeout=1", "--timeout=60", "-k", "not blocks_forever")
    out = done.stdout + done.stderr
    assert done.returncode == 1, out
    loops = ["asyncio"]
    try:
        import uvloop  # noqa: F401

        loops.append("uvloop")
    except ImportError:
        pass
    for loop in loops:
        name = f"test_waits_forever_at_an_await[{loop}]"
        assert f"FAILED test_hangs.py::{name}" in out, out
    assert "did not finish within 1 s (async_test_timeout" in out
    # The traceback shows the await it hung at; a test's own TimeoutError is left to the test.
    assert "await asyncio.Event().wait()" in out
    assert f"{len(loops)} failed, {len(loops)} passed" in out, out


def test_a_test_stuck_outside_the_loop_is_ended_by_the_watchdog_thread(tmp_path: Path) -> None:
    done = _run(tmp_path, "--timeout=2", "-o", "timeout_method=thread", "-k", "blocks_forever")
    out = done.stdout + done.stderr
    assert done.returncode != 0, out
    assert "Timeout" in out and "test_blocks_forever_in_a_call" in out, out
