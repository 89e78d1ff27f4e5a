"""The compiled core and its pure-Python fallback: one list of modules, a switch that works, and a
report of which build runs."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import tdtp
from tdtp._build import COMPILED_MODULES, PURE_ENV

ROOT = Path(__file__).resolve().parent.parent


def _setup_py_list() -> list[str]:
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            isinstance(t, ast.Name) and t.id == "COMPILED" for t in node.targets
        ):
            value = ast.literal_eval(node.value)
            assert isinstance(value, list)
            return [str(v) for v in value]
    raise AssertionError("setup.py has no COMPILED list")


def test_setup_py_compiles_exactly_the_modules_the_runtime_knows() -> None:
    paths = _setup_py_list()
    assert [p.removesuffix(".py").replace("/", ".") for p in paths] == list(COMPILED_MODULES)
    for path in paths:
        assert (ROOT / path).is_file(), path


def _which_build(env: dict[str, str]) -> list[str]:
    code = (
        "import tdtp, tdtp.session.connection, tdtp.control.trinomial as t;"
        "info = tdtp.build_info();"
        "print(info.build, tdtp.session.connection.__file__.endswith('.py'), t.__file__.endswith('.py'))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    return out.stdout.split()


def test_the_pure_switch_loads_every_core_module_from_its_source() -> None:
    env = {**os.environ, PURE_ENV: "1"}
    assert _which_build(env) == ["pure", "True", "True"]


def test_the_report_matches_the_modules_that_run() -> None:
    env = {k: v for k, v in os.environ.items() if k != PURE_ENV}
    build, connection_is_source, controller_is_source = _which_build(env)
    assert connection_is_source == controller_is_source
    assert build == ("pure" if connection_is_source == "True" else "compiled")


def test_build_info_describes_itself() -> None:
    info = tdtp.build_info()
    assert info.build in ("compiled", "pure")
    assert info.describe().startswith("compiled" if info.compiled else "pure Python (")
    assert info.as_dict() == {"build": info.build, "reason": info.reason}


def test_public_classes_keep_their_docstrings_in_both_builds() -> None:
    """help(tdtp.DataReceived) said "mypyc filler docstring" in the compiled build (issue 20, 9)."""
    import inspect

    import tdtp

    for name in tdtp.__all__:
        obj = getattr(tdtp, name)
        if inspect.isclass(obj):
            assert obj.__doc__ and "mypyc" not in obj.__doc__, name
