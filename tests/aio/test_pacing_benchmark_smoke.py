"""Each benchmark runs for a fraction of a second so that it cannot rot. No timing is asserted."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def test_pacing_benchmark_runs_and_reports_every_variant() -> None:
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / "pacing.py"), "--seconds", "0.1", "--json"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    text = json.dumps(report)
    for variant in ("timerfd", "call_at", "naive"):
        assert variant in text.lower(), variant
