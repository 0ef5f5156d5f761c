"""The data contract's checks: a frame's columns, values and units, and its metadata (DESIGN.md, "Data contract").

:func:`check_columns` checks a header, :func:`check_frame` a frame whose contract columns are float64 (NaN,
integers, ranges, units, per-row units; notices for unknown columns and disagreeing angle columns),
:func:`coerce_frame` makes an in-memory frame's contract columns float64, and :func:`check_meta` checks the
metadata and returns the reference field. Limits: :mod:`icgo.io.schema`; every refusal is one
:class:`icgo.core.errors.DataError` line (:func:`icgo.io.schema.fail`). Host-side numpy/pandas code.
"""

from __future__ import annotations

import datetime as _dt
import math

import numpy as np
import pandas as pd

from icgo.core.errors import DataError
from icgo.io import columns as export
from icgo.io.schema import (
    ANGLE_COLUMNS,
    ANGLE_RANGE_DEG,
    B_MEDIAN_RANGE_NT,
    DESCRIPTIVE_KEYS,
    FIELD_KEYS,
    G_MEDIAN_RANGE_G,
    GYRO_COLUMNS,
    INCLINATION_TOL_DEG,
    INTEGER_COLUMNS,
    KNOWN_COLUMNS,
    KNOWN_META_KEYS,
    MAX_ID,
    REFERENCE_COLUMNS,
    REQUIRED_COLUMNS,
    ROW_FACTOR_B,
    ROW_FACTOR_G,
    STANDARD_GRAVITY,
    TOOLFACE_TOL_DEG,
    W_MEDIAN_MIN_DEG_H,
    ReferenceField,
    fail,
    is_number,
)


class DataErrors(DataError):
    """Every failure of one file (:class:`Lazy`): its text is the first failure's line, ``lines`` holds them all."""

    def __init__(self, lines: list[str]):
        super().__init__(lines[0])
        self.lines = list(lines)


class Lazy:
    """Every failure of a file at once, as pandera's lazy validation lists them (``python -m icgo.io check``).

    The checks the doors run one after the other, stopping at the first failure, run here each on its own: a
    failure is kept and the columns it names are marked bad, so the checks that need those columns are skipped
    and every other one still runs. The first failure kept is the one the doors refuse the file with (the checks
    run in the doors' order), so the checker and the doors accept and refuse the same files.

    Attributes:
        errors: the failures (one line each, in the doors' order). bad: the columns a failure names.
    """

    def __init__(self):
        self.errors: list[str] = []
        self.bad: set = set()

    def skip(self, cols) -> bool:
        """Whether a check of ``cols`` is to be skipped (one of them failed already)."""
        return any(c in self.bad for c in cols)

    def raise_all(self) -> None:
        """:class:`DataErrors` of every failure kept (each once, in order), if any."""
        if self.errors:
            raise DataErrors(list(dict.fromkeys(self.errors)))


def guard(lazy: Lazy | None, cols, fn, *args) -> bool:
    """``fn(*args)``; without ``lazy`` a failure raises (the doors), with it the failure is kept and the columns
    ``cols`` marked bad (the checker). Returns whether it passed."""
    if lazy is None:
        fn(*args)
        return True
    try:
        fn(*args)
        return True
    except DataErrors as e:
        lazy.errors += e.lines
    except DataError as e:
        lazy.errors.append(str(e))
    lazy.bad.update(cols)
    return False


def _median_norm(frame: pd.DataFrame, cols) -> float:
    return float(np.median(np.linalg.norm(frame[list(cols)].to_numpy(np.float64), axis=1)))


def coerce_frame(frame: pd.DataFrame, source: str, line_of) -> pd.DataFrame:
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


def check_columns(cols: list, source: str, require_reference: bool = True, setting: str = "columns",
                  lazy: Lazy | None = None) -> None:
    """Header-level checks: required, paired and grouped columns (reference optional if not required).

    ``setting`` names the column map in the hint of a missing column (:func:`icgo.io.columns.missing_hint`).
    ``lazy``: keep every failure instead of raising the first (:class:`Lazy`).
    """
    missing = [c for c in REQUIRED_COLUMNS if c not in cols]

    def required():
        if missing:
            header = [str(c) for c in cols]
            hint = export.missing_hint(missing, header, KNOWN_COLUMNS, setting)
            others = [h for h in header if h not in KNOWN_COLUMNS and f"`{h}`" not in hint and repr(h) not in hint]
            more = export.synonym_hint(others, header + missing, KNOWN_COLUMNS, setting)
            fail(source, f"missing required column(s) {', '.join(missing)} (have: {', '.join(header)})" + hint
                 + (f"; other columns that look like contract columns{more}" if more else ""))

    ref = [c for c in REFERENCE_COLUMNS if c in cols]

    def reference():
        if len(ref) == 1:
            other = REFERENCE_COLUMNS[1 - REFERENCE_COLUMNS.index(ref[0])]
            fail(source, f"column '{ref[0]}' given without '{other}' (the reference attitude needs both)")
        if require_reference and not ref and "group" not in cols:
            fail(source, "missing required columns azimuth_deg, inclination_deg "
                          "(reference attitude; they may be left out only when a 'group' column is present)"
                         + export.missing_hint(list(REFERENCE_COLUMNS), [str(c) for c in cols], KNOWN_COLUMNS,
                                               setting).replace("; name the export", "; or name the export"))

    def gyro():
        have = [c for c in GYRO_COLUMNS if c in cols]
        if have and len(have) != 3:
            fail(source, f"gyro columns must come as wx, wy, wz together (have only {', '.join(have)})")

    guard(lazy, missing, required)
    guard(lazy, REFERENCE_COLUMNS, reference)
    guard(lazy, GYRO_COLUMNS, gyro)


def _check_values(v: np.ndarray, name: str, source: str, line_of) -> None:
    """One contract column's values: no NaN, finite, whole numbers within :data:`MAX_ID` for an id."""
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


def _check_range(a: np.ndarray, name: str, lo: float, hi: float, what: str, source: str, line_of) -> None:
    out = (a < lo) | (a > hi)
    if out.any():
        i = int(np.argmax(out))
        fail(source, f"{what}{float(a[i])!r} deg outside [{lo:g}, {hi:g}]", i + 1, name, line_of(i))


def check_frame(frame: pd.DataFrame, source: str, line_of, notices: list,
                require_reference: bool = True, convert: dict | None = None,
                setting: str = "columns", lazy: Lazy | None = None) -> pd.DataFrame:
    """Contract checks on a frame whose contract columns are float64; returns the typed frame.

    ``convert``: column -> (scale, offset, unit, where) from a units row or bracketed header
    (:func:`icgo.io.columns.prepare`), applied before any check. ``lazy``: every failure kept, the checks of the
    columns a failure names skipped, :class:`DataErrors` raised at the end (:class:`Lazy`); without it the first
    failure raises (the doors).
    """
    cols = list(frame.columns)
    if len(frame) == 0:
        fail(source, "no data rows (header only)")
    check_columns(cols, source, require_reference, setting, lazy)
    if convert:
        frame = frame.copy()
        for name, (scale, offset, *_) in convert.items():
            if name in cols:
                frame[name] = frame[name].to_numpy(np.float64) * scale + offset
    ok = (lambda *c: all(x in cols for x in c) and not lazy.skip(c)) if lazy is not None else (
        lambda *c: all(x in cols for x in c))

    for name in [c for c in KNOWN_COLUMNS if c in cols]:
        if ok(name):
            guard(lazy, (name,), _check_values, frame[name].to_numpy(np.float64), name, source, line_of)
    if ok("inclination_deg"):
        guard(lazy, ("inclination_deg",), _check_range, frame["inclination_deg"].to_numpy(np.float64),
              "inclination_deg", 0.0, 180.0, "inclination ", source, line_of)
    for name in ANGLE_COLUMNS:
        if ok(name):
            guard(lazy, (name,), _check_range, frame[name].to_numpy(np.float64), name, *ANGLE_RANGE_DEG, "",
                  source, line_of)
    for sensor in (("gx", "gy", "gz"), ("bx", "by", "bz"), GYRO_COLUMNS):
        if ok(*sensor):
            guard(lazy, sensor, _check_units, frame, source, sensor, convert or {})
    for sensor in (("gx", "gy", "gz"), ("bx", "by", "bz")):
        if ok(*sensor):
            guard(lazy, sensor, _check_row_units, frame, source, line_of, sensor)
    if lazy is not None:
        lazy.raise_all()

    typed = frame.copy()
    for name in INTEGER_COLUMNS:
        if name in cols:
            typed[name] = typed[name].to_numpy(np.float64).astype(np.int64)
    unknown = [c for c in cols if c not in KNOWN_COLUMNS]
    order = [c for c in KNOWN_COLUMNS if c in cols] + unknown
    typed = typed[order].reset_index(drop=True)
    if unknown:
        notices.append(f"{source}: unknown column(s) kept, not used: {', '.join(map(str, unknown))}"
                       + export.synonym_hint([str(c) for c in unknown], cols, KNOWN_COLUMNS, setting))
    _consistency_notices(typed, source, notices)
    return typed


def _check_row_units(frame: pd.DataFrame, source: str, line_of, cols=("gx", "gy", "gz")) -> None:
    """Every row's |G| (or |B|: ``cols``) within a factor of the median: a row in other units fails, named."""
    unit, factor = ("g", ROW_FACTOR_G) if cols[0] == "gx" else ("nT", ROW_FACTOR_B)
    norm = np.linalg.norm(frame[list(cols)].to_numpy(np.float64), axis=1)
    med = float(np.median(norm))
    off = (norm < med / factor) | (norm > med * factor)
    if off.any():
        i = int(np.argmax(off))
        fail(source, f"|{cols[0][0].upper()}| = {norm[i]:.6g} while the median is {med:.6g} {unit} "
                     f"({int(off.sum())} row(s) more than {factor:g}x off: rows in other units?)", i + 1,
             tuple(cols), line_of(i))


def _given_units(convert: dict, cols, unit: str) -> str:
    """The units a units row or a bracketed header name gave ``cols`` (converted before the check), named with
    where they were given, or ""."""
    conv = [convert[c] for c in cols if c in convert]
    if not conv:
        return ""
    scale, _, token, *where = conv[0]
    return (f"; the values were read as {token} by {where[0] if where else 'the units given'} and converted to "
            f"{unit} (x{scale:g}): as written they are {unit} already, so {where[0] if where else 'that unit'} "
            f"disagrees with the values")


def _check_units(frame: pd.DataFrame, source: str, cols=("gx", "gy", "gz"), convert: dict | None = None) -> None:
    """The median norm of one sensor (``cols``: gravity, field or gyro) in the contract's unit; where a units row
    or bracketed header converted the values, the refusal names it when the values as written fit the unit."""
    convert = convert or {}
    if cols[0] == "gx":
        g = _median_norm(frame, cols)
        lo, hi = G_MEDIAN_RANGE_G
        if not lo <= g <= hi:
            scale = convert[cols[0]][0] if cols[0] in convert else 1.0
            if scale != 1.0 and lo <= g / scale <= hi:
                hint = "expected about 1 g" + _given_units(convert, cols, "g")
            elif lo * STANDARD_GRAVITY <= g <= hi * STANDARD_GRAVITY:
                hint = f"looks like m/s^2: divide by {STANDARD_GRAVITY}, or give m/s^2 in a units row under the header"
            elif lo * 1000 <= g <= hi * 1000:
                hint = "looks like milli-g: divide by 1000"
            else:
                hint = "expected about 1 g"
            fail(source, f"median |G| = {g:.6g} is not in g ({hint})", "all rows", tuple(cols))
    elif cols[0] == "bx":
        b = _median_norm(frame, cols)
        lo, hi = B_MEDIAN_RANGE_NT
        if not lo <= b <= hi:
            scale = convert[cols[0]][0] if cols[0] in convert else 1.0
            if scale != 1.0 and lo <= b / scale <= hi:
                hint = "the geomagnetic field is about 22,000-67,000 nT" + _given_units(convert, cols, "nT")
            elif b < lo and lo <= b * 1e3 <= hi:
                hint = "looks like uT given as nT: multiply by 1000; or give the unit in a units row under the header, docs/data.md"
            elif b < lo and lo <= b * 1e5 <= hi:
                hint = "looks like Gauss given as nT: multiply by 100000; or give the unit in a units row under the header, docs/data.md"
            else:
                hint = "the geomagnetic field is about 22,000-67,000 nT"
            fail(source, f"median |B| = {b:.6g} is not in nT ({hint})", "all rows", tuple(cols))
    else:
        w = _median_norm(frame, cols)
        if w < W_MEDIAN_MIN_DEG_H:
            fail(source, f"median |W| = {w:.6g} is below the earth rate (15.04 deg/h): not deg/h "
                         "(rad/s or deg/s?)", "all rows", tuple(cols))


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


def check_meta(meta, source: str, notices: list) -> ReferenceField | None:
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
            finite = is_number(v) and math.isfinite(float(v))
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
    if is_number(v):
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
