"""Every conformance vector passes against the clean-room implementation (tools/cleanroom/).

The clean-room package was written from docs/PROTOCOL.md and tests/vectors/README.md alone, without
reading tdtp; this test proves, on every change, that an implementation written from the text
passes every vector (issue 31). A change to PROTOCOL.md's behaviour that updates the vectors but not
the text, or the other way round, fails here.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CLEANROOM = ROOT / "tools" / "cleanroom"
VECTORS = ROOT / "tests" / "vectors"
sys.path.insert(0, str(CLEANROOM))

import run_vectors  # noqa: E402

FILES = sorted(VECTORS.glob("tdtp-v4-*.json"))


def test_every_suite_has_a_runner() -> None:
    import json

    suites = {json.loads(f.read_text())["suite"] for f in FILES}
    assert suites <= set(run_vectors.SUITES), suites - set(run_vectors.SUITES)
    assert len(FILES) >= 9


@pytest.mark.parametrize("path", FILES, ids=[f.name for f in FILES])
def test_vector_file(path: Path) -> None:
    passed, failed, failures = run_vectors.run_file(path, verbose=False)
    assert failed == 0, "\n".join(failures)
    assert passed > 0


def test_the_package_does_not_import_tdtp() -> None:
    for src in (CLEANROOM / "tdtp_cleanroom").glob("*.py"):
        text = src.read_text()
        assert (
            "import tdtp\n" not in text and "from tdtp " not in text and "from tdtp." not in text
        ), src
