"""Sphinx configuration for tdtp's documentation site (``make docs``: docs/_build/html).

The pages are Markdown (MyST); the API reference is generated from the docstrings by autodoc, on the
pure-Python build (``make docs`` sets ``TDTP_PURE_PYTHON=1``: the same sources the compiled build is
made from, with their signatures). Everything builds offline from the repository; warnings are errors.
"""

from __future__ import annotations

import importlib
import inspect
import re
import sys
from pathlib import Path

from sphinx.application import Sphinx

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import tdtp  # noqa: E402 - after the path: the checkout's package, built or not

project = "tdtp"
author = "tdtp developers"
copyright = "tdtp developers, MIT licence"
release = version = tdtp.__version__

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.viewcode"]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "figures/*.json"]

myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 4
"""PROTOCOL.md and the others link to their own sections by GitHub's heading anchors."""

autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_default_options = {"members": True, "undoc-members": True, "show-inheritance": True}
autodoc_class_signature = "separated"
python_use_unqualified_type_names = True

html_theme = "furo"
html_title = f"tdtp {release}"
html_static_path: list[str] = []
html_show_sourcelink = False


_LINK = re.compile(r"\[([^\]\n]+)\]\((?!https?:|#|mailto:)([^)\s#]+)(#[^)\s]*)?\)")
"""A Markdown link to a relative path (the explanation pages are read on GitHub too)."""


def _repository_links(app: Sphinx, docname: str, source: list[str]) -> None:
    """A link from a page to a repository file outside docs/ (``../tests/vectors/README.md``) works
    on GitHub but is no page of the site: there it names the file's path instead."""
    srcdir = Path(app.srcdir).resolve()
    base = (srcdir / docname).parent

    def replace(match: re.Match[str]) -> str:
        target = (base / match.group(2)).resolve()
        if target == srcdir or srcdir in target.parents:
            return match.group(0)
        return f"{match.group(1)} (`{target.relative_to(ROOT).as_posix()}` in the repository)"

    source[0] = _LINK.sub(replace, source[0])


def _public_names(app: Sphinx, docname: str, source: list[str]) -> None:
    """A reference page names its module (``.. automodule:: tdtp.wire``, for the module's
    docstring); every name of the module's ``__all__`` is added after it, each with the directive
    its kind needs, so that a name exported later is documented without editing the page. A name
    the package face exports too (the same object) is documented there, once."""
    if not docname.startswith("reference/"):
        return
    match = re.search(r"^\.\. automodule:: (\S+)\n", source[0], re.MULTILINE)
    if match is None:
        return
    module = importlib.import_module(match.group(1))
    face = {name: getattr(tdtp, name) for name in tdtp.__all__}
    lines = ["   :no-members:", ""]
    elsewhere = []
    for name in module.__all__:
        obj = getattr(module, name)
        if module is not tdtp and name in face and face[name] is obj:
            elsewhere.append(f":py:obj:`tdtp.{name}`")
            continue
        if inspect.isclass(obj):
            kind = "autoexception" if issubclass(obj, BaseException) else "autoclass"
        elif inspect.isroutine(obj):
            kind = "autofunction"
        else:
            kind = "autodata"
        lines += [f".. {kind}:: {module.__name__}.{name}", ""]
    if elsewhere:
        lines += ["Documented with the package: " + ", ".join(elsewhere) + ".", ""]
    end = match.end()
    source[0] = source[0][:end] + "\n".join(lines) + "\n" + source[0][end:]


def _no_type_docstrings(
    app: Sphinx, what: str, name: str, obj: object, options: object, lines: list[str]
) -> None:
    """A constant without a docstring of its own (``SCENARIOS``, a dict) would show its type's
    (``dict()``'s): show its value alone."""
    if what in ("data", "attribute") and lines and obj.__doc__ == type(obj).__doc__:
        lines.clear()


def setup(app: Sphinx) -> dict[str, bool]:
    app.connect("autodoc-process-docstring", _no_type_docstrings)
    app.connect("source-read", _repository_links)
    app.connect("source-read", _public_names)
    return {"parallel_read_safe": True}
