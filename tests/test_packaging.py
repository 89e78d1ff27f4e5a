"""The version lives in one place: tdtp/__init__.py; the package metadata reads it from there."""

from __future__ import annotations

import importlib.metadata
import re
import subprocess
import sys
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


def test_a_script_beside_a_clone_called_tdtp_imports_the_package(tmp_path: Path) -> None:
    """A clone is usually a folder called tdtp; a script run from the folder that holds it used to
    import that folder (an empty namespace package) instead of the installed package (issue 35).
    The checkout's own install (``make``: an editable install in setuptools' path mode) and any
    wheel put the real package first."""
    (tmp_path / "tdtp").symlink_to(ROOT, target_is_directory=True)
    script = tmp_path / "app.py"
    script.write_text(
        "import tdtp\nprint(tdtp.__file__, callable(getattr(tdtp, 'connect', None)))\n"
    )
    run = subprocess.run(
        [sys.executable, str(script)],
        check=False,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[-1] == "True", run.stdout
