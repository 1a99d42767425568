"""griffe extension for the API reference: the sources' docstrings as Markdown.

The docstrings are prose with Sphinx roles (``:class:`~arcf.presets.TrackerParams```) and
doctest examples (``>>> ...``). Markdown would print the roles verbatim and read ``>>>`` as
nested block quotes, so, before mkdocstrings renders them, a role becomes inline code of its
target (the last dotted part with ``~``, as Sphinx shows it) and each run of doctest lines
becomes a fenced ``pycon`` block. Fields and constants are documented with ``#:`` comments
above them (Sphinx's convention, which griffe does not read): those comments become the
attribute's docstring. The sources are not changed.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(
    r":(?:py:)?(?:mod|class|func|meth|attr|data|obj|exc|const|ref|term):`(~?)([^`]+)`")


def _role(match: re.Match[str]) -> str:
    target = match.group(2).strip()
    if "<" in target and target.endswith(">"):  # :ref:`title <target>`
        target = target.split("<", 1)[0].strip()
    elif match.group(1):
        target = target.rsplit(".", 1)[-1]
    return f"`{target}`"


def _fence_doctests(text: str) -> str:
    lines = text.split("\n")
    out: list[str] = []
    in_fence = False
    i = 0
    while i < len(lines):
        line = lines[i]
        stripped = line.lstrip()
        if stripped.startswith("```"):
            in_fence = not in_fence
        if in_fence or not stripped.startswith(">>>"):
            out.append(line)
            i += 1
            continue
        indent = line[: len(line) - len(stripped)]
        block = []
        while i < len(lines) and lines[i].strip() and lines[i].startswith(indent):
            block.append(lines[i])
            i += 1
        if out and out[-1].strip():
            out.append("")
        out += [f"{indent}```pycon", *block, f"{indent}```"]
        if i < len(lines) and lines[i].strip():
            out.append("")
    return "\n".join(out)


def _comment_docstring(obj: griffe.Object) -> griffe.Docstring | None:
    """The ``#:`` comment lines right above an attribute, as its docstring."""
    if not obj.is_attribute or not obj.lineno:
        return None
    try:
        lines = obj.module.lines
    except Exception:  # a module without a source file
        return None
    comment: list[str] = []
    index = obj.lineno - 2
    while index >= 0 and lines[index].lstrip().startswith("#:"):
        comment.insert(0, lines[index].lstrip()[2:].removeprefix(" "))
        index -= 1
    if not comment:
        return None
    parent = obj.parent
    while parent is not None and parent.docstring is None:
        parent = parent.parent
    source = parent.docstring if parent is not None else None
    return griffe.Docstring(
        "\n".join(comment), lineno=index + 2, endlineno=obj.lineno - 1, parent=obj,
        parser=source.parser if source else None,
        parser_options=source.parser_options if source else None,
    )


class SourceDocstrings(griffe.Extension):
    """Rewrites every docstring once the object tree is built."""

    def on_object(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is None:
            obj.docstring = _comment_docstring(obj)
        if obj.docstring is not None:
            value = _ROLE.sub(_role, obj.docstring.value)
            obj.docstring.value = _fence_doctests(value)
