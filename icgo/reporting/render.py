"""Result values in Markdown, rendered from the files of ``results/``: ``make docs`` fills them, a test keeps them.

A document marks each value it quotes with the expression that reads it; rendering replaces the text between the
markers with the value read now, so a regenerated ``results/`` followed by :func:`render_text` (``make docs``) leaves
the document true without hand edits. The markers are HTML comments, invisible where the Markdown is shown::

    <!--= {T["MAE (deg)"]["CGO-RELM (ours)"]} -->0.0404 +/- 0.0041<!--/-->   a value (a template, below)
    <!--let T = csv("table1.csv", key="metric") -->                          a name for the rest of the document
    <!--? fig9["CGO-RELM"]["mae_mean"] > fig9["PSO-RELM"]["mae_mean"] -->    a claim the prose around it makes

* A **value** marker holds a template: text with ``{expression}`` or ``{expression:format}`` fields (the fields of a
  Python f-string; ``format`` is a format spec such as ``.4f``, ``.3g``, ``.1%``, ``d``; ``{{`` and ``}}`` are
  braces). What follows it up to ``<!--/-->`` is the rendered text; it may span lines (a table included whole).
* A **let** names a value for the markers after it (a table read once, a derived number).
* A **claim** is an expression that must be true: a regenerated table that turns the order or the verdict a sentence
  states fails rendering at that sentence, instead of leaving the sentence false.

A marker may not contain ``--`` (it would end the HTML comment early in some Markdown renderers): a table built in a
marker writes its rule as ``| - | - |``. Markers inside code spans and fenced blocks are examples, never rendered.

Expressions are Python expressions restricted to literals (f-strings included), names (``let`` names and the
functions below), arithmetic, comparisons, ``and``/``or``/``not``, ``a if c else b``, subscripts, comprehensions and
calls of the functions below: no attributes, no other names. Sources (paths relative to the results directory):

* ``csv(file, key=None)``: the rows of a CSV file as dicts (numbers parsed), or with ``key`` (a column or a tuple of
  columns) a dict from the key's values to the rows (a repeated key is an error);
* ``md(file, n=0, key=None, having=None)``: the ``n``-th Markdown table of a results file (of those with a column
  ``having``, when given), the same way (``**bold**`` removed);
* ``table(file, n=0, having=None)``: that table verbatim (to include a table whole);
* ``js(file)``: a JSON file's value;
* ``text(file, pattern)``: group 1 of the one match of a regular expression in a results file (numbers parsed);
* ``paper(name, *keys)``: a published value of :mod:`icgo.reporting.published` (``paper("ICGO", "table1", "relm",
  0)``).

Helpers: ``num(s)`` (the first number in ``"0.0295 +/- 0.0021"``), ``nums(s)`` (all of them), ``sd(s)`` (the number
after ``+/-``), ``col(rows, name)`` (one column of a list of rows), ``where(rows, **equal)`` (the rows whose columns
equal the values), ``join(values, sep, spec)`` (formatted and joined), ``lines(rows)`` (joined by newlines),
``split(s, sep)``, ``items(d)`` (a dict's pairs), ``pair(rows, x, y)`` (the row of paired tests, columns ``a`` and
``b``, comparing x with y), ``carried(rows, lower, higher)`` (that row's Holm p < 0.05 with ``lower`` below: the
order a sentence states is carried by a test), ``untested(rows, x, y)`` (its Holm p >= 0.05), ``abs``, ``min``, ``max``, ``sum``, ``len``, ``round``,
``sorted``, ``set``, ``list``, ``int``, ``float``, ``any``, ``all``, ``mean``, ``median``. A value that renders as NaN
or infinity is an error, never written.
"""

from __future__ import annotations

import ast
import csv as _csv
import io
import json
import math
import re
import statistics
from dataclasses import dataclass
from pathlib import Path

#: ``<!--= TEMPLATE -->RENDERED<!--/-->``, ``<!--let NAME = EXPR -->``, ``<!--? EXPR -->``.
VALUE = re.compile(r"<!--=(?P<template>.*?)-->(?P<rendered>.*?)<!--/-->", re.S)
LET = re.compile(r"<!--let\s+(?P<name>[A-Za-z]\w*)\s*=(?P<let>.*?)-->", re.S)
CLAIM = re.compile(r"<!--\?(?P<claim>.*?)-->", re.S)
MARKER = re.compile("|".join(p.pattern for p in (VALUE, LET, CLAIM)), re.S)
#: Fenced code blocks and inline code spans: a marker written there is an example, never rendered.
FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.S | re.M)
CODE_SPAN = re.compile(r"(`+)(?!`).*?(?<!`)\1(?!`)", re.S)
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


class RenderError(ValueError):
    """A marker that cannot be rendered: a bad expression, a missing file or cell, a false claim."""


@dataclass(frozen=True)
class Problem:
    """One thing wrong in a document: where (1-based line) and what."""

    doc: str
    line: int
    message: str

    def __str__(self) -> str:
        return f"{self.doc}:{self.line}: {self.message}"


# ------------------------------------------------------------------------------------------------ the sources
def _value(cell: str):
    """A table cell as a number (or a bool for ``True``/``False``) when it is one, else the stripped text without
    Markdown bold."""
    s = cell.strip()
    s = s[2:-2] if s.startswith("**") and s.endswith("**") and len(s) > 4 else s
    if s in ("True", "False"):
        return s == "True"
    try:
        return int(s)
    except ValueError:
        pass
    try:
        return float(s)
    except ValueError:
        return s


def _keyed(rows: list[dict], key, where: str):
    if key is None:
        return rows
    cols = key if isinstance(key, tuple) else (key,)
    out = {}
    for r in rows:
        missing = [c for c in cols if c not in r]
        if missing:
            raise RenderError(f"{where}: no column {missing[0]!r} (columns: {', '.join(map(str, r))})")
        k = tuple(r[c] for c in cols) if isinstance(key, tuple) else r[key]
        if k in out:
            raise RenderError(f"{where}: key {k!r} is in more than one row; give a key of more columns")
        out[k] = r
    return out


def _md_tables(text: str) -> list[list[str]]:
    """The Markdown tables of ``text``, each as its lines (header, rule, rows)."""
    tables, cur = [], []
    for line in text.splitlines() + [""]:
        if line.lstrip().startswith("|"):
            cur.append(line)
        elif cur:
            if len(cur) >= 2 and set(cur[1].replace("|", "").strip()) <= set("-: "):
                tables.append(cur)
            cur = []
    return tables


def _cells(line: str) -> list[str]:
    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]


class Sources:
    """The functions a marker may call, reading files below ``results`` (each file read once)."""

    def __init__(self, results: Path):
        self.results = Path(results)
        self._texts: dict[str, str] = {}

    def _read(self, file: str) -> str:
        if not isinstance(file, str) or file.startswith("/") or ".." in Path(file).parts:
            raise RenderError(f"{file!r}: give a path relative to the results directory")
        if file not in self._texts:
            path = self.results / file
            if not path.is_file():
                raise RenderError(f"results/{file}: no such file")
            self._texts[file] = path.read_text()
        return self._texts[file]

    def csv(self, file: str, key=None):
        reader = _csv.DictReader(io.StringIO(self._read(file)))
        rows = [{k: _value(v if v is not None else "") for k, v in r.items()} for r in reader]
        return _keyed(rows, key, f"results/{file}")

    def md(self, file: str, n: int = 0, key=None, having: str | None = None):
        lines = self._table_lines(file, n, having)
        head = _cells(lines[0])
        rows = [dict(zip(head, (_value(c) for c in _cells(line)))) for line in lines[2:]]
        return _keyed(rows, key, f"results/{file} table {n}")

    def table(self, file: str, n: int = 0, having: str | None = None) -> str:
        return "\n".join(self._table_lines(file, n, having))

    def _table_lines(self, file: str, n: int, having: str | None = None) -> list[str]:
        tables = _md_tables(self._read(file))
        if having is not None:
            tables = [t for t in tables if having in _cells(t[0])]
        if not 0 <= n < len(tables):
            what = f" with a column {having!r}" if having is not None else ""
            raise RenderError(f"results/{file}: no Markdown table {n}{what} (it has {len(tables)})")
        return tables[n]

    def js(self, file: str):
        try:
            return json.loads(self._read(file))
        except ValueError as e:
            raise RenderError(f"results/{file}: not JSON ({e})") from None

    def text(self, file: str, pattern: str):
        hits = list(re.finditer(pattern, self._read(file)))
        if len(hits) != 1:
            raise RenderError(f"results/{file}: pattern {pattern!r} matches {len(hits)} times (must match once)")
        if hits[0].re.groups < 1:
            raise RenderError(f"pattern {pattern!r} has no group")
        return _value(hits[0].group(1))

    def lock(self, package: str) -> str:
        """The version ``requirements/dev.lock`` pins for ``package``: the lock beside the results directory, else the
        repository's (a copy of results/ elsewhere still renders)."""
        path = self.results.parent / "requirements" / "dev.lock"
        if not path.is_file():
            path = Path(__file__).resolve().parents[2] / "requirements" / "dev.lock"
        if not path.is_file():
            raise RenderError(f"{path}: no such lock file")
        want = re.sub(r"[-_.]+", "-", package).lower()
        for line in path.read_text().splitlines():
            m = re.match(r"([A-Za-z0-9._-]+)==([^\s;]+)", line)
            if m and re.sub(r"[-_.]+", "-", m.group(1)).lower() == want:
                return m.group(2)
        raise RenderError(f"{path.name}: {package!r} is not locked")

    @staticmethod
    def paper(name: str, *keys):
        from icgo.reporting import published

        if name not in ("ICGO", "ICGO_LAB_MAE", "MISMA"):
            raise RenderError(f"paper({name!r}): one of ICGO, ICGO_LAB_MAE, MISMA")
        v = getattr(published, name)
        for k in keys:
            try:
                v = v[k]
            except (KeyError, IndexError, TypeError):
                raise RenderError(f"paper({name!r}, ...): no entry {k!r}") from None
        return v

    def functions(self) -> dict:
        return {"csv": self.csv, "md": self.md, "table": self.table, "js": self.js, "text": self.text,
                "lock": self.lock, "paper": self.paper, **HELPERS}


def num(s):
    """The first number in ``s`` (``"0.0295 +/- 0.0021"`` -> 0.0295); a number is returned as it is."""
    if isinstance(s, (int, float)):
        return s
    m = _NUMBER.search(str(s))
    if not m:
        raise RenderError(f"no number in {s!r}")
    return float(m.group(0))


def nums(s) -> list[float]:
    """Every number in ``s``, in order (``"0.857 (4.389)"`` -> [0.857, 4.389])."""
    return [float(x) for x in _NUMBER.findall(str(s))]


def sd(s):
    """The number after ``+/-`` in ``s`` (``"0.0295 +/- 0.0021"`` -> 0.0021)."""
    m = re.search(r"\+/-\s*(" + _NUMBER.pattern + ")", str(s))
    if not m:
        raise RenderError(f"no '+/- number' in {s!r}")
    return float(m.group(1))


def col(rows, name):
    """Column ``name`` of a list of rows (or of a keyed table's rows)."""
    rows = list(rows.values()) if isinstance(rows, dict) else rows
    try:
        return [r[name] for r in rows]
    except KeyError:
        raise RenderError(f"no column {name!r}") from None


def where(rows, **equal):
    """The rows (of a list or a keyed table) whose columns equal the given values."""
    rows = list(rows.values()) if isinstance(rows, dict) else rows
    return [r for r in rows if all(r.get(k) == v for k, v in equal.items())]


def join(values, sep: str = ", ", spec: str = "") -> str:
    """``values`` formatted with ``spec`` and joined by ``sep`` (``join([0.2781, 0.38], "/", ".3f")``)."""
    return sep.join(format(v, spec) for v in values)


def lines(rows) -> str:
    """``rows`` joined by newlines (Markdown table rows built in a marker)."""
    return "\n".join(str(r) for r in rows)


def split(s: str, sep: str) -> list[str]:
    """``s`` split at every ``sep``."""
    return str(s).split(sep)


def items(mapping) -> list:
    """The ``(key, value)`` pairs of a dict (a JSON object), in order."""
    return list(dict(mapping).items())


def pair(rows, x, y):
    """The one row of paired tests (columns ``a``, ``b``) that compares ``x`` with ``y``, either way round."""
    rows = list(rows.values()) if isinstance(rows, dict) else rows
    hits = [r for r in rows if {r.get("a"), r.get("b")} == {x, y}]
    if len(hits) != 1:
        raise RenderError(f"pair({x!r}, {y!r}): {len(hits)} rows compare them (give one family's rows)")
    return hits[0]


def carried(rows, lower, higher, alpha: float = 0.05) -> bool:
    """Whether the paired tests ``rows`` carry ``lower < higher``: their row (:func:`pair`) has ``p (Holm)`` below
    ``alpha`` and its median difference puts ``lower`` below. False also when the order is the other way or untested."""
    r = pair(rows, lower, higher)
    d = r["median difference a - b"] * (1 if r["a"] == lower else -1)
    return r["p (Holm)"] < alpha and d < 0


def untested(rows, x, y, alpha: float = 0.05) -> bool:
    """Whether the paired tests ``rows`` leave the order of ``x`` and ``y`` untested (``p (Holm)`` >= ``alpha``)."""
    return not pair(rows, x, y)["p (Holm)"] < alpha


HELPERS = {"num": num, "nums": nums, "sd": sd, "col": col, "where": where, "join": join, "lines": lines,
           "split": split, "items": items, "pair": pair, "carried": carried, "untested": untested, "abs": abs,
           "min": min, "max": max, "sum": sum, "len": len, "round": round,
           "sorted": sorted, "set": set, "list": list, "int": int, "float": float, "any": any, "all": all,
           "mean": statistics.fmean, "median": statistics.median}
#: Every name a marker may call.
FUNCTIONS = (*HELPERS, "csv", "md", "table", "js", "text", "lock", "paper")


# -------------------------------------------------------------------------------------------- expressions
_ALLOWED = (ast.Expression, ast.Constant, ast.Name, ast.Load, ast.Store, ast.List, ast.Tuple, ast.Dict, ast.BinOp,
            ast.Add, ast.Sub, ast.Mult, ast.Div, ast.FloorDiv, ast.Mod, ast.Pow, ast.UnaryOp, ast.USub, ast.UAdd,
            ast.Not, ast.BoolOp, ast.And, ast.Or, ast.Compare, ast.Eq, ast.NotEq, ast.Lt, ast.LtE, ast.Gt, ast.GtE,
            ast.In, ast.NotIn, ast.IfExp, ast.Subscript, ast.Slice, ast.Call, ast.keyword, ast.ListComp,
            ast.GeneratorExp, ast.comprehension, ast.JoinedStr, ast.FormattedValue)


def compile_expression(source: str):
    """``source`` compiled, after checking it uses only the constructs the module docstring lists."""
    try:
        tree = ast.parse(source.strip(), mode="eval")
    except SyntaxError as e:
        raise RenderError(f"not an expression: {source.strip()!r} ({e.msg})") from None
    for node in ast.walk(tree):
        if not isinstance(node, _ALLOWED):
            raise RenderError(f"{type(node).__name__} is not allowed in a marker: {source.strip()!r}")
        if isinstance(node, ast.Name) and node.id.startswith("_"):
            raise RenderError(f"name {node.id!r} is not allowed in a marker")
        if isinstance(node, ast.Call) and not isinstance(node.func, ast.Name):
            raise RenderError(f"only named functions may be called in a marker: {source.strip()!r}")
    return compile(tree, "<marker>", "eval")


def evaluate(source: str, names: dict):
    """The value of ``source`` over ``names`` (no builtins besides them)."""
    code = compile_expression(source)
    try:  # names as globals, so that comprehensions (a scope of their own) see them too
        return eval(code, {**names, "__builtins__": {}})  # noqa: S307  (checked by compile_expression)
    except RenderError:
        raise
    except NameError as e:
        raise RenderError(f"{e} (a `let` below its use, or a typo?)") from None
    except Exception as e:  # noqa: BLE001  (a missing key, a bad format: one line naming it)
        raise RenderError(f"{source.strip()!r}: {type(e).__name__}: {e}") from None


def fields(template: str) -> list[tuple[str, str | None, str | None]]:
    """A template split into ``(literal, expression, format)`` parts (the last two None after the last field).

    A field is ``{expression}`` or ``{expression:format}``; the format starts at the last ``:`` outside brackets and
    string literals; ``{{`` and ``}}`` are literal braces.
    """
    out, lit, i, n = [], [], 0, len(template)
    while i < n:
        ch = template[i]
        if ch in "{}" and template[i:i + 2] in ("{{", "}}"):
            lit.append(ch)
            i += 2
            continue
        if ch == "}":
            raise RenderError(f"unmatched '}}' in template {template!r}")
        if ch != "{":
            lit.append(ch)
            i += 1
            continue
        depth, quote, j, colon = 0, None, i + 1, None
        while j < n:
            c = template[j]
            if quote:
                if c == "\\":
                    j += 1
                elif c == quote:
                    quote = None
            elif c in "'\"":
                quote = c
            elif c in "([{":
                depth += 1
            elif c in ")]}":
                if depth == 0 and c == "}":
                    break
                depth -= 1
            elif c == ":" and depth == 0:
                colon = j
            j += 1
        if j >= n:
            raise RenderError(f"unclosed '{{' in template {template!r}")
        body = template[i + 1:j]
        expr, spec = (body, None) if colon is None else (template[i + 1:colon], template[colon + 1:j])
        out.append(("".join(lit), expr, spec))
        lit, i = [], j + 1
    out.append(("".join(lit), None, None))
    return out


def _format(value, spec: str | None, source: str) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        raise RenderError(f"{source.strip()!r} is {value}: no value to quote")
    try:
        return format(value, spec or "")
    except (TypeError, ValueError) as e:
        raise RenderError(f"{source.strip()!r}: format {spec!r}: {e}") from None


def render_template(template: str, names: dict) -> str:
    """A value marker's template rendered over ``names``."""
    parts = []
    for lit, expr, spec in fields(template.strip()):
        parts.append(lit)
        if expr is not None:
            parts.append(_format(evaluate(expr, names), spec, expr))
    return "".join(parts)


# ------------------------------------------------------------------------------------------------ documents
def _line(text: str, pos: int) -> int:
    return text.count("\n", 0, pos) + 1


def render_text(text: str, results: Path, doc: str = "<doc>") -> tuple[str, list[Problem]]:
    """``text`` with every value marker re-rendered from ``results``, and the problems found.

    A marker that fails keeps its old text (and is a problem); a false claim is a problem. Markers are read in
    document order, so a ``let`` applies to the markers after it.
    """
    names = Sources(results).functions()
    code = [(c.start(), c.end()) for pat in (FENCE, CODE_SPAN) for c in pat.finditer(text)]
    out, problems, end = [], [], 0
    for m in MARKER.finditer(text):
        if any(a <= m.start() < b for a, b in code):
            continue
        out.append(text[end:m.start()])
        end = m.end()
        try:
            inner = next(g for g in (m.group("template"), m.group("let"), m.group("claim")) if g is not None)
            if "--" in inner:
                raise RenderError("'--' inside a marker ends the HTML comment early in some Markdown renderers")
            if m.group("template") is not None:
                rendered = _block(render_template(m.group("template"), names))
                out.append(f"<!--={m.group('template')}-->{rendered}<!--/-->")
                continue
            if m.group("name") is not None:
                if m.group("name") in FUNCTIONS:
                    raise RenderError(f"let {m.group('name')}: the name of a function")
                names[m.group("name")] = evaluate(m.group("let"), names)
            elif not evaluate(m.group("claim"), names):
                raise RenderError(f"claim no longer holds: {' '.join(m.group('claim').split())}")
        except RenderError as e:
            problems.append(Problem(doc, _line(text, m.start()), str(e)))
        out.append(m.group(0))
    out.append(text[end:])
    return "".join(out), problems


def _block(rendered: str) -> str:
    """A multi-line value (a table) on lines of its own, a blank line between it and each marker."""
    return "\n\n" + rendered + "\n\n" if "\n" in rendered else rendered


def stale(text: str, results: Path, doc: str = "<doc>") -> list[Problem]:
    """The problems of ``text`` against ``results``: markers that fail, false claims and values whose text is not
    what they render to now (stale)."""
    new, problems = render_text(text, results, doc)
    if new != text:
        old_vals = list(VALUE.finditer(text))
        new_vals = list(VALUE.finditer(new))
        for a, b in zip(old_vals, new_vals):
            if a.group("rendered") != b.group("rendered"):
                problems.append(Problem(doc, _line(text, a.start()),
                                        f"stale: {a.group('rendered').strip()[:60]!r}, the results give "
                                        f"{b.group('rendered').strip()[:60]!r} (make docs)"))
    return problems
