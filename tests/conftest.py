"""Shared fixtures. ``tests/`` is on sys.path, so tests import the fake-time pair as ``pair``."""

from __future__ import annotations

import sys
from pathlib import Path

from hypothesis import HealthCheck, settings

sys.path.insert(0, str(Path(__file__).parent))

# A bound on every asyncio test that works on uvloop too (tests/suite_bounds.py).
from suite_bounds import pytest_addoption, pytest_runtest_setup

__all__ = ["pytest_addoption", "pytest_report_header", "pytest_runtest_setup"]

# Property tests judge behaviour, never the machine's speed: no per-example deadline and no "too
# slow" health check (a loaded CI machine once failed a codec property on hypothesis's 200 ms).
settings.register_profile(
    "tdtp", deadline=None, suppress_health_check=[HealthCheck.too_slow], print_blob=True
)
settings.load_profile("tdtp")


def pytest_report_header() -> str:
    """Which build of the core the suite runs against (``make test`` runs it on both)."""
    import tdtp

    return f"tdtp core: {tdtp.build_info().describe()}"
