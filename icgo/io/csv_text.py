"""A contract CSV's text -> the checked frame: pandas' C parser where it can, the exact reader where it cannot.

:func:`parse_contract_text` takes the text with comments blanked and the header resolved
(:mod:`icgo.io.columns`); :func:`_read_fast` reads it without a Python object per cell and hands anything
unusual to :func:`_read_exact` (the csv module and ``float`` on every cell), which is the reference reader and
the one that words every error. Both give the same frame whenever the fast one returns one (tested side by
side on mutated files). Checks: :mod:`icgo.io.checks`.
"""

from __future__ import annotations

import csv
import io as _io
import re

import numpy as np
import pandas as pd

from icgo.core.errors import DataError
from icgo.io.checks import Lazy, check_columns, check_frame, guard
from icgo.io.schema import KNOWN_COLUMNS, fail


def parse_contract_text(text: str, src: str, require_reference: bool, convert=None,
                        setting: str = "columns", lazy: Lazy | None = None,
                        gap: tuple[int, int] | None = None) -> tuple[pd.DataFrame, list]:
    """(checked frame, notices) of a contract CSV's text (comments blanked, header resolved: :mod:`icgo.io.columns`):
    pandas' C parser where it can, the exact reader where it cannot (and to word every error). ``lazy``: every
    failure of the file kept (:class:`icgo.io.checks.Lazy`; the exact reader only), raised together at the end.
    ``gap``: (the character offset where the rows begin, the file's lines between the header and them) of a
    streamed chunk: the exact reader, which names lines, reads that many blank lines there, so that its line
    numbers are the file's; the fast reader, which names none, reads the text as it is."""
    notices: list[str] = []
    def exact():  # built only when the exact reader runs: a chunk deep in a survey has millions of lines before it
        return text if gap is None else text[:gap[0]] + "\n" * gap[1] + text[gap[0]:]

    if lazy is not None:
        return _read_exact(exact(), src, notices, require_reference, convert=convert, setting=setting,
                           lazy=lazy), notices
    typed = _read_fast(text, src, notices, require_reference, convert=convert, setting=setting)
    if typed is None:
        notices = []
        typed = _read_exact(exact(), src, notices, require_reference, convert=convert, setting=setting)
    return typed, notices


#: A line longer than the csv module's field limit: the exact reader refuses it, so the fast one must not read it.
_LONG_LINE = re.compile("(?m)^[^\n]{%d}" % (csv.field_size_limit() + 1))
#: pandas before 3.1 parses floats correctly rounded only with ``float_precision="round_trip"`` (from 3.1 on
#: every mode uses one correctly rounded converter and the argument is deprecated).
_ROUND_TRIP = {"float_precision": "round_trip"} if tuple(
    int(v) for v in re.findall(r"\d+", pd.__version__)[:2]) < (3, 1) else {}


def _read_fast(text: str, src: str, notices: list, require_reference: bool, convert=None,
               setting: str = "columns") -> pd.DataFrame | None:
    """The checked frame of a plain CSV text by pandas' C parser, or None to leave it to :func:`_read_exact`.

    Same result as :func:`_read_exact` whenever it returns a frame (tested side by side on mutated
    files), in a fraction of its time and memory: no Python object per cell of the contract columns.
    Known columns are parsed as float64 by a correctly rounded converter (:data:`_ROUND_TRIP`), so
    every number ``float`` accepts reads back bit for bit, and a cell it refuses fails the parse. Anything else goes to the exact reader: quotes
    or NUL characters in the text, an over-long line, a header the exact reader refuses, a parse
    error (more fields than the header), a line with fewer fields (the count of commas), no data
    rows, and every contract error (the exact reader then names the row and its line).
    """
    if '"' in text or "\x00" in text or (len(text) >= csv.field_size_limit() and _LONG_LINE.search(text)):
        return None
    try:
        header = next((r for r in csv.reader(_io.StringIO(text)) if r and not (len(r) == 1 and r[0].strip() == "")),
                      None)
    except csv.Error:  # e.g. a carriage return inside a field: the exact reader words it (line and reason)
        return None
    if header is None:
        return None
    header = [h.strip() for h in header]
    if "" in header or len(set(header)) != len(header):
        return None
    try:
        check_columns(header, src, require_reference, setting)
        parsed = pd.read_csv(_io.BytesIO(text.encode("utf-8")), encoding="utf-8", header=0, names=header, engine="c", na_filter=False,
                             skip_blank_lines=True, dtype={h: np.float64 if h in KNOWN_COLUMNS else object
                                                           for h in header}, **_ROUND_TRIP)
    except Exception:  # noqa: BLE001  (any refusal: the exact reader decides and words it)
        return None
    # without quotes a line has commas + 1 fields; a longer line failed the parse, so a short one shows here
    if (len(parsed) == 0 or not parsed.index.equals(pd.RangeIndex(len(parsed)))
            or text.count(",") != (len(header) - 1) * (len(parsed) + 1)):
        return None
    data = {}
    for name in header:
        col = parsed[name]
        if name in KNOWN_COLUMNS:
            data[name] = col.to_numpy(np.float64)
            continue
        cells = col.tolist()
        try:  # unknown column: numeric if every cell parses, else kept as text (as the exact reader does)
            data[name] = np.fromiter((float(c) for c in cells), np.float64, len(cells))
        except ValueError:
            data[name] = cells
    del parsed
    frame = pd.DataFrame(data)
    try:
        return check_frame(frame, src, lambda i: i + 2, notices, require_reference, convert, setting)
    except DataError:
        return None


def _read_exact(text: str, src: str, notices: list, require_reference: bool, convert=None,
                setting: str = "columns", lazy: Lazy | None = None) -> pd.DataFrame:
    """Every row through the csv module and ``float``: the reference reader, and the one that words errors."""
    reader = csv.reader(_io.StringIO(text))
    numbered = []  # (line number, fields), blank lines skipped
    try:
        for r in reader:
            if r and not (len(r) == 1 and r[0].strip() == ""):
                numbered.append((reader.line_num, r))
    except csv.Error as e:
        fail(src, f"CSV syntax error at line {reader.line_num}: {e}")
    (hline, header), body = numbered[0], numbered[1:]
    header = [h.strip() for h in header]
    for j, h in enumerate(header):
        if h == "":
            fail(src, f"empty column name (column {j + 1} of the header)", None, None)
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        fail(src, f"duplicate column(s) {', '.join(dup)} in the header (line {hline})")
    for k, (ln, r) in enumerate(body):
        if len(r) != len(header):
            fail(src, f"{len(r)} fields, the header has {len(header)}", k + 1, None, ln)
    if body:
        check_columns(header, src, require_reference, setting, lazy)
    rows = [r for _, r in body]
    line_of = lambda i: body[i][0]  # noqa: E731
    frame = _parse_columns(header, rows, src, line_of, lazy) if rows else pd.DataFrame(columns=header)
    return check_frame(frame, src, line_of, notices, require_reference, convert, setting, lazy)


def _parse_columns(header: list[str], rows: list[list[str]], source: str, line_of,
                   lazy: Lazy | None = None) -> pd.DataFrame:
    """Text cells -> numeric DataFrame; a column's first bad cell raises DataError (``lazy``: kept, and the column
    read as NaN and marked bad, so no later check of it runs)."""
    data = {}
    for j, name in enumerate(header):
        cells = [r[j] for r in rows]
        if name in KNOWN_COLUMNS:
            out = []
            if guard(lazy, (name,), lambda: out.append(_to_float(cells, name, source, line_of))):
                data[name] = out[0]
            else:
                data[name] = np.full(len(cells), np.nan)
        else:  # unknown column: numeric if it parses, else kept as text
            try:
                data[name] = np.fromiter((float(c) for c in cells), np.float64, len(cells))
            except ValueError:
                data[name] = cells
    return pd.DataFrame(data)


def _to_float(cells, name, source, line_of) -> np.ndarray:
    # Python's float() rounds correctly, so repr-written floats read back bit for bit; it also takes
    # digit separators ("1_000"), which the contract (and pandas' parser) does not.
    try:
        if not any("_" in c for c in cells):
            return np.fromiter((float(c) for c in cells), np.float64, len(cells))
    except ValueError:
        pass
    for i, c in enumerate(cells):
        try:
            float(c)
            if "_" in c:
                raise ValueError
        except ValueError:
            if c.strip() == "":
                fail(source, "missing value (empty cell)", i + 1, name, line_of(i))
            fail(source, f"non-numeric value {c!r}", i + 1, name, line_of(i))
    raise AssertionError("unreachable: float() failed on the whole column but on no cell")
