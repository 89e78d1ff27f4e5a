"""benchmarks/cellular_bounds.py's forecasting parts on synthetic traces (the recorded ones stay
out of the tests): the stop predictor finds a warning that is there and nothing in a blind draw,
the rate belief follows what it observes, and the Sprout-style sender stops feeding an outage."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


@pytest.fixture(scope="module")
def bounds() -> ModuleType:
    sys.path.insert(0, str(BENCHMARKS))
    try:
        spec = importlib.util.spec_from_file_location(
            "benchmarks_cellular_bounds", BENCHMARKS / "cellular_bounds.py"
        )
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules["benchmarks_cellular_bounds"] = module
        spec.loader.exec_module(module)
        return module
    finally:
        sys.path.remove(str(BENCHMARKS))


def _trace(tmp_path: Path, name: str, times: list[int]) -> str:
    path = tmp_path / name
    path.write_text("".join(f"{t}\n" for t in times))
    return f"delay 20ms trace {path} limit-bytes 150000"


def _warned_stops(cycles: int) -> list[int]:
    """Cycles of 1,000 ms at one opportunity per ms, 150 ms at one per 10 ms (the warning), then
    a 200 ms stop."""
    times: list[int] = []
    for c in range(cycles):
        start = c * 1350
        times += range(start + 1, start + 1001)
        times += range(start + 1010, start + 1151, 10)
    times.append(cycles * 1350)
    return times


def test_the_predictor_learns_a_warning_and_a_blind_draw_does_not(
    bounds: ModuleType, tmp_path: Path
) -> None:
    text = _trace(tmp_path, "warned", _warned_stops(40))
    trace, offset, _ = bounds.trace_of(text)
    predictor = bounds.StopForecast(trace, 40)
    assert 0.02 < predictor.base < 0.04  # 40 ms of decisions before each onset, of 1,350
    precision, recall = predictor.judge(predictor.fires(0.10))
    assert precision / predictor.base > 5 and recall > 0.9
    blind, _ = predictor.judge(predictor.fires(0.10, blind=True))
    assert blind / predictor.base < 2.5
    # holding on the warning keeps the samples a stop would have caught out of the link
    late = bounds.unavoidable(text, 40, 20.0, 0.060)
    hold = predictor.hold(predictor.fires(0.10), offset)
    assert late > 0 and bounds.unavoidable(text, 40, 20.0, 0.060, hold) > 0.9 * late


def test_the_belief_follows_its_observations(bounds: ModuleType) -> None:
    belief = bounds.RateBelief(bounds.RateModel())
    for _ in range(50):
        belief.tick(3, at_least=False)  # 150 opportunities/s
    busy = belief.forecast(bounds.QUANTILE)
    assert busy == sorted(busy) and 0 < busy[5] < 3 * 5
    for _ in range(10):
        belief.tick(0, at_least=False)  # the link kept busy delivered nothing: an outage
    assert belief.forecast(bounds.QUANTILE)[bounds.TICKS] == 0
    for _ in range(10):
        belief.tick(None, at_least=True)  # nothing seen: only the walk
    assert belief.forecast(bounds.QUANTILE)[bounds.TICKS] == 0  # an outage ends slowly (1/s)


@pytest.mark.parametrize("sees_link", [True, False])
def test_the_forecaster_stops_feeding_an_outage(
    bounds: ModuleType, tmp_path: Path, sees_link: bool
) -> None:
    times = [*range(1, 3001), *range(5001, 8001)]  # a 2 s outage from 3 s
    text = _trace(tmp_path, "outage", times)
    share, p95, _ = bounds.forecaster(text, 40, 7.5, sees_link=sees_link)
    never = bounds.frontier(text, 1000, 7.5)  # a sender that never stops
    # the never-stopping sender puts ~2,000 samples into the outage, the forecaster its ~50 ms of
    # lag and one probe per 50 ms
    assert 90 < share < never[0] - 10
    assert p95 < 25 < never[1]  # outside the outage it waits for nothing
