"""A Griffe extension for the API pages (mkdocs.yml, mkdocstrings' ``extensions``): the docstrings'
Sphinx roles read as Markdown.

snell_bench's docstrings are Google-style and cross-reference with Sphinx roles
(``:func:`~snell_bench.optics.compute_warps```, ``:mod:`.io```). Markdown has no roles, so each one
becomes a code span of the name it shows (the last dotted part with ``~``, else the whole target),
and reStructuredText's double backticks become single ones. Pure text rewriting: the docstrings
themselves stay as they are.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

__all__ = ["SphinxRoles", "markdown_roles"]

_ROLE = re.compile(r":(?:py:)?(?:func|meth|class|mod|attr|data|obj|exc|const|ref|term):`(~?)([^`]+)`")
_DOUBLE = re.compile(r"``([^`]+?)``")
_LITERAL = re.compile(r"(\S)::$", re.MULTILINE)


def _shown(tilde: str, target: str) -> str:
    """The text a role shows: ``~a.b.c`` shows ``c``, ``title <target>`` shows ``title``."""
    if "<" in target and target.endswith(">"):
        return target.split("<", 1)[0].strip()
    target = target.lstrip(".")
    return target.rsplit(".", 1)[-1] if tilde else target


def markdown_roles(text: str) -> str:
    """A docstring with its Sphinx roles and double backticks written as Markdown code spans, and
    reStructuredText's ``::`` before a literal block as a plain colon (the indented block stays code).

    Args:
        text: the docstring.

    Returns:
        The same text, ``:func:`~a.b``` as ```b```, ````x```` as ```x``` and ``text::`` as ``text:``.

    Examples:
        >>> markdown_roles("see :func:`~snell_bench.optics.compute_warps` and ``warps.roi``")
        'see `compute_warps` and `warps.roi`'
    """
    text = _ROLE.sub(lambda m: f"`{_shown(m.group(1), m.group(2))}`", text)
    text = _LITERAL.sub(r"\1:", text)
    return _DOUBLE.sub(r"`\1`", text)


class SphinxRoles(griffe.Extension):
    """Rewrites every docstring Griffe loads with :func:`markdown_roles`."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:  # noqa: D102
        if obj.docstring is not None:
            obj.docstring.value = markdown_roles(obj.docstring.value)
