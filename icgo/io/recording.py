"""Data contract I/O: CSV + ``<name>.meta.json``, validation, real-device converters.

The contract (DESIGN.md, "Data contract"; details and error messages in
``docs/data.md``):

* CSV columns: ``station`` (int), ``gx, gy, gz`` (g, gravity vector in the tool
  frame: a vertical tool reads ``gz = +1``), ``bx, by, bz`` (nT),
  ``azimuth_deg, inclination_deg`` (reference attitude, when known); optional
  ``toolface_deg``, ``group`` (int; rows of one group share the true direction,
  used when no reference attitude is known), ``time_s``, ``wx, wy, wz`` (gyro,
  deg/h), ``temperature_c``, ``md`` (measured depth along the hole, m; ``depth_m`` reads as ``md``).
* Field exports (:mod:`icgo.io.columns`): names matched case-insensitively, a column map
  (``columns={"gx": "Accel X"}`` or a mapping file), ``#`` comment lines, a units row under the
  header (converted into these units).
* Metadata JSON: ``total_field_nT``, ``dip_deg``, ``declination_deg``,
  ``gravity_g``; or ``latitude``, ``longitude``, ``altitude_km``, ``date`` from
  which :func:`icgo.physics.field.reference_field` computes the field; descriptive
  ``name``, ``source``, ``license``, ``description``.

Bad input raises :class:`icgo.core.errors.DataError` (a ``ValueError``) whose message is one
line naming the file, row and column. Unknown columns and metadata keys are
kept and listed in ``Recording.notices``. Writes are atomic (temp file in the
same directory + ``os.replace``). Host-side numpy/pandas code, not jitted.

This module reads (:func:`read_recording`, :func:`read_meta`), checks in memory (:func:`validate`) and writes
(:func:`write_recording`) a recording; the parts: the columns, keys and limits (:mod:`icgo.io.schema`), the
checks (:mod:`icgo.io.checks`), the CSV text's two readers (:mod:`icgo.io.csv_text`), the bundled
circuitpython-mag-cal devices (:mod:`icgo.io.mag_cal_bundled`).

Command line: ``python -m icgo.io check FILE.csv|FILE.json`` (JSON: :mod:`icgo.io.mag_cal_json`) and
``python -m icgo.io export-mag-cal OUTDIR``.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from icgo.io import columns as export
from icgo.io.checks import check_frame, check_meta, coerce_frame
from icgo.io.csv_text import parse_contract_text
from icgo.io.files import read_text_bounded
from icgo.io.schema import KNOWN_COLUMNS, MAX_CSV_BYTES, MAX_META_BYTES, REFERENCE_COLUMNS, ReferenceField, fail


class Recording(NamedTuple):
    """A recording in the data contract.

    frame: DataFrame, one row per shot; contract columns first, in
        ``KNOWN_COLUMNS`` order, then unknown columns as given.
    meta: the metadata dict as given (unknown keys kept).
    notices: one-line remarks (unknown columns/keys, disagreements).
    field: the reference field, or None when the metadata has none.
    source: where it came from (a path or a description).
    """

    frame: pd.DataFrame
    meta: dict
    notices: list
    field: ReferenceField | None
    source: str

    @property
    def G(self) -> np.ndarray:
        """Gravity in the tool frame, (n, 3) float64, g."""
        return self.frame[["gx", "gy", "gz"]].to_numpy(np.float64)

    @property
    def B(self) -> np.ndarray:
        """Magnetic field in the tool frame, (n, 3) float64, nT."""
        return self.frame[["bx", "by", "bz"]].to_numpy(np.float64)

    @property
    def has_reference(self) -> bool:
        """True when the reference attitude columns are present."""
        return all(c in self.frame.columns for c in REFERENCE_COLUMNS)

    def toolface_deg(self) -> np.ndarray:
        """Gravity toolface from G (deg, [0, 360)), never from a toolface column."""
        from icgo.physics.frames import toolface_from_g

        return np.asarray(toolface_from_g(self.G), np.float64)


def validate(frame: pd.DataFrame, meta: dict | None = None, source: str = "<frame>", *,
             require_reference: bool = True) -> Recording:
    """Check an in-memory frame and metadata against the contract.

    Args:
        frame: DataFrame with the contract columns (units as in the contract).
        meta: metadata dict (None means ``{}``).
        source: name used in error messages and notices.
        require_reference: False accepts a frame with neither the reference attitude nor
            a ``group`` column (a new survey to correct, where the attitude is the unknown).
    Returns:
        Recording with typed columns (station/group int64, others float64).
    Raises:
        DataError: one line naming source, row and column.
    """
    if not isinstance(frame, pd.DataFrame):
        fail(source, f"expected a pandas DataFrame, got {type(frame).__name__}")
    names = [str(c) for c in frame.columns]
    dup = sorted({c for c in names if names.count(c) > 1})
    if dup:
        fail(source, f"duplicate column(s) {', '.join(dup)}")
    frame = frame.set_axis(names, axis=1).reset_index(drop=True)
    notices: list[str] = []
    line_of = lambda i: i + 2  # noqa: E731  (line in the CSV this frame would be written to)
    typed = check_frame(coerce_frame(frame, source, line_of), source, line_of, notices, require_reference)
    meta = {} if meta is None else meta
    field = check_meta(meta, source, notices)
    return Recording(typed, meta, notices, field, source)


# ------------------------------------------------------------------ reading
def meta_path_for(csv_path) -> Path:
    """``dir/name.csv`` -> ``dir/name.meta.json``."""
    p = Path(csv_path)
    stem = p.name[:-4] if p.name.lower().endswith(".csv") else p.name
    return p.with_name(stem + ".meta.json")


def column_map(columns=None, columns_file=None, setting: str = "columns") -> dict[str, str]:
    """One column map from a front door's settings: the entries of ``columns_file`` (JSON or YAML), then
    ``columns`` over them (:mod:`icgo.io.columns`).

    Raises:
        SettingError: one line naming the setting (a key that is not a contract column, a bad file).
    """
    base = {} if columns_file in (None, "") else export.load_column_map(columns_file, KNOWN_COLUMNS,
                                                                       f"{setting}_file")
    return base | export.check_column_map(columns, KNOWN_COLUMNS, setting)


def read_recording(csv_path, meta_path=None, *, require_meta: bool = True, require_reference: bool = True,
                   columns=None, column_setting: str = "columns", max_bytes: int = MAX_CSV_BYTES,
                   lazy: bool = False) -> Recording:
    """Read and validate a contract CSV and its ``<name>.meta.json``.

    Args:
        csv_path: path of the CSV.
        meta_path: metadata path; default ``<name>.meta.json`` beside the CSV.
        require_meta: if False, a missing metadata file reads as ``{}``
            (with a notice) instead of raising.
        require_reference: False accepts a survey without the reference attitude
            and without groups (see :func:`validate`).
        columns: a column map ``{contract column: export column}`` for a field export
            (:mod:`icgo.io.columns`; :func:`column_map` builds one from settings and a file).
        column_setting: how the caller names the column map, for the hints in errors
            (``columns``, ``dataset.columns``).
        max_bytes: the largest file read (default :data:`MAX_CSV_BYTES`; a larger survey streams through
            :func:`icgo.io.stream.read_chunks`).
        lazy: list every failure of the file at once (``python -m icgo.io check``): the CSV's checks each on their own
            (:class:`icgo.io.checks.Lazy`) and the metadata read even where the CSV fails;
            :class:`icgo.io.checks.DataErrors` (a DataError whose text is the first failure, the one the doors give)
            holds them all.
    Returns:
        Recording; ``notices`` say which export columns were mapped and which units converted.
    Raises:
        DataError: one line naming the file, row (and its line) and column.
        SettingError: a column map whose key is not a contract column.
    """
    csv_path = Path(csv_path)
    src = str(csv_path)
    text = read_text_bounded(csv_path, max_bytes, "a contract CSV")  # a FIFO, a device, a huge file: refused
    if text.strip() == "":
        fail(src, "empty file (no header, no rows)")
    cmap = export.check_column_map(columns, KNOWN_COLUMNS, column_setting)
    if lazy:
        return _read_lazy(csv_path, meta_path, text, cmap, require_meta, require_reference, column_setting)
    prep = export.prepare(text, src, KNOWN_COLUMNS, cmap, column_setting)
    text = prep.text
    if text.strip() == "":
        fail(src, "only comment lines (lines starting with #): no header, no rows")
    typed, notices = parse_contract_text(text, src, require_reference, prep.convert, column_setting)
    notices[:0] = prep.notices
    if not text.endswith(("\n", "\r")):  # a cut-off write leaves no newline: say so, naming the last row
        notices.append(f"{src}: the file does not end with a newline; check that its last row (row {len(typed)}) "
                       f"is complete")
    del text
    meta, field = read_meta(csv_path, meta_path, require_meta, notices)
    return Recording(typed, meta, notices, field, src)


def _read_lazy(csv_path: Path, meta_path, text: str, cmap: dict, require_meta: bool, require_reference: bool,
               column_setting: str) -> Recording:
    """:func:`read_recording` with every failure kept (``lazy=True``): the CSV's (those after a failure of the
    header's names or units row cannot be judged and are not run) and the metadata's, together."""
    from icgo.io.checks import DataErrors, Lazy, guard

    src, lazy, notices, typed = str(csv_path), Lazy(), [], None

    def csv_part():
        nonlocal typed
        prep = export.prepare(text, src, KNOWN_COLUMNS, cmap, column_setting)
        if prep.text.strip() == "":
            fail(src, "only comment lines (lines starting with #): no header, no rows")
        typed, found = parse_contract_text(prep.text, src, require_reference, prep.convert, column_setting, Lazy())
        notices.extend(prep.notices + found)
        if not prep.text.endswith(("\n", "\r")):
            notices.append(f"{src}: the file does not end with a newline; check that its last row (row {len(typed)}) "
                           f"is complete")

    guard(lazy, (), csv_part)
    meta = {}
    field = None

    def meta_part():
        nonlocal meta, field
        meta, field = read_meta(csv_path, meta_path, require_meta, notices)

    guard(lazy, (), meta_part)
    if lazy.errors:
        raise DataErrors(list(dict.fromkeys(lazy.errors)))
    return Recording(typed, meta, notices, field, src)


def read_meta(csv_path, meta_path=None, require_meta: bool = True, notices: list | None = None):
    """(metadata dict, reference field or None) of a CSV's ``<name>.meta.json`` (or ``meta_path``), checked.

    A missing file reads as ``{}`` with a notice when ``require_meta`` is False. Raises DataError (one line)."""
    notices = [] if notices is None else notices
    mpath = Path(meta_path) if meta_path is not None else meta_path_for(csv_path)
    msrc = str(mpath)
    if mpath.exists() and not mpath.is_file():
        fail(str(mpath), "not a regular file (a directory, pipe or device); give a JSON file")
    if not mpath.exists():
        if require_meta:
            fail(msrc, "metadata file not found (the contract needs it beside the CSV; "
                        "write {} if nothing is known)")
        notices.append(f"{msrc}: no metadata file; read as {{}}")
        meta = {}
    else:
        mtext = read_text_bounded(mpath, MAX_META_BYTES, "a metadata JSON")
        if mtext.strip() == "":
            fail(msrc, "empty metadata file (write {} if nothing is known)")
        try:
            meta = json.loads(mtext, parse_constant=lambda c: fail(msrc, f"{c} is not allowed in metadata"))
        except json.JSONDecodeError as e:
            fail(msrc, f"invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}")
        except RecursionError:
            fail(msrc, "metadata nested too deeply to read (the contract's metadata is a flat JSON object)")
    return meta, check_meta(meta, msrc, notices)


# ------------------------------------------------------------------ writing
def atomic_write_texts(items: list[tuple[Path, str]]) -> None:
    """Write every (path, text) to a temp file in its directory, then os.replace each.

    All temp files are complete and fsynced before any target is replaced, so a
    failure while writing leaves every existing target untouched (and no temp
    file behind).
    """
    temps: list[tuple[str, Path]] = []
    try:
        for path, text in items:
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
            temps.append((tmp, path))
            with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            mode = path.stat().st_mode & 0o777 if path.exists() else 0o644
            os.chmod(tmp, mode)
        for tmp, path in temps:
            os.replace(tmp, path)
    finally:
        for tmp, _ in temps:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)


def write_recording(csv_path, frame: pd.DataFrame, meta: dict | None = None, *,
                    require_reference: bool = True) -> Recording:
    """Validate, then atomically write ``csv_path`` and ``<name>.meta.json``.

    Args:
        csv_path: target CSV path (its directory must exist).
        frame: DataFrame in contract units.
        meta: metadata dict (None means ``{}``).
        require_reference: see :func:`validate`.
    Returns:
        The validated Recording that was written.
    Raises:
        DataError: the frame or metadata breaks the contract (nothing written).
    """
    csv_path = Path(csv_path)
    rec = validate(frame, meta, source=f"{csv_path} (to write)", require_reference=require_reference)
    # repr-exact float formatting: pandas writes the shortest string that round-trips.
    csv_text = rec.frame.to_csv(index=False, lineterminator="\n")
    try:
        meta_text = json.dumps(rec.meta, indent=2, allow_nan=False) + "\n"
    except (TypeError, ValueError) as e:
        fail(f"{meta_path_for(csv_path)} (to write)", f"metadata is not JSON-serialisable: {e}")
    if not csv_path.parent.is_dir():
        fail(str(csv_path), f"directory {csv_path.parent} does not exist")
    atomic_write_texts([(csv_path, csv_text), (meta_path_for(csv_path), meta_text)])
    return rec._replace(source=str(csv_path))
