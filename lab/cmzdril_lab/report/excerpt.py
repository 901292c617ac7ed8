"""One section of a hand-written markdown page, copied into a generated one (results.md), its links made
to work from there.

The report links its discussion page; a page that must say something on its own face (where a target was
not reached, say) copies one ``## `` section of it, labelled as written by hand, with :func:`excerpt`. The
text stays written in one place, the discussion: the report copies it each time it is written.
"""
from __future__ import annotations

import re
import unicodedata
from pathlib import Path

from cmzdril_lab.report.readme import link
from sb3_cmzdril.errors import UserError
from sb3_cmzdril.io import PathLike

#: A markdown link or image target: ``](target)``, the target without spaces.
_TARGET = re.compile(r"\]\(([^)\s]+)\)")
#: Targets left as they are: another site, an e-mail address, a path from the site's root.
_ABSOLUTE = re.compile(r"^([a-z][a-z0-9+.-]*:|/)", re.IGNORECASE)


def slug(heading: str) -> str:
    """The anchor mkdocs (Python-Markdown's ``toc``) gives a heading: ``Where the targets stand (D14)`` ->
    ``where-the-targets-stand-d14``."""
    text = unicodedata.normalize("NFKD", heading).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def sections(text: str) -> list[tuple[str, int, int]]:
    """The ``## `` sections of a markdown page: (heading, first line, end line), fenced code skipped. A
    section ends at the next ``## `` or ``# `` heading."""
    lines = text.splitlines()
    heads: list[tuple[str | None, int]] = []  # (a ``## `` heading, or None for a ``# `` one; its line)
    fenced = False
    for i, line in enumerate(lines):
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
        elif not fenced and line.startswith(("# ", "## ")):
            heads.append((line[3:].strip() if line.startswith("## ") else None, i))
    ends = [i for _, i in heads[1:]] + [len(lines)]
    return [(heading, i, end) for (heading, i), end in zip(heads, ends, strict=True) if heading is not None]


def _retarget(target: str, page: Path, out: Path) -> str:
    """A link target of ``page`` as the same target from a page in the folder ``out``."""
    if _ABSOLUTE.match(target):
        return target
    path, hashmark, anchor = target.partition("#")
    where = link(page.parent / path, out) if path else link(page, out)
    return where + hashmark + anchor


def excerpt(page: PathLike, title: str, out: PathLike) -> str:
    """The section of ``page`` whose ``## `` heading starts with ``title``, for a page in the folder ``out``:
    its heading, a line saying it is written by hand and where, then its body with every relative link
    pointing where it pointed from ``page``.

    :raises UserError: no heading, or more than one, starts with ``title`` (the message lists them).
    """
    page, out = Path(page), Path(out)
    text = page.read_text(encoding="utf-8")
    found = sections(text)
    matches = [s for s in found if s[0].startswith(title)]
    if len(matches) != 1:
        headings = "; ".join(h for h, _, _ in found) or "none"
        which = "no" if not matches else "more than one"
        raise UserError(f"{which} section of {page} starts with {title!r} (its sections: {headings})")
    heading, start, end = matches[0]
    body = "\n".join(text.splitlines()[start + 1:end]).strip("\n")
    body = _TARGET.sub(lambda m: f"]({_retarget(m.group(1), page, out)})", body)
    source = f"{link(page, out)}#{slug(heading)}"
    return f"## {heading}\n\nWritten by hand, copied from [the discussion]({source}).\n\n{body}\n"


__all__ = ["excerpt", "sections", "slug"]
