"""Griffe extension: Sphinx cross-reference roles in the docstrings become code spans on the site.

The package's docstrings are Sphinx-style (``:param x:`` fields, which mkdocstrings reads with
``docstring_style: sphinx``) and refer to each other with roles such as ``:class:`~pkg.mod.Name```,
which Markdown would show as they are. Here ``:role:`~a.b.C``` becomes ```C``` and ``:role:`a.b.C```
becomes ```a.b.C```, as Sphinx would print them (without the link).
"""
from __future__ import annotations

import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|attr|data|obj|exc|const):`(~?)([^`]+)`")


def plain(text: str) -> str:
    """``text`` with every Sphinx role replaced by a code span of the name Sphinx would show."""

    def span(match: re.Match[str]) -> str:
        tilde, target = match.groups()
        return f"`{target.rsplit('.', 1)[-1] if tilde else target.lstrip('.')}`"

    return ROLE.sub(span, text)


class SphinxRoles(griffe.Extension):
    """Rewrites every docstring of every object griffe loads."""

    def on_instance(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = plain(obj.docstring.value)
