"""The version lives in one place: tdtp/__init__.py; the package metadata reads it from there."""

from __future__ import annotations

import importlib.metadata
import re
from pathlib import Path

import tdtp

ROOT = Path(__file__).resolve().parent.parent


def test_the_version_is_defined_once() -> None:
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert re.search(r"^version\s*=\s*[\"']", pyproject, re.MULTILINE) is None
    assert 'dynamic = ["version"]' in pyproject
    assert importlib.metadata.version("tdtp") == tdtp.__version__
    assert f"## {tdtp.__version__}" in (ROOT / "CHANGELOG.md").read_text() or (
        "## Unreleased" in (ROOT / "CHANGELOG.md").read_text()
    )
