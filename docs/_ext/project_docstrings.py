"""Read swarmloc's docstring convention with napoleon's numpy parser.

swarmloc's docstrings write numpy-style sections (``Parameters`` underlined with dashes), but each entry as
``name: description`` (``name [unit]: description``, ``a, b: description``), continued on indented lines, where
numpy style writes ``name : type`` with the description below. Read as written, napoleon would take every
description for a type. This extension runs before napoleon and rewrites such a section into numpy's form:

* an entry ``name: text`` becomes ``name`` with ``text`` as the first line of its description (the type then
  comes from the signature's annotations, as napoleon does when none is written);
* a paragraph after the entries that is not an entry (``Other keywords: ...``) ends the section, as prose;
* a qualified heading (``Parameters (besides X's)``, ``Parameters common to all nodes``) becomes that heading as
  a sentence (with a colon) followed by a plain ``Parameters`` section.

It also keeps a data or attribute docstring as written: napoleon would read the text before its first colon as
the attribute's type ("Landmark id -> (x, y)..." would become a type named ``Landmark id -> ...``).
"""

from __future__ import annotations

import re
from typing import Any

_NAME = r"[A-Za-z_*][A-Za-z0-9_*]*(?: \[[^\]]*\])?"
_ENTRY = re.compile(rf"^(?P<names>{_NAME}(?:, {_NAME})*): ?(?P<text>.*)$")
_SECTIONS = ("Parameters", "Other Parameters", "Attributes", "Keyword Arguments")


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def _is_rule(line: str | None) -> bool:
    return line is not None and len(line.strip()) >= 3 and set(line.strip()) == {"-"}


def _entry(line: str, indent: int) -> list[str]:
    """``name [unit]: text`` -> ``name`` and, indented below it, ``[unit] text`` (numpy's form without a type)."""
    match = _ENTRY.match(line.strip())
    assert match is not None
    names, text = match["names"], match["text"]
    units = re.findall(r" (\[[^\]]*\])", names)
    names = re.sub(r" \[[^\]]*\]", "", names)
    text = " ".join([*units, text]).strip()
    pad = " " * indent
    return [pad + names, pad + "    " + text] if text else [pad + names]


def convert(lines: list[str]) -> list[str]:
    """The docstring's lines with its parameter-like sections in numpy's form (see the module docstring)."""
    out: list[str] = []
    i = 0
    while i < len(lines):
        line = lines[i]
        head = line.strip()
        nxt = lines[i + 1] if i + 1 < len(lines) else None
        section = next((s for s in _SECTIONS if head == s or head.startswith(s + " ")), None)
        if section is None or not _is_rule(nxt):
            out.append(line)
            i += 1
            continue
        indent = _indent(line)
        if head != section:  # "Parameters (besides X's)": say so, then a plain section
            out += [" " * indent + head + ":", ""]
        out += [" " * indent + section, " " * indent + "-" * len(section)]
        i += 2
        while i < len(lines):
            line = lines[i]
            if not line.strip():
                out.append(line)
                i += 1
                continue
            if _indent(line) > indent:  # a continuation of the entry above
                out.append(line)
                i += 1
                continue
            following = lines[i + 1] if i + 1 < len(lines) else None
            if _indent(line) == indent and _ENTRY.match(line.strip()) and not _is_rule(following):
                out += _entry(line, indent)
                i += 1
                continue
            break  # prose, or the next section: end this one (two blank lines end a numpy section)
        if i < len(lines) and not (i + 1 < len(lines) and _is_rule(lines[i + 1])):
            while out and not out[-1].strip():
                out.pop()
            out += ["", ""]
    return out


def _process(app: Any, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    lines[:] = convert(lines)


def _keep_attribute_docstrings_as_written() -> None:
    from sphinx.ext.napoleon.docstring import GoogleDocstring

    def parse_attribute_docstring(self: GoogleDocstring) -> list[str]:
        return self.__class__(self._dedent(self._consume_to_end()), self._config).lines()

    if hasattr(GoogleDocstring, "_parse_attribute_docstring"):
        GoogleDocstring._parse_attribute_docstring = parse_attribute_docstring  # type: ignore[method-assign]


def setup(app: Any) -> dict[str, Any]:
    _keep_attribute_docstrings_as_written()
    app.connect("autodoc-process-docstring", _process, priority=400)  # napoleon's handler runs at 500
    return {"parallel_read_safe": True, "parallel_write_safe": True}
