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

Bad input raises :class:`DataError` (a ``ValueError``) whose message is one
line naming the file, row and column. Unknown columns and metadata keys are
kept and listed in ``Recording.notices``. Writes are atomic (temp file in the
same directory + ``os.replace``). Host-side numpy/pandas code, not jitted.

Command line: ``python -m icgo.io check FILE.csv|FILE.json`` (JSON: :mod:`icgo.io.mag_cal_json`) and
``python -m icgo.io export-mag-cal OUTDIR``.
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import io as _io
import json
import math
import os
import re
import tempfile
from importlib import resources
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from icgo.core.errors import DataError
from icgo.io import columns as export
from icgo.io.files import read_text_bounded

# ----------------------------------------------------------------- the schema
#: Largest contract CSV read (bytes; docs/data.md): the reader's peak memory is 7 to 13 times the file
#: (0.84 GB for 1 M rows x 10 columns on the fast path, 1.5 GB when the exact reader words an error).
MAX_CSV_BYTES = 256 << 20
#: Largest metadata file read (bytes).
MAX_META_BYTES = 1 << 20
SENSOR_COLUMNS = ("gx", "gy", "gz", "bx", "by", "bz")
REQUIRED_COLUMNS = ("station",) + SENSOR_COLUMNS
REFERENCE_COLUMNS = ("azimuth_deg", "inclination_deg")
GYRO_COLUMNS = ("wx", "wy", "wz")
OPTIONAL_COLUMNS = ("toolface_deg", "group", "time_s") + GYRO_COLUMNS + ("temperature_c", "md")
#: Contract columns in the order they are written.
KNOWN_COLUMNS = REQUIRED_COLUMNS + REFERENCE_COLUMNS + OPTIONAL_COLUMNS
INTEGER_COLUMNS = ("station", "group")
#: Largest id magnitude: every integer up to 2^53 is exact in float64 (and fits int64).
MAX_ID = 2**53
#: Attitude angles (deg) and the range they may take (a turn either side of [0, 360)).
ANGLE_COLUMNS = ("azimuth_deg", "toolface_deg")
ANGLE_RANGE_DEG = (-360.0, 720.0)
#: A row's |G| or |B| may differ from the median by at most this factor (a row in other units does not:
#: m/s^2 vs g is 9.8x, uT vs nT 1000x; a casing 0.5 m away changes |B| by a few percent).
ROW_FACTOR_G = 3.0
ROW_FACTOR_B = 10.0

FIELD_KEYS = ("total_field_nT", "dip_deg", "declination_deg", "gravity_g")
LOCATION_KEYS = ("latitude", "longitude", "altitude_km", "date")
DESCRIPTIVE_KEYS = ("name", "source", "license", "description", "instrument")
KNOWN_META_KEYS = FIELD_KEYS + LOCATION_KEYS + DESCRIPTIVE_KEYS

#: Standard gravity, m/s^2 per g.
STANDARD_GRAVITY = 9.80665
#: Accepted median |G| (g). Outside it the units are judged wrong (e.g. m/s^2).
G_MEDIAN_RANGE_G = (0.5, 1.5)
#: Accepted median |B| (nT). The geomagnetic field is 22,000-67,000 nT; raw
#: magnetometers with hard iron read up to a few times that. Below 1000 nT the
#: values are uT or Gauss given as nT.
B_MEDIAN_RANGE_NT = (1_000.0, 1_000_000.0)
#: Below this median |W| (deg/h) a 3-axis gyro cannot be in deg/h: the earth
#: rate alone is 15.04 deg/h (rad/s gives 7e-5, deg/s 4e-3).
W_MEDIAN_MIN_DEG_H = 1.0
#: Given toolface vs toolface from G: larger differences give a notice (deg).
TOOLFACE_TOL_DEG = 1.0
#: Reference inclination vs inclination from G: larger median gives a notice (deg).
INCLINATION_TOL_DEG = 5.0


class ReferenceField(NamedTuple):
    """Reference field of a recording.

    total_field_nT (nT), dip_deg (deg, positive down), declination_deg (deg,
    east of true north), gravity_g (g), origin: ``"metadata"`` or
    ``"field model"``.
    """

    total_field_nT: float
    dip_deg: float
    declination_deg: float
    gravity_g: float
    origin: str


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


# ------------------------------------------------------------------- helpers
def fail(source: str, msg: str, row: int | str | None = None, column: str | tuple | None = None,
          line: int | None = None):
    """Raise DataError "source, row R (line L), column 'c': msg" (row may be "all rows")."""
    where = [source]
    if isinstance(row, str):
        where.append(row)
    elif row is not None:
        where.append(f"row {row}" + (f" (line {line})" if line is not None else ""))
    if isinstance(column, tuple):
        where.append("columns " + ", ".join(f"'{c}'" for c in column))
    elif column is not None:
        where.append(f"column '{column}'")
    raise DataError(": ".join([", ".join(where), msg]))


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _median_norm(frame: pd.DataFrame, cols) -> float:
    return float(np.median(np.linalg.norm(frame[list(cols)].to_numpy(np.float64), axis=1)))


# ------------------------------------------------------------ column parsing
def _parse_columns(header: list[str], rows: list[list[str]], source: str, line_of) -> pd.DataFrame:
    """Text cells -> numeric DataFrame; first bad cell raises DataError."""
    data = {}
    for j, name in enumerate(header):
        cells = [r[j] for r in rows]
        if name in KNOWN_COLUMNS:
            data[name] = _to_float(cells, name, source, line_of)
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


def _coerce_frame(frame: pd.DataFrame, source: str, line_of) -> pd.DataFrame:
    """In-memory DataFrame -> float columns for the contract ones; non-numeric cells raise."""
    out = {}
    for name in frame.columns:
        col = frame[name]
        if name not in KNOWN_COLUMNS:
            out[name] = col.to_numpy()
            continue
        if pd.api.types.is_bool_dtype(col):
            fail(source, "boolean values where numbers are expected", None, name)
        num = pd.to_numeric(col, errors="coerce")
        bad = num.isna().to_numpy() & col.notna().to_numpy()
        if bad.any():
            i = int(np.argmax(bad))
            fail(source, f"non-numeric value {col.iloc[i]!r}", i + 1, name, line_of(i))
        out[name] = num.to_numpy(np.float64)
    return pd.DataFrame(out)


# --------------------------------------------------------------- validation
def _check_columns(cols: list, source: str, require_reference: bool = True, setting: str = "columns") -> None:
    """Header-level checks: required, paired and grouped columns (reference optional if not required).

    ``setting`` names the column map in the hint of a missing column (:func:`icgo.io.columns.missing_hint`).
    """
    missing = [c for c in REQUIRED_COLUMNS if c not in cols]
    if missing:
        fail(source, f"missing required column(s) {', '.join(missing)} (have: {', '.join(map(str, cols))})"
                     + export.missing_hint(missing, [str(c) for c in cols], KNOWN_COLUMNS, setting))
    ref = [c for c in REFERENCE_COLUMNS if c in cols]
    if len(ref) == 1:
        other = REFERENCE_COLUMNS[1 - REFERENCE_COLUMNS.index(ref[0])]
        fail(source, f"column '{ref[0]}' given without '{other}' (the reference attitude needs both)")
    if require_reference and not ref and "group" not in cols:
        fail(source, "missing required columns azimuth_deg, inclination_deg "
                      "(reference attitude; they may be left out only when a 'group' column is present)"
                     + export.missing_hint(list(REFERENCE_COLUMNS), [str(c) for c in cols], KNOWN_COLUMNS,
                                           setting).replace("; name the export", "; or name the export"))
    gyro = [c for c in GYRO_COLUMNS if c in cols]
    if gyro and len(gyro) != 3:
        fail(source, f"gyro columns must come as wx, wy, wz together (have only {', '.join(gyro)})")


def _check_frame(frame: pd.DataFrame, source: str, line_of, notices: list,
                 require_reference: bool = True, convert: dict | None = None,
                 setting: str = "columns") -> pd.DataFrame:
    """Contract checks on a frame whose contract columns are float64; returns the typed frame.

    ``convert``: column -> (scale, offset, unit) from a units row (:func:`icgo.io.columns.prepare`),
    applied before any check.
    """
    cols = list(frame.columns)
    if len(frame) == 0:
        fail(source, "no data rows (header only)")
    _check_columns(cols, source, require_reference, setting)
    if convert:
        frame = frame.copy()
        for name, (scale, offset, _) in convert.items():
            if name in cols:
                frame[name] = frame[name].to_numpy(np.float64) * scale + offset

    for name in [c for c in KNOWN_COLUMNS if c in cols]:
        v = frame[name].to_numpy(np.float64)
        nan = np.isnan(v)
        if nan.any():
            i = int(np.argmax(nan))
            fail(source, "NaN / missing value", i + 1, name, line_of(i))
        inf = ~np.isfinite(v)
        if inf.any():
            i = int(np.argmax(inf))
            fail(source, f"non-finite value {float(v[i])!r}", i + 1, name, line_of(i))
        if name in INTEGER_COLUMNS:
            frac = v != np.round(v)
            if frac.any():
                i = int(np.argmax(frac))
                fail(source, f"{float(v[i])!r} is not an integer", i + 1, name, line_of(i))
            big = np.abs(v) > MAX_ID
            if big.any():  # beyond 2^53 a float64 no longer holds every integer (and 1e300 is no int64)
                i = int(np.argmax(big))
                fail(source, f"{float(v[i])!r} is too large for an id (at most {MAX_ID:,} in magnitude)", i + 1,
                      name, line_of(i))

    if "inclination_deg" in cols:
        inc = frame["inclination_deg"].to_numpy(np.float64)
        out = (inc < 0.0) | (inc > 180.0)
        if out.any():
            i = int(np.argmax(out))
            fail(source, f"inclination {float(inc[i])!r} deg outside [0, 180]", i + 1, "inclination_deg", line_of(i))

    for name in ANGLE_COLUMNS:
        if name in cols:
            a = frame[name].to_numpy(np.float64)
            out = (a < ANGLE_RANGE_DEG[0]) | (a > ANGLE_RANGE_DEG[1])
            if out.any():
                i = int(np.argmax(out))
                fail(source, f"{float(a[i])!r} deg outside [{ANGLE_RANGE_DEG[0]:g}, {ANGLE_RANGE_DEG[1]:g}]", i + 1,
                      name, line_of(i))

    _check_units(frame, source)
    _check_row_units(frame, source, line_of)

    typed = frame.copy()
    for name in INTEGER_COLUMNS:
        if name in cols:
            typed[name] = typed[name].to_numpy(np.float64).astype(np.int64)
    unknown = [c for c in cols if c not in KNOWN_COLUMNS]
    order = [c for c in KNOWN_COLUMNS if c in cols] + unknown
    typed = typed[order].reset_index(drop=True)
    if unknown:
        notices.append(f"{source}: unknown column(s) kept, not used: {', '.join(map(str, unknown))}")
    _consistency_notices(typed, source, notices)
    return typed


def _check_row_units(frame: pd.DataFrame, source: str, line_of) -> None:
    """Every row's |G| and |B| within a factor of the median: a row in other units fails, named."""
    for cols, unit, factor in ((("gx", "gy", "gz"), "g", ROW_FACTOR_G), (("bx", "by", "bz"), "nT", ROW_FACTOR_B)):
        norm = np.linalg.norm(frame[list(cols)].to_numpy(np.float64), axis=1)
        med = float(np.median(norm))
        off = (norm < med / factor) | (norm > med * factor)
        if off.any():
            i = int(np.argmax(off))
            fail(source, f"|{cols[0][0].upper()}| = {norm[i]:.6g} while the median is {med:.6g} {unit} "
                          f"({int(off.sum())} row(s) more than {factor:g}x off: rows in other units?)", i + 1,
                  cols, line_of(i))


def _check_units(frame: pd.DataFrame, source: str) -> None:
    g = _median_norm(frame, ("gx", "gy", "gz"))
    lo, hi = G_MEDIAN_RANGE_G
    if not lo <= g <= hi:
        if lo * STANDARD_GRAVITY <= g <= hi * STANDARD_GRAVITY:
            hint = f"looks like m/s^2: divide by {STANDARD_GRAVITY}, or give m/s^2 in a units row under the header"
        elif lo * 1000 <= g <= hi * 1000:
            hint = "looks like milli-g: divide by 1000"
        else:
            hint = "expected about 1 g"
        fail(source, f"median |G| = {g:.6g} is not in g ({hint})", "all rows", ("gx", "gy", "gz"))
    b = _median_norm(frame, ("bx", "by", "bz"))
    lo, hi = B_MEDIAN_RANGE_NT
    if not lo <= b <= hi:
        if b < lo and lo <= b * 1e3 <= hi:
            hint = "looks like uT given as nT: multiply by 1000; or give the unit in a units row under the header, docs/data.md"
        elif b < lo and lo <= b * 1e5 <= hi:
            hint = "looks like Gauss given as nT: multiply by 100000; or give the unit in a units row under the header, docs/data.md"
        else:
            hint = "the geomagnetic field is about 22,000-67,000 nT"
        fail(source, f"median |B| = {b:.6g} is not in nT ({hint})", "all rows", ("bx", "by", "bz"))
    if "wx" in frame.columns:
        w = _median_norm(frame, GYRO_COLUMNS)
        if w < W_MEDIAN_MIN_DEG_H:
            fail(source, f"median |W| = {w:.6g} is below the earth rate (15.04 deg/h): not deg/h "
                          "(rad/s or deg/s?)", "all rows", GYRO_COLUMNS)


def _consistency_notices(frame: pd.DataFrame, source: str, notices: list) -> None:
    from icgo.physics.frames import NEAR_VERTICAL_DEG, angle_diff, inclination_from_g, toolface_from_g

    G = frame[["gx", "gy", "gz"]].to_numpy(np.float64)
    inc_g = np.asarray(inclination_from_g(G), np.float64)
    ok = (inc_g >= NEAR_VERTICAL_DEG) & (inc_g <= 180.0 - NEAR_VERTICAL_DEG)
    if "toolface_deg" in frame.columns and ok.any():
        d = np.abs(np.asarray(angle_diff(frame["toolface_deg"].to_numpy(np.float64), toolface_from_g(G))))
        d = np.where(ok, d, 0.0)
        if d.max() > TOOLFACE_TOL_DEG:
            i = int(np.argmax(d))
            notices.append(
                f"{source}: column 'toolface_deg' disagrees with the toolface from G, atan2(Gy, -Gx), "
                f"by up to {d[i]:.3g} deg (row {i + 1}; {int((d > TOOLFACE_TOL_DEG).sum())} row(s) over "
                f"{TOOLFACE_TOL_DEG} deg); kept, but icgo computes toolface from G"
            )
    if "inclination_deg" in frame.columns:
        d = np.abs(frame["inclination_deg"].to_numpy(np.float64) - inc_g)
        med = float(np.median(d))
        if med > INCLINATION_TOL_DEG:
            notices.append(
                f"{source}: column 'inclination_deg' differs from the inclination from G by {med:.3g} deg "
                "(median); if G is specific force (a vertical tool reads gz = -1 g), negate it"
            )


def _check_meta(meta, source: str, notices: list) -> ReferenceField | None:
    """Metadata checks; returns the reference field (or None when none is given)."""
    if not isinstance(meta, dict):
        fail(source, f"metadata must be a JSON object, got {type(meta).__name__}")
    for k in meta:
        if not isinstance(k, str):
            fail(source, f"metadata key {k!r} is not a string")
    numeric = [k for k in FIELD_KEYS + ("latitude", "longitude", "altitude_km") if k in meta]
    for k in numeric:
        v = meta[k]
        try:
            finite = _is_number(v) and math.isfinite(float(v))
        except OverflowError:  # an integer with hundreds of digits
            finite = False
        if not finite:
            shown = repr(v) if len(repr(v)) <= 40 else repr(v)[:20] + f"... ({len(repr(v))} characters)"
            fail(source, f"metadata key '{k}': expected a finite number, got {shown}")

    def in_range(k, lo, hi, unit, hint=""):
        if k in meta and not lo <= float(meta[k]) <= hi:
            fail(source, f"metadata key '{k}': {meta[k]!r} outside [{lo}, {hi}] {unit}{hint}")

    if "total_field_nT" in meta:
        f = float(meta["total_field_nT"])
        lo, hi = B_MEDIAN_RANGE_NT
        if f < lo and lo <= f * 1e3:
            hint = " (looks like uT: multiply by 1000)"
        elif f < lo and lo <= f * 1e5:
            hint = " (looks like Gauss: multiply by 100000)"
        else:
            hint = ""
        in_range("total_field_nT", lo, hi, "nT", hint)
    in_range("dip_deg", -90.0, 90.0, "deg")
    in_range("declination_deg", -180.0, 360.0, "deg")
    g_hint = ""
    if "gravity_g" in meta and float(meta["gravity_g"]) > 5:
        g_hint = f" (looks like m/s^2: divide by {STANDARD_GRAVITY})"
    in_range("gravity_g", *G_MEDIAN_RANGE_G, "g", g_hint)
    in_range("latitude", -90.0, 90.0, "deg")
    in_range("longitude", -180.0, 360.0, "deg")
    in_range("altitude_km", -12.0, 1000.0, "km")
    for k in DESCRIPTIVE_KEYS:
        if k in meta and not isinstance(meta[k], str):
            fail(source, f"metadata key '{k}': expected a string, got {meta[k]!r}")
    if "date" in meta:
        _check_date(meta["date"], source)

    unknown = [k for k in meta if k not in KNOWN_META_KEYS]
    if unknown:
        notices.append(f"{source}: unknown metadata key(s) kept, not used: {', '.join(unknown)}")

    gravity = float(meta.get("gravity_g", 1.0))
    has_field = [k for k in ("total_field_nT", "dip_deg") if k in meta]
    has_loc = [k for k in ("latitude", "longitude", "date") if k in meta]
    if len(has_field) == 1:
        other = "dip_deg" if has_field[0] == "total_field_nT" else "total_field_nT"
        fail(source, f"metadata key '{has_field[0]}' given without '{other}' (the reference field needs both)")
    if has_field:
        if has_loc:
            notices.append(f"{source}: both field values and a site are given; using total_field_nT, "
                           "dip_deg, declination_deg as given")
        if "declination_deg" not in meta:
            notices.append(f"{source}: no declination_deg: taken as 0 (azimuths are magnetic)")
        return ReferenceField(float(meta["total_field_nT"]), float(meta["dip_deg"]),
                              float(meta.get("declination_deg", 0.0)), gravity, "metadata")
    if has_loc or "altitude_km" in meta:
        missing = [k for k in ("latitude", "longitude", "date") if k not in meta]
        if missing:
            fail(source, f"metadata: site given without {', '.join(missing)} "
                          "(the field model needs latitude, longitude and date)")
        if "declination_deg" in meta:
            notices.append(f"{source}: declination_deg without total_field_nT/dip_deg is ignored; "
                           "the field model's declination is used")
        from icgo.physics.field import reference_field  # lazy: io must not pull the field model in

        try:
            r = reference_field(meta["latitude"], meta["longitude"], meta.get("altitude_km", 0.0), meta["date"])
        except ValueError as e:
            fail(source, f"metadata: field model failed: {e}")
        from icgo.physics.field import FIELD_MODEL_YEARS, decimal_year

        year = decimal_year(meta["date"])
        if not FIELD_MODEL_YEARS[0] <= year < FIELD_MODEL_YEARS[1]:
            notices.append(f"{source}: date {meta['date']!r} lies outside the field model's years "
                           f"({FIELD_MODEL_YEARS[0]:g}-{FIELD_MODEL_YEARS[1]:g}, WMM2020 and WMM2025): its field "
                           f"is extrapolated and may be off by hundreds of nT; give total_field_nT and dip_deg")
        return ReferenceField(r.total_field_nT, r.dip_deg, r.declination_deg, gravity, "field model")
    if "declination_deg" in meta:
        notices.append(f"{source}: declination_deg without total_field_nT/dip_deg: no reference field")
    return None


def _check_date(v, source: str) -> None:
    if _is_number(v):
        if not 1900.0 <= float(v) <= 2100.0:
            fail(source, f"metadata key 'date': decimal year {v!r} outside [1900, 2100]")
        return
    if isinstance(v, str):
        try:
            _dt.date.fromisoformat(v.strip())
            return
        except ValueError:
            pass
    fail(source, f"metadata key 'date': {v!r} is neither YYYY-MM-DD nor a decimal year")


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
    typed = _check_frame(_coerce_frame(frame, source, line_of), source, line_of, notices, require_reference)
    meta = {} if meta is None else meta
    field = _check_meta(meta, source, notices)
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
                   columns=None, column_setting: str = "columns", max_bytes: int = MAX_CSV_BYTES) -> Recording:
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


def parse_contract_text(text: str, src: str, require_reference: bool, convert=None,
                        setting: str = "columns") -> tuple[pd.DataFrame, list]:
    """(checked frame, notices) of a contract CSV's text (comments blanked, header resolved: :mod:`icgo.io.columns`):
    pandas' C parser where it can, the exact reader where it cannot (and to word every error)."""
    notices: list[str] = []
    typed = _read_fast(text, src, notices, require_reference, convert=convert, setting=setting)
    if typed is None:
        notices = []
        typed = _read_exact(text, src, notices, require_reference, convert=convert, setting=setting)
    return typed, notices


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
    return meta, _check_meta(meta, msrc, notices)


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
    header = next((r for r in csv.reader(_io.StringIO(text)) if r and not (len(r) == 1 and r[0].strip() == "")), None)
    if header is None:
        return None
    header = [h.strip() for h in header]
    if "" in header or len(set(header)) != len(header):
        return None
    try:
        _check_columns(header, src, require_reference, setting)
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
        return _check_frame(frame, src, lambda i: i + 2, notices, require_reference, convert, setting)
    except DataError:
        return None


def _read_exact(text: str, src: str, notices: list, require_reference: bool, convert=None,
                setting: str = "columns") -> pd.DataFrame:
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
        _check_columns(header, src, require_reference, setting)
    rows = [r for _, r in body]
    line_of = lambda i: body[i][0]  # noqa: E731
    frame = _parse_columns(header, rows, src, line_of) if rows else pd.DataFrame(columns=header)
    return _check_frame(frame, src, line_of, notices, require_reference, convert, setting)


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


# ------------------------------------------- real data: circuitpython-mag-cal
MAG_CAL_VERSION = "1.4.1"
MAG_CAL_LICENSE = "MIT, Copyright (c) 2022 Phil Underwood for Underwood Underground"
#: Device frame of the mag_cal fixtures: X right, Y the pointing axis, Z up
#: (mag_cal docs/howto.rst). Tool frame: z = device Y (pointing axis), x = device
#: Z (up, so a level upright device has toolface 0), y = device X; right-handed
#: since Z x X = Y.
MAG_CAL_DEVICE_TO_TOOL = (2, 0, 1)  # tool[i] = device[MAG_CAL_DEVICE_TO_TOOL[i]]
#: nT per uT (circuitpython-mag-cal reports the field in uT).
UT_TO_NT = 1000.0
#: Shots rolled about the pointing axis in one direction (mag_cal read_fixture: mag[8:16], mag[16:24]).
MAG_CAL_RUNS = ((8, 16), (16, 24))
MAG_CAL_SHOTS = 24


def _mag_cal_dir():
    return resources.files("icgo").joinpath("data").joinpath("mag_cal")


def mag_cal_devices() -> list[str]:
    """Names of the 9 vendored circuitpython-mag-cal devices (``['ab', 'ai', ...]``)."""
    return sorted(p.name[:-5] for p in _mag_cal_dir().iterdir() if p.name.endswith(".json"))


def _fixture_triples(values, src: str, key: str) -> np.ndarray:
    """mag_cal's read_fixture: drop None/NaN padding, reshape to (n, 3)."""
    if not isinstance(values, list):
        fail(src, f"'shots.{key}' is not a list")
    kept = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    bad = next((i for i, v in enumerate(kept) if not _is_number(v) or not math.isfinite(v)), None)
    if bad is not None:
        fail(src, f"'shots.{key}' value {bad} is not a finite number: {str(kept[bad])[:40]!r}")
    if len(kept) % 3:
        fail(src, f"'shots.{key}' has {len(kept)} values, not a multiple of 3")
    return np.asarray(kept, np.float64).reshape(-1, 3)


def device_to_tool(v) -> np.ndarray:
    """mag_cal device frame (X right, Y pointing, Z up) -> tool frame, (N, 3) (:data:`MAG_CAL_DEVICE_TO_TOOL`)."""
    return np.asarray(v, np.float64)[:, list(MAG_CAL_DEVICE_TO_TOOL)]


def fixture_shots(d, src: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """mag_cal's fixture layout (``{"shots": {"mag", "grav"}}``, device frame, g and uT) -> tool frame.

    Returns:
        (G (n, 3) g, B (n, 3) nT, group): for the peer's 24 shots, shot k < 8 is its own group k and
        shots 8-15 and 16-23 are groups 8 and 9 (rolled about the pointing axis, mag_cal ``read_fixture``);
        for any other count None (the rolls are then found from the data, :mod:`icgo.io.mag_cal_json`).
    Raises:
        DataError: one line naming ``src``.
    """
    shots = d.get("shots") if isinstance(d, dict) else None
    if not isinstance(shots, dict) or "mag" not in shots or "grav" not in shots:
        fail(src, "no 'shots' with 'mag' and 'grav'")
    mag = _fixture_triples(shots["mag"], src, "mag")
    grav = _fixture_triples(shots["grav"], src, "grav")
    if len(mag) != len(grav) or not len(mag):
        fail(src, f"'shots.mag' has {len(mag)} readings and 'shots.grav' {len(grav)}: one of each per shot")
    group = None
    if len(mag) == MAG_CAL_SHOTS:
        group = np.arange(MAG_CAL_SHOTS)
        for gid, (a, b) in zip((8, 9), MAG_CAL_RUNS):
            group[a:b] = gid
    # fixtures are in g already (median |G| ~ 1.00), gravity pointing down; uT -> nT
    return device_to_tool(grav), device_to_tool(mag) * UT_TO_NT, group


def load_mag_cal_device(name: str) -> Recording:
    """One real device of circuitpython-mag-cal 1.4.1 as a contract Recording.

    24 static shots of raw accelerometer (g) and magnetometer (uT -> nT, x1000)
    readings, axes permuted from the device frame to the tool frame
    (``MAG_CAL_DEVICE_TO_TOOL``). Groups: shot k < 8 is its own group k (eight
    distinct orientations); shots 8-15 are group 8 and shots 16-23 group 9 (rolled
    about the pointing axis, one true direction each). ``station`` = shot index
    0-23. No reference attitude, no field metadata. An unknown name raises DataError.

    Args:
        name: one of :func:`mag_cal_devices`.
    Returns:
        Recording (24 rows).
    """
    names = mag_cal_devices()
    if name not in names:
        fail("mag_cal", f"unknown device {name!r}; choose one of {', '.join(names)}")
    res = _mag_cal_dir().joinpath(f"{name}.json")
    src = f"icgo/data/mag_cal/{name}.json"
    d = json.loads(res.read_text(encoding="utf-8"))
    G, B, group = fixture_shots(d, src)
    frame = pd.DataFrame({
        "station": np.arange(MAG_CAL_SHOTS),
        "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
        "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2],
        "group": group,
    })
    meta = {
        "name": str(d.get("name", name)),
        "source": f"circuitpython-mag-cal {MAG_CAL_VERSION} sdist, tests/fixtures/cal_data/{name}.json",
        "license": MAG_CAL_LICENSE,
        "description": "raw (uncalibrated) static shots; device axes (X right, Y pointing, Z up) "
                       "mapped to tool (x, y, z) = (Z, X, Y); mag uT x1000 -> nT; shots 8-15 "
                       "(group 8) and 16-23 (group 9) rolled about the pointing axis",
    }
    return validate(frame, meta, source=src)
