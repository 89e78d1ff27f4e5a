"""The documentation site's API reference covers the public API: a page for every public module, and
in the built site (``make docs``, which ``make test`` runs first) an entry for every public name."""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import pytest
from public_api import PUBLIC_MODULES, public_objects

DOCS = Path(__file__).resolve().parent.parent / "docs"
INVENTORY = DOCS / "_build" / "html" / "objects.inv"


def _reference_modules() -> set[str]:
    found = set()
    for page in (DOCS / "reference").glob("*.rst"):
        found.update(re.findall(r"^\.\. automodule:: (\S+)", page.read_text(), re.MULTILINE))
    return found


def test_the_reference_has_a_page_for_every_public_module() -> None:
    assert _reference_modules() == set(PUBLIC_MODULES)


def _inventory() -> set[str]:
    """The Python objects the built site documents, from Sphinx's objects.inv (its format 2: four
    header lines, then zlib-compressed lines ``name domain:role priority uri display``)."""
    data = INVENTORY.read_bytes()
    header_end = 0
    for _ in range(4):
        header_end = data.index(b"\n", header_end) + 1
    names = set()
    for line in zlib.decompress(data[header_end:]).decode().splitlines():
        name, role = line.split(" ", 2)[:2]
        if role.startswith("py:"):
            names.add(name)
    return names


def test_the_built_reference_lists_every_public_name() -> None:
    if not INVENTORY.is_file():
        pytest.skip(
            "the site is not built here: `make docs` (make test builds it before the tests)"
        )
    documented = _inventory()
    missing = []
    for module, name, obj in public_objects():
        candidates = {f"{module}.{name}", f"tdtp.{name}"}
        qualname = getattr(obj, "__qualname__", None)
        if qualname is not None and isinstance(getattr(obj, "__module__", None), str):
            candidates.add(f"{obj.__module__}.{qualname}")
        if not candidates & documented:
            missing.append(f"{module}.{name}")
    assert missing == []


def test_the_inventory_reader_sees_a_missing_name() -> None:
    """The check above can fail: a name nobody documents is not in the inventory."""
    if not INVENTORY.is_file():
        pytest.skip("the site is not built here")
    documented = _inventory()
    assert "tdtp.connect" in documented and "tdtp.no_such_name" not in documented
