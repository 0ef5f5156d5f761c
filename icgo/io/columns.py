"""Field exports into the data contract: column names, a column map, comment lines and a units row.

Survey and MWD exports rarely carry the contract's exact header. This module turns what they look
like into what :func:`icgo.io.recording.read_recording` checks, and says what it did:

* **Names** are matched without regard to case or surrounding spaces (``Gx``, ``GX `` -> ``gx``);
  a name with its unit in brackets (``Bx [uT]``, ``Inclination_deg (rad)``) is the contract column
  with that unit. ``depth_m`` is read as ``md`` (:data:`ALIASES`).
* **A column map** ``{contract column: export column}`` names the columns whose names differ
  otherwise (``{"gx": "Accel X"}``); on the Hydra front doors ``columns.gx='Accel X'``, or a JSON /
  YAML mapping file (:func:`load_column_map`).
* **Comment lines** (first non-blank character ``#``) are skipped anywhere in the file; line
  numbers in errors stay those of the file.
* **A units row** directly under the header (``,g,g,g,uT,uT,uT,deg,deg``) is read, checked against
  each column's kind and converted into the contract's units (:data:`UNITS`): magnetic field
  nT, uT, G, mG, T, gamma; gravity g, mg, m/s^2, ft/s^2; angles deg, rad; gyro rates deg/h,
  deg/s, rad/s; time s, ms, min, h; temperature C, K, F; depth m, ft. An empty cell keeps the
  contract's unit.

Nothing else is guessed: without a units row or a bracketed unit the reader's unit checks run as
before (a field in uT given as nT is still refused). A missing required column's error names the
likely export column (:func:`missing_hint`). Host-side string handling only.
"""

from __future__ import annotations

import csv
import io as _io
import json
import math
import re
from collections.abc import Mapping
from pathlib import Path

from icgo.core.errors import DataError, SettingError

#: Export names read as another contract column without a map.
ALIASES = {"depth_m": "md"}

_G0 = 9.80665  # m/s^2 per g (standard gravity; icgo.io.schema.STANDARD_GRAVITY)
_B = {"nt": 1.0, "nanotesla": 1.0, "gamma": 1.0, "ut": 1e3, "µt": 1e3, "μt": 1e3, "microtesla": 1e3,
      "g": 1e5, "gs": 1e5, "gauss": 1e5, "mg": 100.0, "milligauss": 100.0, "t": 1e9, "tesla": 1e9, "mt": 1e6}
_G = {"g": 1.0, "gn": 1.0, "g0": 1.0, "mg": 1e-3, "milli-g": 1e-3, "m/s^2": 1 / _G0, "m/s2": 1 / _G0,
      "m/s²": 1 / _G0, "ms-2": 1 / _G0, "m.s-2": 1 / _G0, "mps2": 1 / _G0, "ft/s^2": 0.3048 / _G0,
      "ft/s2": 0.3048 / _G0}
_ANGLE = {"deg": 1.0, "degree": 1.0, "degrees": 1.0, "°": 1.0, "rad": 180.0 / math.pi, "radian": 180.0 / math.pi,
          "radians": 180.0 / math.pi}
_RATE = {"deg/h": 1.0, "deg/hr": 1.0, "°/h": 1.0, "°/hr": 1.0, "dph": 1.0, "deg/s": 3600.0, "°/s": 3600.0,
         "dps": 3600.0, "rad/s": 3600.0 * 180.0 / math.pi, "rad/h": 180.0 / math.pi}
_TIME = {"s": 1.0, "sec": 1.0, "second": 1.0, "seconds": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0, "hr": 3600.0}
_DEPTH = {"m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0, "ft": 0.3048, "feet": 0.3048,
          "foot": 0.3048, "usft": 1200.0 / 3937.0}
_COUNT = {"": 1.0, "-": 1.0, "#": 1.0, "id": 1.0, "no": 1.0, "n": 1.0, "none": 1.0, "count": 1.0, "1": 1.0}

#: Contract column -> (its unit, what it is, {unit token: factor to the contract unit}); temperature has offsets.
UNITS: dict[str, tuple[str, str, dict]] = {
    **{c: ("g", "gravity", _G) for c in ("gx", "gy", "gz")},
    **{c: ("nT", "magnetic field", _B) for c in ("bx", "by", "bz")},
    **{c: ("deg", "an angle", _ANGLE) for c in ("azimuth_deg", "inclination_deg", "toolface_deg")},
    **{c: ("deg/h", "a rotation rate", _RATE) for c in ("wx", "wy", "wz")},
    "time_s": ("s", "time", _TIME), "md": ("m", "measured depth", _DEPTH),
    "temperature_c": ("C", "temperature", {"c": 1.0, "degc": 1.0, "°c": 1.0, "celsius": 1.0, "k": 1.0, "kelvin": 1.0,
                                           "f": 5.0 / 9.0, "degf": 5.0 / 9.0, "°f": 5.0 / 9.0}),
    "station": ("", "an id", _COUNT), "group": ("", "an id", _COUNT),
}
#: The units named in errors, per kind (every spelling of :data:`UNITS` is accepted).
ACCEPTED = {"gravity": "g, mg, m/s^2, ft/s^2", "magnetic field": "nT, uT, G, mG, T, gamma", "an angle": "deg, rad",
            "a rotation rate": "deg/h, deg/s, rad/s, rad/h", "time": "s, ms, min, h", "measured depth": "m, ft, usft",
            "temperature": "C, K, F", "an id": "none (leave the cell empty)"}
#: Offsets (added after scaling) of the temperature units that need one.
_OFFSET = {"k": -273.15, "kelvin": -273.15, "f": -32.0 * 5.0 / 9.0, "degf": -32.0 * 5.0 / 9.0,
           "°f": -32.0 * 5.0 / 9.0}
#: Every unit token of every kind (a row of these under the header is a units row).
_ALL_UNITS = set().union(*(u[2] for u in UNITS.values())) - {"", "1", "n", "no", "none", "id", "#", "-"}

#: Names an export may give a contract column (compared lower-case, letters and digits only): the one table of
#: the hints every reader gives (a missing column's, :func:`missing_hint`, and an unknown column's that looks like a
#: contract column, :func:`synonym_hint`), on the doors and in ``python -m icgo.io check`` alike; none is read
#: without a map.
SYNONYMS = {
    "station": ("stn", "sta", "stationid", "stationno", "stationnumber", "shot", "shotno", "shotnumber", "index",
                "id", "svy", "survey", "surveyno", "surveynumber", "surveyid", "svyno"),
    "azimuth_deg": ("azimuth", "azi", "az", "azm", "azimuthdeg", "refazimuth", "trueazimuth", "azimuthref"),
    "inclination_deg": ("inclination", "inc", "incl", "incdeg", "inclinationdeg", "refinclination", "inclinationref"),
    "toolface_deg": ("toolface", "tf", "gtf", "gravitytoolface", "highsidetoolface"),
    "md": ("measureddepth", "depth", "mdm", "mdft", "depthm"),
    "time_s": ("time", "t", "timestamp", "times", "elapsed"),
    "temperature_c": ("temperature", "temp", "tempc"),
    **{f"g{a}": (f"g{a}", f"grav{a}", f"gravity{a}", f"acc{a}", f"accel{a}", f"accelerometer{a}", f"a{a}", f"g_{a}")
       for a in "xyz"},
    **{f"b{a}": (f"b{a}", f"mag{a}", f"m{a}", f"h{a}", f"magnetometer{a}", f"field{a}", f"bfield{a}")
       for a in "xyz"},
    **{f"w{a}": (f"w{a}", f"gyro{a}", f"rate{a}", f"omega{a}", f"gyr{a}") for a in "xyz"},
}

_COMMENT = re.compile(r"(?m)^[ \t]*#[^\r\n]*")
_BRACKETED = re.compile(r"^(.*?)\s*[\(\[]\s*([^\)\]]*?)\s*[\)\]]\s*$")


def _key(name: str) -> str:
    """Case- and space-insensitive form of a column name."""
    return name.strip().casefold()


def _loose(name: str) -> str:
    """Letters and digits only, lower case: how :data:`SYNONYMS` are compared."""
    return re.sub(r"[^0-9a-z]", "", name.casefold())


def unit_token(text: str) -> str:
    """A unit cell as compared with :data:`UNITS`: brackets, spaces and case dropped (``"[m/s^2]"`` -> ``"m/s^2"``)."""
    t = text.strip()
    m = re.fullmatch(r"[\(\[]\s*(.*?)\s*[\)\]]", t)
    t = (m.group(1) if m else t).replace(" ", "").casefold()
    return t.replace("deg.", "deg").replace("degrees/", "deg/").replace("degree/", "deg/").replace("μ", "µ")


def blank_comments(text: str) -> str:
    """Every comment line (first non-blank character ``#``) emptied; line numbers are kept."""
    return _COMMENT.sub("", text) if "#" in text else text


def load_column_map(path, known, setting: str = "columns_file") -> dict[str, str]:
    """A column map from a JSON or YAML file: ``{contract column: export column}`` (or under a ``columns`` key).

    Raises:
        SettingError: one line naming ``setting`` and the file.
    """
    p = Path(str(path)).expanduser()
    if not p.is_file():
        raise SettingError(setting, f"{str(p)!r}: file not found (a JSON or YAML map of contract column -> "
                                    f"export column)")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise SettingError(setting, f"{str(p)!r}: cannot read it ({e})") from None
    if p.suffix.lower() in (".yaml", ".yml"):
        import yaml

        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise SettingError(setting, f"{str(p)!r}: not valid YAML ({str(e).splitlines()[0]})") from None
    else:
        try:
            data = json.loads(text)
        except ValueError as e:
            raise SettingError(setting, f"{str(p)!r}: not valid JSON ({e}); a .yaml file is read as YAML") from None
    if isinstance(data, dict) and set(data) == {"columns"}:
        data = data["columns"]
    return check_column_map(data, known, setting)


def check_column_map(columns, known, setting: str = "columns") -> dict[str, str]:
    """``columns`` as a plain ``{contract column: export column}`` dict, checked (None -> ``{}``; entries whose
    value is None are left out).

    Args:
        columns: the map. known: the contract's column names. setting: its name in errors.
    Raises:
        SettingError: a key that is not a contract column, a value that is not a name.
    """
    if columns is None:
        return {}
    if not isinstance(columns, Mapping):
        raise SettingError(setting, f"must map contract columns to export column names, got {columns!r}")
    out = {}
    for k, v in columns.items():
        if v is None:  # the Hydra configs list every contract column, null = read under its own name
            continue
        if k not in known:
            raise SettingError(f"{setting}.{k}", f"is not a contract column; the contract's columns are "
                                                 f"{', '.join(known)}")
        if not isinstance(v, str) or not v.strip():
            raise SettingError(f"{setting}.{k}", f"must be the export column's name, got {v!r}")
        out[str(k)] = v
    return out


class Header:
    """An export header resolved to contract names.

    Attributes:
        names: the header as the reader sees it (contract names where matched, others as given).
        units: contract column -> unit token from a bracketed name (``Bx [uT]``).
        renamed: (export name, contract name) pairs that differ.
    """

    def __init__(self, names, units, renamed):
        self.names, self.units, self.renamed = names, units, renamed


def _fail(source: str, msg: str):
    raise DataError(f"{source}: {msg}")


def resolve_header(header: list[str], columns: Mapping[str, str], known, source: str,
                   setting: str = "columns") -> Header:
    """Export header -> contract names, by the column map, then case-insensitively, then by bracketed units.

    Args:
        header: the export's column names. columns: the column map. known: the contract's names.
        source: the file (errors). setting: how the map is named in errors.
    Raises:
        DataError: a mapped name not in the header; two export columns read as one contract column.
    """
    names = [h.strip() for h in header]
    out = list(names)
    units: dict[str, str] = {}
    taken: dict[str, str] = {}  # contract name -> the export name that gave it
    mapped: set[int] = set()
    for contract, export in columns.items():
        hits = [j for j, h in enumerate(names) if h == export.strip()] or \
               [j for j, h in enumerate(names) if _key(h) == _key(export)]
        if not hits:
            _fail(source, f"{setting}.{contract}={export!r}: the header has no such column "
                          f"(have: {', '.join(names)})")
        out[hits[0]], taken[contract] = contract, names[hits[0]]
        mapped.add(hits[0])
    by_key = {_key(c): c for c in known} | {_key(a): c for a, c in ALIASES.items()}
    for j, h in enumerate(names):
        if j in mapped:
            continue
        name, unit = _key(h), None
        m = _BRACKETED.match(h)
        if name not in by_key and m and _key(m.group(1)) in by_key:
            name, unit = _key(m.group(1)), m.group(2)
        if name not in by_key:
            continue
        contract = by_key[name]
        if contract in taken:
            _fail(source, f"columns {taken[contract]!r} and {h!r} both read as the contract column {contract!r}; "
                          f"keep one, or name the one to use with {setting}.{contract}=...")
        out[j], taken[contract] = contract, h
        if unit is not None:
            units[contract] = unit
    renamed = [(h, c) for h, c in zip(names, out) if h != c]
    return Header(out, units, renamed)


def missing_hint(missing, header: list[str], known, setting: str = "columns") -> str:
    """For missing contract columns, the export columns that look like them (:data:`SYNONYMS`).

    Returns:
        ``"; found `Inc`: use columns.inclination_deg=Inc"`` (one part per column with a candidate), or a
        pointer to the column map when no column looks like one.
    """
    hints = []
    for c in missing:
        wanted = {_loose(c)} | {_loose(s) for s in SYNONYMS.get(c, ())}
        found = [h for h in header if h not in known
                 and (_loose(h) in wanted or (_BRACKETED.match(h) and _loose(_BRACKETED.match(h).group(1)) in wanted))]
        if found:
            h = found[0]
            hints.append(f"found `{h}`: use {_use(setting, c, h)}" if re.fullmatch(r"[\w.-]+", h)
                         else f"found {h!r}: use {_use(setting, c, h)}")
    return ("; " + "; ".join(hints)) if hints else (
        f"; name the export's columns with {setting}.<contract column>=<export column> (docs/data.md)")


def _use(setting: str, c: str, h: str) -> str:
    return (f"{setting}.{c}={h}" if re.fullmatch(r"[\w.-]+", h) else f"{setting}.{c}='{h}'")


def synonym_hint(unknown: list[str], header: list[str], known, setting: str = "columns") -> str:
    """For unknown columns that look like a contract column the header lacks (:data:`SYNONYMS`), how to read them.

    Returns:
        ``" (`Inc` looks like inclination_deg: columns.inclination_deg=Inc)"``, or "" when none looks like one.
    """
    hints = []
    for h in unknown:
        m = _BRACKETED.match(h)
        forms = {_loose(h)} | ({_loose(m.group(1))} if m else set())
        for c in known:
            if c not in header and forms & ({_loose(c)} | {_loose(x) for x in SYNONYMS.get(c, ())}):
                hints.append(f"`{h}` looks like {c}: {_use(setting, c, h)}")
                break
    return f" ({'; '.join(hints)})" if hints else ""


def _numeric(cell: str) -> bool:
    try:
        float(cell)
        return "_" not in cell
    except ValueError:
        return False


def read_units_row(cells: list[str], names: list[str], bracketed: dict, source: str, line: int) -> dict | None:
    """The units of a units row (contract column -> unit token), or None when the row is data.

    A row is a units row when none of its contract-column cells is a number and at least one is a
    unit of :data:`UNITS`. Each contract column's cell must then be a unit of its kind (or empty).

    Raises:
        DataError: "line L looks like a units row, but ..." naming the column and its accepted units.
    """
    idx = [(j, n) for j, n in enumerate(names) if n in UNITS and j < len(cells)]
    if not idx or any(_numeric(cells[j]) for j, _ in idx):
        return None
    tokens = {n: unit_token(cells[j]) for j, n in idx}
    if not any(t in _ALL_UNITS for t in tokens.values()):
        return None
    units = {}
    for n, t in tokens.items():
        _, kind, table = UNITS[n]
        if t and t not in table:
            _fail(source, f"line {line} looks like a units row, but {cells[names.index(n)].strip()!r} is not a unit "
                          f"of {kind} (column '{n}'; accepted: {ACCEPTED[kind]})")
        if t and n in bracketed and unit_token(bracketed[n]) != t:
            _fail(source, f"column '{n}': the header says {bracketed[n]!r}, the units row (line {line}) "
                         f"{cells[names.index(n)].strip()!r}")
        units[n] = t
    return units


def conversions(units: dict[str, str]) -> dict[str, tuple[float, float, str]]:
    """Contract column -> (scale, offset, unit as given) for every column not already in the contract's unit."""
    out = {}
    for n, t in units.items():
        scale = UNITS[n][2].get(t)
        if scale is None:
            continue
        offset = _OFFSET.get(t, 0.0) if n == "temperature_c" else 0.0
        if scale != 1.0 or offset != 0.0:
            out[n] = (scale, offset, t)
    return out


def bracket_units(units: dict, source: str) -> dict:
    """Bracketed units of the header checked like a units row (contract column -> token)."""
    out = {}
    for n, u in units.items():
        t = unit_token(u)
        _, kind, table = UNITS[n]
        if t not in table:
            _fail(source, f"column '{n}': {u!r} in its header name is not a unit of {kind} (accepted: {ACCEPTED[kind]})")
        out[n] = t
    return out


class Prepared:
    """A field export's text made ready for the contract reader.

    Attributes:
        text: comment lines and the units row emptied, the header line in contract names.
        convert: contract column -> (scale, offset, unit given, where it was given: the units row or the header) to
            apply to the parsed values.
        notices: one line each: the names mapped, the units converted.
    """

    def __init__(self, text, convert, notices):
        self.text, self.convert, self.notices = text, convert, notices


def prepare(text: str, source: str, known, columns: Mapping[str, str] | None = None,
            setting: str = "columns") -> Prepared:
    """Comment lines, column names and a units row of an export, resolved; see the module docstring.

    Args:
        text: the whole file. source: its name (errors, notices). known: the contract's column names.
        columns: the column map (checked by :func:`check_column_map`).
        setting: how the column map is named in hints (``columns``, ``dataset.columns``).
    Raises:
        DataError: one line (a mapped column missing, a bad units row, two columns for one).
    """
    text = blank_comments(text)
    lines = text.splitlines(keepends=True)
    hidx = next((i for i, ln in enumerate(lines) if ln.strip() != ""), None)
    notices: list[str] = []
    if hidx is None:
        return Prepared(text, {}, notices)
    try:
        header = next(csv.reader([lines[hidx]]))
    except (csv.Error, StopIteration):
        return Prepared(text, {}, notices)
    hdr = resolve_header(header, columns or {}, known, source, setting)
    units = bracket_units(hdr.units, source)
    given = dict(hdr.units)  # contract column -> the unit as written, for the notice
    where = {n: f"the header ({header[hdr.names.index(n)].strip()!r})" for n in hdr.units}
    uidx = next((i for i in range(hidx + 1, len(lines)) if lines[i].strip() != ""), None)
    if uidx is not None:
        try:
            cells = next(csv.reader([lines[uidx]]))
        except (csv.Error, StopIteration):
            cells = None
        row_units = read_units_row(cells, hdr.names, hdr.units, source, uidx + 1) if cells else None
        if row_units is not None:
            units.update({n: t for n, t in row_units.items() if t or n not in units})
            given.update({n: cells[hdr.names.index(n)].strip() for n, t in row_units.items() if t})
            where.update({n: f"the units row (line {uidx + 1})" for n, t in row_units.items() if t})
            ending = lines[uidx][len(lines[uidx].rstrip("\r\n")):]
            lines[uidx] = ending
            notices.append(f"{source}: line {uidx + 1} read as the units row")
    if hdr.renamed:
        ending = lines[hidx][len(lines[hidx].rstrip("\r\n")):]
        buf = _io.StringIO()
        csv.writer(buf, lineterminator="").writerow(hdr.names)
        lines[hidx] = buf.getvalue() + ending
        notices.append(f"{source}: export column(s) read as contract columns: "
                       + ", ".join(f"{h!r} -> {c}" for h, c in hdr.renamed))
    convert = conversions(units)
    if convert:
        groups: dict[tuple, list] = {}
        for n, (scale, offset, t) in convert.items():
            groups.setdefault((given.get(n, t), UNITS[n][0], scale, offset), []).append(n)
        notices.append(f"{source}: converted to the contract's units: " + "; ".join(
            f"{', '.join(ns)} {u} -> {cu} (x{scale:.10g}{f' {offset:+.10g}' if offset else ''})"
            for (u, cu, scale, offset), ns in groups.items()))
        # each conversion names where its unit was given: a refusal of the converted values names it
        convert = {n: (scale, offset, given.get(n, t), where.get(n, "the units given"))
                   for n, (scale, offset, t) in convert.items()}
    return Prepared("".join(lines), convert, notices)
