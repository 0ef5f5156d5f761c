"""Which numbers of a Markdown document report a result, and whether each is rendered from ``results/``.

:mod:`icgo.reporting.render` fills marked values from the results files; this module finds the result numbers that
are *not* marked, so that a quoted result cannot drift from its table unnoticed. A number needs a marker when

* it stands in a **result unit**: a paragraph, list item or table that cites a file of ``results/`` (by path or by
  its file name) or holds a marker, or a table right after such a paragraph (in a table whose rows cite results
  files, each row is a unit of its own). There
  every decimal number, every count of the form "N of M", every integer with ``%``, a time unit (``s``, ``min``,
  ``h``) or a ratio sign (``x``, ``times``) and every ``p =`` value must be rendered; or
* anywhere else, it is a decimal of three or more significant digits that equals (at its written precision) a
  value of some results file: a quoted result that names no source.

Not counted: code spans and fenced code (settings and commands), HTML comments, link targets, references
("Table 4", "eq. 15", "section 3.3", "Fig. 9"), the significance level where a sentence states it ("p < 0.05"),
and the numbers of a development measurement: a unit holding ``<!--development: how it was measured-->``, or every
unit from ``<!--development-begin: how it was measured-->`` to ``<!--development-end-->`` (they must then cite no
results file: rule 6 of docs/reporting.md). The papers' values are rendered too (``paper(...)``), so they are traced
to :mod:`icgo.reporting.published`.
"""

from __future__ import annotations

import bisect
import re
from dataclasses import dataclass
from pathlib import Path

from icgo.reporting.render import CODE_SPAN, FENCE, VALUE

#: Files of results/ whose numbers count as results (the data files the tables are made of).
RESULT_SUFFIXES = (".md", ".csv", ".json")
DEVELOPMENT = re.compile(r"<!--development:.*?-->", re.S)
#: A development region: from a ``<!--development-begin: ...-->`` comment to ``<!--development-end-->``.
DEVELOPMENT_REGION = re.compile(r"<!--development-begin:.*?-->.*?<!--development-end-->", re.S)
#: The significance level where a sentence states it ("Holm p < 0.05", "below 0.05"): a setting, not a quote.
_LEVEL = re.compile(r"(?:\bp\s*<=?\s*|\bbelow\s+|\bat\s+)0\.05\b(?![\d.])")
_COMMENT = re.compile(r"<!--.*?-->", re.S)
_LINK = re.compile(r"\]\([^)]*\)|https?://\S+")
_REFERENCE = re.compile(r"(?i)\b(?:sections?|eqs?\.|equations?|figs?\.|figures?|tables?|steps?|item)\s*\(?"
                        r"\d+(?:\.\d+)*[a-z]?(?:\s*(?:-|,|and|to)\s*\d+(?:\.\d+)*)*")
_DECIMAL = re.compile(r"(?<![\w.^/])[-+]?\d+\.\d+(?:[eE][-+]?\d+)?(?![\w.]*\d)")
_COUNT = re.compile(r"(?<![\w.])(\d+)\s+of\s+(?:the\s+)?(\d+)(?![\w.]*\d)")
_UNIT = re.compile(r"(?<![\w.^/])(\d+)(?:\s*%|\s+(?:s|min|h)\b|x\b|\s+times\b)")
_P = re.compile(r"(?<![\w.])p\s*(?:=|<|>|<=|>=)\s*(\d+(?:\.\d+)?(?:e-?\d+)?)")
_ANY_NUMBER = re.compile(r"[-+]?\d+\.?\d*(?:[eE][-+]?\d+)?")


@dataclass(frozen=True)
class Untraced:
    """A result number of a document that no marker renders."""

    line: int
    number: str
    why: str


def _blank(text: str, pattern: re.Pattern) -> str:
    """``text`` with every match of ``pattern`` replaced by spaces (newlines kept, so offsets and lines hold)."""
    return pattern.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), text)


def units(text: str) -> list[tuple[int, int]]:
    """The (start, end) offsets of the paragraphs, list items, headings and tables of ``text``."""
    spans, start, pos, prev = [], None, 0, ""
    for line in text.splitlines(keepends=True):
        s = line.strip()
        is_table = s.startswith("|")
        new_item = bool(re.match(r"\s*([-*+] |\d+\. )", line)) and not prev.lstrip().startswith("|")
        switch = start is not None and is_table != prev.strip().startswith("|")
        breaks = not s or s.startswith("#") or new_item or switch
        if breaks and start is not None:
            spans.append((start, pos))
            start = None
        if s and start is None:
            start = pos
        if s.startswith("#"):
            spans.append((pos, pos + len(line)))
            start = None
        pos += len(line)
        prev = line
    if start is not None:
        spans.append((start, pos))
    return spans


def missing_citations(text: str, results: Path) -> list[tuple[int, str]]:
    """(line, citation) of every ``results/...`` path the document names that does not exist (a ``<...>`` part or
    ``{a,b}`` stands for any name; ``tables_missing.txt`` and ``excluded_repeats.txt`` exist only when something is
    missing, and a citation of them names no number)."""
    import glob

    out = []
    for m in re.finditer(r"results/([\w./<>*{},-]+)", text):
        cite = m.group(1).rstrip(".,)`")
        if cite in ("tables_missing.txt", "excluded_repeats.txt") or not cite:
            continue
        pattern = re.sub(r"\{[^}]*\}", "*", re.sub(r"<[^>]*>", "*", cite))
        if not glob.glob(str(Path(results) / pattern)):
            out.append((text.count("\n", 0, m.start()) + 1, f"results/{cite}"))
    return out


def result_values(results: Path) -> list[float]:
    """Every number written in a results file (absolute values, sorted): what a quoted result may equal."""
    out = set()
    for f in Path(results).rglob("*"):
        if f.is_file() and f.suffix in RESULT_SUFFIXES:
            for x in _ANY_NUMBER.findall(f.read_text(errors="replace")):
                try:
                    out.add(abs(float(x)))
                except ValueError:
                    pass
    return sorted(out)


def _equals_some(q: str, values: list[float]) -> bool:
    """``q`` (as written) equals some value at its written precision."""
    mantissa, _, exp = q.lower().lstrip("+-").partition("e")
    digits = len(mantissa.split(".")[1]) if "." in mantissa else 0
    tol = 0.5 * 10.0 ** -digits * 10.0 ** int(exp or 0) * (1 + 1e-9)
    v = abs(float(q))
    i = bisect.bisect_left(values, v - tol)
    return i < len(values) and values[i] <= v + tol


def _significant(q: str) -> int:
    return len(q.lower().lstrip("+-").split("e")[0].replace(".", "").lstrip("0"))


def untraced(text: str, results: Path, values: list[float] | None = None) -> list[Untraced]:
    """The result numbers of a Markdown document that no marker renders (see the module docstring)."""
    results = Path(results)
    names = {p.name for p in results.iterdir() if p.is_file()}  # a bare file name cites a file of results/ itself
    cite = re.compile(r"results/[\w./<>*{},-]*|(?<![\w.-])(?:" + "|".join(
        re.escape(n) for n in sorted(names, key=len, reverse=True)) + r")(?!\w)")
    numbers_file = re.compile(r"\.(?:md|csv|json)\b|results/[\w<>*{},-]*/?(?![\w.])")
    values = result_values(results) if values is None else values
    masked = _blank(text, FENCE)
    uncoded = _blank(masked, CODE_SPAN)  # a marker or a declaration in a code span is an example
    masked = _blank(masked, VALUE)  # rendered values are traced
    regions = [(m.start(), m.end()) for m in DEVELOPMENT_REGION.finditer(uncoded)]
    spans = []
    for a, b in units(masked):
        rows = masked[a:b].splitlines(keepends=True)
        if rows and rows[0].lstrip().startswith("|") and any(cite.search(_blank(r, _COMMENT)) for r in rows):
            pos = a  # a table whose rows cite results files: each row is a unit (it quotes its own file)
            for r in rows:
                spans.append((pos, pos + len(r)))
                pos += len(r)
        else:
            spans.append((a, b))
    out, before = [], False  # before: the unit just before is a paragraph that quotes results
    for a, b in spans:
        raw = masked[a:b]
        active = uncoded[a:b]
        development = DEVELOPMENT.search(active) or any(s <= a < e for s, e in regions)
        body = _blank(_blank(_blank(_blank(_blank(raw, _COMMENT), CODE_SPAN), _LINK), _REFERENCE), _LEVEL)
        marked = any(x in active for x in ("<!--=", "<!--?", "<!--let"))
        cited = [m.group(0) for m in cite.finditer(_blank(raw, _COMMENT))]
        cites = bool(cited)
        is_table = raw.lstrip().startswith("|")
        cites = cites or (is_table and before)  # a table of numbers the paragraph before it introduces
        if not is_table:
            before = not development and (marked or any(numbers_file.search(c) for c in cited))
        line0 = text.count("\n", 0, a) + 1
        where = lambda m, g=0: line0 + body.count("\n", 0, m.start(g))  # noqa: E731
        if development:
            if cites:
                out.append(Untraced(line0, "", "a development measurement that cites results/ (rule 6: it names "
                                                "no results file)"))
            continue
        if cites or marked:
            found = {}
            for m in _DECIMAL.finditer(body):
                found[m.start()] = (m.group(0), where(m))
            for pat in (_COUNT, _UNIT, _P):
                for m in pat.finditer(body):
                    for g in range(1, (m.re.groups or 0) + 1):
                        found.setdefault(m.start(g), (m.group(g), where(m, g)))
            out += [Untraced(line, q, "in a unit that quotes results/: render it (<!--= ... -->)")
                    for _, (q, line) in sorted(found.items())]
        else:
            out += [Untraced(where(m), m.group(0), "equals a value in results/ but names no source: render it, or "
                                                    "declare the unit <!--development: ...-->")
                    for m in _DECIMAL.finditer(body) if _significant(m.group(0)) >= 3 and
                    _equals_some(m.group(0), values)]
    return out
