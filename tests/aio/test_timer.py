"""The deadline timers: correctness on the stock loop and on uvloop, for each kind.

Every asyncio test runs on the stock loop and on uvloop (the ``pytest_asyncio_loop_factories`` hook
in tests/aio/conftest.py) and, where the kind matters, with each timer kind. "Never early" is
asserted inside the callback (``monotonic() >= deadline``): it is a correctness property. How
*precisely* the timers fire is a benchmark figure (benchmarks/pacing.py), so nothing here asserts on
latency beyond generous "it did fire" timeouts.
"""

from __future__ import annotations

import asyncio
import math
import os
import sys
from collections.abc import AsyncIterator, Callable
from pathlib import Path

import pytest
import pytest_asyncio

from tdtp.aio import timer as timer_module
from tdtp.aio.timer import (
    DEFAULT_SPIN_WINDOW,
    PRECISE_SPIN_WINDOW,
    CallAtTimer,
    DeadlineTimer,
    TimerfdTimer,
    TimerUnavailableError,
    create_timer,
    monotonic,
    timerfd_unavailable_reason,
)

# "call_at-spin": the fallback with the precise spin window, so its call_soon polling runs too.
KINDS = ("timerfd", "call_at", "call_at-spin")
QUIET = 0.03  # how long "nothing fires" is watched for
PATIENCE = 2.0  # generous upper bound for "it fires" (a correctness timeout, not a timing goal)


@pytest.fixture(params=KINDS)
def kind(request: pytest.FixtureRequest) -> str:
    kind: str = request.param
    if kind == "timerfd" and (reason := timerfd_unavailable_reason()) is not None:
        pytest.skip(reason)
    return kind


def make_timer(
    kind: str, loop: asyncio.AbstractEventLoop, callback: Callable[[], None]
) -> DeadlineTimer:
    if kind == "call_at-spin":
        return CallAtTimer(loop, callback, spin_window=PRECISE_SPIN_WINDOW)
    t = create_timer(loop, callback, prefer=kind)
    assert t.kind == kind
    return t


class Recorder:
    """A callback that records when it ran and checks it never ran before the armed deadline."""

    def __init__(self) -> None:
        self.times: list[float] = []
        self.early: list[tuple[float, float]] = []
        self.deadline: float | None = None  # what the test armed, for the never-early check
        self.then: Callable[[], None] | None = None
        self._event = asyncio.Event()

    def __call__(self) -> None:
        now = monotonic()
        if self.deadline is not None and now < self.deadline:
            self.early.append((now, self.deadline))
        self.times.append(now)
        self._event.set()
        if self.then is not None:
            self.then()

    async def wait(self, count: int = 1) -> None:
        async with asyncio.timeout(PATIENCE):
            while len(self.times) < count:
                self._event.clear()
                await self._event.wait()


@pytest.fixture
def recorder() -> Recorder:
    return Recorder()


@pytest_asyncio.fixture(loop_scope="function")
async def timer(kind: str, recorder: Recorder) -> AsyncIterator[DeadlineTimer]:
    t = make_timer(kind, asyncio.get_running_loop(), recorder)
    yield t
    t.close()


def arm(t: DeadlineTimer, recorder: Recorder, deadline: float | None) -> None:
    recorder.deadline = deadline
    t.arm(deadline)


@pytest.mark.asyncio
async def test_fires_once_after_the_deadline(timer: DeadlineTimer, recorder: Recorder) -> None:
    deadline = monotonic() + 0.005
    arm(timer, recorder, deadline)
    assert timer.deadline == deadline
    await recorder.wait()
    await asyncio.sleep(QUIET)
    assert len(recorder.times) == 1
    assert recorder.times[0] >= deadline
    assert timer.deadline is None


@pytest.mark.asyncio
async def test_chained_deadlines_never_fire_early(timer: DeadlineTimer, recorder: Recorder) -> None:
    # Re-arming from the callback, as a pacer does, on an awkward period that is not whole
    # milliseconds or microseconds, so rounding on every path is exercised.
    count, period = 40, 0.000_712_345_7
    start = monotonic() + 0.002
    schedule = [start + i * period for i in range(count)]

    def next_deadline() -> None:
        if len(recorder.times) < count:
            arm(timer, recorder, schedule[len(recorder.times)])

    recorder.then = next_deadline
    arm(timer, recorder, schedule[0])
    await recorder.wait(count)
    assert recorder.early == []
    assert all(t >= d for t, d in zip(recorder.times, schedule, strict=True))


@pytest.mark.asyncio
async def test_rearm_earlier(timer: DeadlineTimer, recorder: Recorder) -> None:
    arm(timer, recorder, monotonic() + 60.0)
    earlier = monotonic() + 0.005
    arm(timer, recorder, earlier)
    await recorder.wait()
    assert recorder.early == []
    await asyncio.sleep(QUIET)
    assert len(recorder.times) == 1
    assert timer.deadline is None  # the 60 s deadline is gone, not pending


@pytest.mark.asyncio
async def test_rearm_later(timer: DeadlineTimer, recorder: Recorder) -> None:
    arm(timer, recorder, monotonic() + 0.002)
    later = monotonic() + 0.02
    arm(timer, recorder, later)
    await recorder.wait()
    assert recorder.times[0] >= later
    await asyncio.sleep(QUIET)
    assert len(recorder.times) == 1


@pytest.mark.asyncio
async def test_rearming_the_same_deadline_is_a_no_op(
    timer: DeadlineTimer, recorder: Recorder, monkeypatch: pytest.MonkeyPatch
) -> None:
    deadline = monotonic() + 0.005
    arm(timer, recorder, deadline)
    calls: list[float] = []
    schedule = timer._schedule
    monkeypatch.setattr(timer, "_schedule", lambda d: (calls.append(d), schedule(d)))
    for _ in range(100):
        timer.arm(deadline)
    assert calls == []
    monkeypatch.undo()
    await recorder.wait()
    assert len(recorder.times) == 1
    # Once it has fired the timer is disarmed, so the same deadline arms a new call.
    timer.arm(deadline)
    assert timer.deadline == deadline
    await recorder.wait(2)
    assert recorder.early == []


@pytest.mark.asyncio
@pytest.mark.parametrize("disarm", [None, math.inf], ids=["None", "inf"])
async def test_disarm(timer: DeadlineTimer, recorder: Recorder, disarm: float | None) -> None:
    arm(timer, recorder, monotonic() + 0.002)
    timer.arm(disarm)
    assert timer.deadline is None
    await asyncio.sleep(QUIET)
    assert recorder.times == []
    # Disarmed, not broken.
    arm(timer, recorder, monotonic() + 0.001)
    await recorder.wait()
    assert recorder.early == []


@pytest.mark.asyncio
@pytest.mark.parametrize("past", [-1.0, 0.0, -math.inf], ids=["1s-ago", "zero", "-inf"])
async def test_past_deadline_fires_promptly(
    timer: DeadlineTimer, recorder: Recorder, past: float
) -> None:
    # 0.0 matters for timerfd: a zero absolute expiry would disarm it instead of firing.
    deadline = monotonic() + past if past == -1.0 else past
    arm(timer, recorder, deadline)
    await recorder.wait()
    await asyncio.sleep(QUIET / 3)
    assert len(recorder.times) == 1


@pytest.mark.asyncio
async def test_nan_is_rejected(timer: DeadlineTimer) -> None:
    with pytest.raises(ValueError, match="NaN"):
        timer.arm(math.nan)
    assert timer.deadline is None


@pytest.mark.asyncio
async def test_close_is_idempotent_and_stops_callbacks(
    timer: DeadlineTimer, recorder: Recorder
) -> None:
    arm(timer, recorder, monotonic() + 0.002)
    timer.close()
    timer.close()
    assert timer.closed
    assert timer.deadline is None
    await asyncio.sleep(QUIET)
    assert recorder.times == []
    timer.arm(None)  # disarming a closed timer is harmless
    with pytest.raises(RuntimeError, match="closed"):
        timer.arm(monotonic())
    if isinstance(timer, TimerfdTimer):
        assert timer.fd == -1


@pytest.mark.asyncio
async def test_early_wake_rearms_instead_of_calling_back(
    timer: DeadlineTimer, recorder: Recorder
) -> None:
    # Simulate the implementation waking too soon: spurious fd readiness (timerfd) or an early
    # call_at (CallAtTimer). Neither may call back before the deadline.
    deadline = monotonic() + 0.02
    arm(timer, recorder, deadline)
    if isinstance(timer, TimerfdTimer):
        timer._on_readable()  # read() gets EAGAIN: nothing expired
    else:
        assert isinstance(timer, CallAtTimer)
        timer._on_wake()
    timer._expired()  # the shared guard, as if the mechanism had fired early
    assert recorder.times == []
    assert timer.deadline == deadline
    await recorder.wait()
    assert recorder.early == []
    await asyncio.sleep(QUIET / 3)
    assert len(recorder.times) == 1


@pytest.mark.asyncio
async def test_expiry_superseded_before_the_read(timer: DeadlineTimer, recorder: Recorder) -> None:
    # Armed in the past (timerfd: already expired), then moved to the future before the loop ran:
    # the stale expiry must not call back.
    arm(timer, recorder, monotonic() - 1.0)
    later = monotonic() + 0.01
    arm(timer, recorder, later)
    await recorder.wait()
    assert recorder.times[0] >= later
    await asyncio.sleep(QUIET / 3)
    assert len(recorder.times) == 1


@pytest.mark.asyncio
async def test_callback_exception_goes_to_the_loop_and_timer_survives(kind: str) -> None:
    loop = asyncio.get_running_loop()
    errors: list[BaseException | None] = []
    loop.set_exception_handler(lambda _loop, context: errors.append(context.get("exception")))
    fired = asyncio.Event()

    def boom() -> None:
        fired.set()
        raise ZeroDivisionError

    t = make_timer(kind, loop, boom)
    try:
        t.arm(monotonic())
        async with asyncio.timeout(PATIENCE):
            await fired.wait()
        await asyncio.sleep(0.001)
        assert len(errors) == 1
        assert isinstance(errors[0], ZeroDivisionError)
        fired.clear()
        t.arm(monotonic())
        async with asyncio.timeout(PATIENCE):
            await fired.wait()
    finally:
        t.close()


def _open_fds() -> int:
    """Open timerfds. Only these: sockets of earlier tests may be closed by the garbage collector
    at any moment, which changed a plain fd count under the full suite."""
    count = 0
    for name in os.listdir("/proc/self/fd"):
        try:
            if os.readlink(f"/proc/self/fd/{name}") == "anon_inode:[timerfd]":
                count += 1
        except OSError:
            continue  # closed between listdir and readlink
    return count


@pytest.mark.asyncio
@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc/self/fd")
async def test_many_rearms_and_timers_do_not_leak_fds(kind: str) -> None:
    loop = asyncio.get_running_loop()
    before = _open_fds()
    t = make_timer(kind, loop, lambda: None)
    base = monotonic() + 60.0
    for i in range(5_000):
        t.arm(base + i * 1e-4 if i % 3 else None)
    t.close()
    for _ in range(50):
        make_timer(kind, loop, lambda: None).close()
    # No growth: an earlier test's timer may be collected (and its fd closed) meanwhile.
    assert _open_fds() <= before


@pytest.mark.asyncio
async def test_auto_prefers_timerfd_where_available() -> None:
    t = create_timer(asyncio.get_running_loop(), lambda: None)
    try:
        expected = "timerfd" if timerfd_unavailable_reason() is None else "call_at"
        assert t.kind == expected
    finally:
        t.close()


@pytest.mark.asyncio
async def test_prefer_timerfd_where_unavailable(monkeypatch: pytest.MonkeyPatch) -> None:
    reason = f"timerfd is Linux-only (this is {sys.platform}-simulated)"
    monkeypatch.setattr(timer_module, "timerfd_unavailable_reason", lambda: reason)
    loop = asyncio.get_running_loop()
    with pytest.raises(TimerUnavailableError) as info:
        create_timer(loop, lambda: None, prefer="timerfd")
    message = str(info.value)
    assert reason in message
    assert "prefer='call_at'" in message
    assert isinstance(info.value, RuntimeError)
    fallback = create_timer(loop, lambda: None)  # "auto" falls back quietly
    try:
        assert fallback.kind == "call_at"
    finally:
        fallback.close()


@pytest.mark.asyncio
async def test_prefer_must_be_known() -> None:
    with pytest.raises(ValueError, match="prefer must be one of"):
        create_timer(asyncio.get_running_loop(), lambda: None, prefer="spin")


@pytest.mark.asyncio
async def test_call_at_spin_window_is_bounded() -> None:
    loop = asyncio.get_running_loop()
    assert CallAtTimer(loop, lambda: None).spin_window == DEFAULT_SPIN_WINDOW == 0.0
    with pytest.raises(ValueError, match="spin_window"):
        CallAtTimer(loop, lambda: None, spin_window=-0.001)
    with pytest.raises(ValueError, match="spin_window"):
        CallAtTimer(loop, lambda: None, spin_window=1.0)


@pytest.mark.asyncio
@pytest.mark.parametrize("spin_window", [0.0003, 0.0008])
async def test_call_at_with_a_partial_spin_window_still_never_fires_early(
    recorder: Recorder, spin_window: float
) -> None:
    t = CallAtTimer(asyncio.get_running_loop(), recorder, spin_window=spin_window)
    try:
        for i in range(5):
            arm(t, recorder, monotonic() + 0.0017)
            await recorder.wait(i + 1)
        assert recorder.early == []
    finally:
        t.close()


@pytest.mark.parametrize(
    ("deadline", "expected_ns"),
    [
        (-5.0, 1),
        (0.0, 1),
        (1.5, 1_500_000_000),
        (2.000_000_000_1, 2_000_000_001),  # rounded up, never down
        (1e300, ((1 << 31) - 1) * 1_000_000_000),
    ],
)
def test_deadline_ns_rounds_up_and_never_disarms(deadline: float, expected_ns: int) -> None:
    assert timer_module._deadline_ns(deadline) == expected_ns
