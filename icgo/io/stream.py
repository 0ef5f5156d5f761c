"""A large survey read in chunks of rows, so that ``apply`` corrects it in bounded memory.

:func:`read_chunks` reads a contract CSV (or a field export: comments, a column map, a units row) of up to
``max_bytes`` and yields it as consecutive :class:`icgo.io.recording.Recording` chunks. A file of at most
``stream_above`` bytes is one chunk, read by :func:`icgo.io.recording.read_recording` exactly as every other
door reads it. A larger one is read line by line: its head (comment lines, the header, a units row) is resolved
once (:func:`icgo.io.columns.prepare`), then every ``chunk_rows`` data lines are parsed and checked with the same
code and the same rules as a whole file (:func:`icgo.io.csv_text.parse_contract_text`), with the lines before
them kept as empty lines so that an error names the file's own line, and its row counted from the file's start.
The reader then holds one chunk's text and frame, never the file.

A streamed file must hold one row per line (a quoted field over several lines is refused: split the file),
and checks that look at all rows at once (the units from the median |G| and |B|, a row off by a factor)
look at each chunk's rows.
"""

from __future__ import annotations

import io as _io
import re
from pathlib import Path

from icgo.core.errors import DataError
from icgo.io import columns as export
from icgo.io.csv_text import parse_contract_text
from icgo.io.files import MiB, open_regular
from icgo.io.recording import Recording, read_meta, read_recording
from icgo.io.schema import KNOWN_COLUMNS, fail

#: The largest survey ``apply`` takes by default (bytes; its ``max_mb`` setting): streamed, its memory does not
#: grow with it beyond a few floats per row.
MAX_SURVEY_BYTES = 4096 * MiB
#: Surveys larger than this are read in chunks (bytes; ``apply``'s ``stream_mb`` setting, docs/data.md).
STREAM_ABOVE_BYTES = 64 * MiB
#: Data lines per chunk (``apply``'s ``chunk_rows`` setting): about 25-40 MB of text and frame per chunk.
CHUNK_ROWS = 200_000
_ROW = re.compile(r"\brow (\d+)\b")


def _shift_rows(e: DataError, rows_before: int) -> DataError:
    """The error of a chunk with its row number counted from the file's first data row."""
    return DataError(_ROW.sub(lambda m: f"row {int(m.group(1)) + rows_before}", str(e), count=1))


def read_chunks(csv_path, *, max_bytes: int, stream_above: int = STREAM_ABOVE_BYTES, chunk_rows: int = CHUNK_ROWS,
                require_meta: bool = True, require_reference: bool = True, columns=None,
                column_setting: str = "columns"):
    """Yield a contract CSV as consecutive :class:`Recording` chunks (module doc).

    Every chunk carries the file's metadata and reference field; the first also the head's notices (the columns
    mapped, the units converted, the metadata's), each later one only its own new notices.

    Args:
        csv_path: the survey. max_bytes: the largest file taken. stream_above: files larger than this stream.
        chunk_rows: data lines per chunk. require_meta, require_reference, columns, column_setting: as
            :func:`icgo.io.recording.read_recording`.
    Raises:
        DataError: one line naming the file, the row (from the file's start) and its line.
        SettingError: a column map whose key is not a contract column.
    """
    src = str(csv_path)
    with open_regular(csv_path, max_bytes, "a contract CSV") as f:
        size = f.seek(0, 2)
    if size <= stream_above:
        yield read_recording(csv_path, require_meta=require_meta, require_reference=require_reference,
                             columns=columns, column_setting=column_setting, max_bytes=max_bytes)
        return
    cmap = export.check_column_map(columns, KNOWN_COLUMNS, column_setting)
    notices: list[str] = []
    meta, field = read_meta(Path(csv_path), None, require_meta, notices)
    with open_regular(csv_path, max_bytes, "a contract CSV") as raw:
        text = _io.TextIOWrapper(raw, encoding="utf-8-sig", newline="")
        lines = iter(text)
        head, seen = [], 0
        try:
            for ln in lines:  # comment and blank lines, the header, and the next line (a units row or the first row)
                head.append(ln)
                if ln.strip() and not ln.lstrip().startswith("#"):
                    seen += 1
                    if seen == 2:
                        break
        except UnicodeDecodeError as e:
            fail(src, f"not UTF-8 text ({e.reason}); give a contract CSV")
        if seen == 0:
            fail(src, "only comment lines (lines starting with #): no header, no rows")
        prep = export.prepare("".join(head), src, KNOWN_COLUMNS, cmap, column_setting)
        prepared = prep.text.splitlines(keepends=True)
        first_row = [] if seen < 2 or not prepared[-1].strip() else [head[-1]]  # not a units row: a data row
        head_text = "".join(prepared[:-1] if first_row else prepared)
        notices[:0] = prep.notices
        line_no, rows_before, chunk = len(head) - len(first_row), 0, list(first_row)
        said = set(notices)

        def parse(chunk_lines, gap_lines):
            nonlocal rows_before
            body = "".join(chunk_lines)
            if '"' in body:
                fail(src, f"a quoted field in a streamed survey (over {stream_above / MiB:g} MiB; lines "
                          f"{gap_lines + 1}-{gap_lines + len(chunk_lines)}): give one row per line, or split the file")
            try:
                frame, new = parse_contract_text(head_text + body, src, require_reference, prep.convert, column_setting,
                                                 gap=(len(head_text), gap_lines - head_text.count("\n")))
            except DataError as e:
                raise _shift_rows(e, rows_before) from None
            rows_before += len(frame)
            fresh = [n for n in new if n not in said]
            said.update(fresh)
            return frame, fresh

        try:
            first = True
            for ln in lines:
                chunk.append(ln)
                if len(chunk) >= chunk_rows:
                    frame, fresh = parse(chunk, line_no)
                    line_no += len(chunk)
                    yield Recording(frame, meta, (notices if first else []) + fresh, field, src)
                    chunk, first = [], False
            if chunk or first:
                frame, fresh = parse(chunk, line_no)
                ended_nl = not chunk or chunk[-1].endswith(("\n", "\r"))
                tail = [] if ended_nl else [f"{src}: the file does not end with a newline; check that its last row "
                                            f"(row {rows_before}) is complete"]
                yield Recording(frame, meta, (notices if first else []) + fresh + tail, field, src)
        except UnicodeDecodeError as e:
            fail(src, f"not UTF-8 text ({e.reason}) after line {line_no}; give a contract CSV")
