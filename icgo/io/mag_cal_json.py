"""circuitpython-mag-cal JSON recordings -> contract :class:`icgo.io.recording.Recording`.

Two layouts are read (``docs/calibrate.md``):

* **fixture** (mag_cal's ``tests/fixtures/cal_data``, the 9 bundled devices):
  ``{"shots": {"mag": [x, y, z, x, ...], "grav": [...]}, ...}``, flat lists padded
  with null/NaN, already in the device frame, gravity in g, field in uT; any number of shots.
* **raw** (newer mag_cal): ``{"mag": [[x, y, z], ...], "grav": [[x, y, z], ...]}`` in
  the *sensor* frames, with the mounting given by axis strings (``mag_axes``,
  ``grav_axes``, mag_cal ``Axes``: for each device axis X, Y, Z the sensor axis
  and its sign, e.g. ``+x+y-z``), gravity in m/s^2 or g and field in uT. The strings
  come from the caller (a setting) or from the JSON (keys ``mag_axes`` / ``grav_axes``).

Every shot is checked before anything is computed from it: finite numbers, the units of the whole file from its
median (below), and every shot's |G| and |B| within a factor of those medians (:data:`icgo.io.schema.ROW_FACTOR_G`,
:data:`icgo.io.schema.ROW_FACTOR_B`; a shot of 1e300 is refused here, naming the shot). Groups: a recording of
``8 + 8 k`` shots is in the circuitpython-mag-cal layout (:func:`icgo.io.grouping.layout_groups`: 8 single shots,
then rolls of 8) and gets the layout's groups; shot ranges given (``groups=``) replace them and are checked
(:func:`icgo.io.grouping.check_given`). Checking a layout against the data and finding rolls where no layout is
known are :mod:`icgo.models.grouping`'s (composed by :mod:`icgo.studies.common.shots`).
Units are converted and stated in the recording's ``description``: gravity to g
(m/s^2 / 9.80665 when the median |G| is near 9.8), field uT -> nT (x 1000); a field that
is not in uT (Gauss, nT) is refused with the factor. The device frame (X right, Y pointing, Z up)
maps to the tool frame as for the bundled devices (:data:`icgo.io.mag_cal_bundled.MAG_CAL_DEVICE_TO_TOOL`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from icgo.core.errors import DataError, GroupingError, SettingError
from icgo.io.files import read_text_bounded
from icgo.io.grouping import Layout, check_given, groups_from_ranges, layout_groups
from icgo.io.mag_cal_bundled import UT_TO_NT, device_to_tool, fixture_shots
from icgo.io.recording import Recording, validate
from icgo.io.schema import ROW_FACTOR_B, ROW_FACTOR_G, STANDARD_GRAVITY, fail
from icgo.physics.rolls import AXIS_TO_Z_DEG, rolls_off_axis_deg

#: Largest JSON recording read (bytes; docs/data.md): ten times the largest recording calibrate takes.
MAX_JSON_BYTES = 4 << 20
#: Median |G| bands that identify the gravity unit of a recording.
G_UNIT_BANDS = {"g": (0.5, 1.5), "m/s^2": (5.0, 15.0)}
#: Median |B| band (uT) of a magnetometer reading the earth's field in uT (hard iron included).
B_UT_BAND = (5.0, 500.0)
#: Other field units recognised only to name them in the refusal: median |B| band in that unit, x to uT.
B_OTHER_UNITS = {"Gauss": ((0.05, 5.0), 100.0), "nT": ((5000.0, 500000.0), 0.001)}
#: The shot counts of the circuitpython-mag-cal layout, in words (icgo.io.grouping.layout_groups).
LAYOUT_SHOTS_RULE = "8 + 8 k"
#: Mounting assumed when neither the caller nor the file gives one (mag_cal's default).
DEFAULT_AXES = "+X+Y+Z"
#: The instrument whose recordings these are (the ``instrument`` metadata key; its layout: icgo.io.grouping).
INSTRUMENT = "circuitpython-mag-cal"


class ShotFile(NamedTuple):
    """A recording of grouped shots as read, before any search of the data.

    Attributes:
        recording: the contract :class:`icgo.io.recording.Recording`; a ``group`` column when the groups are
            known here (the layout's, or given), else none.
        origin: where the ``group`` column came from: ``layout``, ``column`` (the file's), ``ranges``
            (``groups=``), or None (no groups: to be found from the data).
        layout: the recording's known layout, or None.
        hint: the probable cause to name when no roll is found (a mounting not given), or "".
    """

    recording: Recording
    origin: str | None
    layout: Layout | None
    hint: str = ""


def parse_axes(axes: str, what: str, setting: bool = False) -> tuple[list[int], list[int]]:
    """mag_cal's axis string (``+X+Y+Z``, case-insensitive) -> (sensor index, sign) per device axis.

    Args:
        axes: the string. what: its name for the message (``mag_axes``, ``<file>: grav_axes``).
        setting: the string is a setting (SettingError, exit 2) rather than read from a file (DataError).
    Raises:
        SettingError / DataError: one line naming ``what`` and the expected form.
    """
    s = str(axes).strip().upper()
    bad = f"{axes!r}: expected 6 characters, a sign and one of X, Y, Z per device axis, e.g. +x+y-z"
    ok = len(s) == 6 and all(s[i] in "+-" and s[i + 1] in "XYZ" for i in (0, 2, 4))
    if ok and sorted("XYZ".index(s[i + 1]) for i in (0, 2, 4)) != [0, 1, 2]:
        ok, bad = False, bad + " (each axis once)"
    if not ok:
        raise (SettingError if setting else DataError)(f"{what} {bad}")
    return ["XYZ".index(s[i + 1]) for i in (0, 2, 4)], [1 if s[i] == "+" else -1 for i in (0, 2, 4)]


def sensor_to_device(data, axes: str, what: str) -> np.ndarray:
    """Sensor-frame (N, 3) readings -> device frame: ``device[:, i] = sign_i * sensor[:, idx_i]`` (mag_cal Axes)."""
    idx, sign = parse_axes(axes, what)
    data = np.asarray(data, np.float64)
    return data[:, idx] * np.asarray(sign, np.float64)


def _triples(v, src: str, key: str) -> np.ndarray:
    """A raw-layout list of [x, y, z] readings -> (N, 3) float64, or a one-line DataError."""
    if not isinstance(v, list) or not v:
        fail(src, f"'{key}' must be a non-empty list of [x, y, z] readings")
    for i, t in enumerate(v):
        if not (isinstance(t, list) and len(t) == 3 and all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                                              and math.isfinite(c) for c in t)):
            fail(src, f"'{key}[{i}]' must be [x, y, z] with 3 finite numbers, got {str(t)[:60]}")
    return np.asarray(v, np.float64)


def _gravity_to_g(grav: np.ndarray, src: str, key: str = "grav") -> tuple[np.ndarray, str]:
    med = float(np.median(np.linalg.norm(grav, axis=1)))
    for unit, (lo, hi) in G_UNIT_BANDS.items():
        if lo <= med <= hi:
            return (grav / STANDARD_GRAVITY if unit == "m/s^2" else grav), unit
    fail(src, f"'{key}': median |G| = {med:.4g} is neither g (~1) nor m/s^2 (~9.81)")


def _field_to_nT(mag: np.ndarray, src: str, key: str = "mag") -> np.ndarray:
    """uT -> nT; a field in another unit is refused with the factor that makes it uT."""
    med = float(np.median(np.linalg.norm(mag, axis=1)))
    if B_UT_BAND[0] <= med <= B_UT_BAND[1]:
        return mag * UT_TO_NT
    unit = next((f"; looks like {u}: multiply by {k:g} to give uT" for u, ((lo, hi), k) in B_OTHER_UNITS.items()
                 if lo <= med <= hi), "")
    fail(src, f"'{key}': median |B| = {med:.4g}; expected the earth's field in uT "
              f"({B_UT_BAND[0]:g}-{B_UT_BAND[1]:g}){unit}")


def layout_of(d) -> str:
    """``"fixture"`` or ``"raw"`` for a parsed JSON document, else a DataError naming both layouts."""
    if isinstance(d, dict) and isinstance(d.get("shots"), dict) and {"mag", "grav"} <= set(d["shots"]):
        return "fixture"
    if isinstance(d, dict) and {"mag", "grav"} <= set(d):
        return "raw"
    raise DataError("expected a circuitpython-mag-cal JSON: the fixture layout {\"shots\": {\"mag\": [...], "
                    "\"grav\": [...]}} or the raw layout {\"mag\": [[x, y, z], ...], \"grav\": [[x, y, z], ...]}")


def check_shots(G, B_uT, src: str) -> None:
    """Every shot's |G| and |B| within :data:`icgo.io.schema.ROW_FACTOR_G` / ``ROW_FACTOR_B`` of the median, so
    that one corrupt or mis-scaled reading (1e300, a value in other units) is refused, named, before any fit.

    Args:
        G: (N, 3) gravity, g. B_uT: (N, 3) field, uT. src: the file.
    Raises:
        DataError: one line naming the first such shot (0-based, as ``station``).
    """
    for v, what, unit, factor in ((G, "|G|", "g", ROW_FACTOR_G), (B_uT, "|B|", "uT", ROW_FACTOR_B)):
        norm = np.hypot(np.hypot(v[:, 0], v[:, 1]), v[:, 2])  # no square of 1e300 overflows here
        med = float(np.median(norm))
        off = (norm < med / factor) | (norm > med * factor)
        if off.any():
            i = int(np.argmax(off))
            fail(src, f"shot {i}: {what} = {norm[i]:.4g} {unit} while the median is {med:.4g} {unit} "
                      f"({int(off.sum())} shot(s) more than {factor:g}x off: a corrupt reading or one in other units)")


def read_mag_cal_json(path, mag_axes: str | None = None, grav_axes: str | None = None, groups=None) -> ShotFile:
    """A circuitpython-mag-cal JSON file (either layout) as a contract Recording, grouped by its layout or ``groups=``.

    Args:
        path: the JSON file.
        mag_axes, grav_axes: mounting strings for the raw layout (settings: override the file's keys;
            default ``+X+Y+Z``, grav default = mag, as mag_cal). Refused for the fixture layout,
            which is in the device frame already.
        groups: a :func:`icgo.io.grouping.parse_groups` value: shot ranges (checked), ``auto`` or None (the
            layout's groups where the shot count fits it; ``auto`` asks the caller to search the data, and the
            layout is still returned to compare with), ``column`` (refused: a JSON has no group column).
    Returns:
        :class:`ShotFile` (station = shot index; no reference attitude, no field metadata; ``instrument`` in the
        metadata).
    Raises:
        SettingError: a bad ``mag_axes`` / ``grav_axes`` setting, axes for a fixture file, a bad shot range.
        DataError: one line naming the file and what is wrong.
    """
    src = str(path)
    for key, v in (("mag_axes", mag_axes), ("grav_axes", grav_axes)):
        if v is not None:
            parse_axes(v, key, setting=True)
    try:
        d = json.loads(read_text_bounded(path, MAX_JSON_BYTES, "a circuitpython-mag-cal JSON file"))
    except (json.JSONDecodeError, RecursionError, ValueError) as e:
        if isinstance(e, DataError):
            raise
        fail(src, f"not valid JSON: {str(e).splitlines()[0][:120]}")
    try:
        layout = layout_of(d)
    except DataError as e:
        fail(src, str(e))
    hint = ""
    if layout == "fixture":
        if mag_axes is not None or grav_axes is not None:
            raise SettingError(f"mag_axes / grav_axes apply to the raw layout; {src} is a fixture-layout file, "
                               "in the device frame already: drop them")
        G, B, _ = fixture_shots(d, src)
        check_shots(G, B / UT_TO_NT, src)
        _field_to_nT(B / UT_TO_NT, src, "shots.mag")
        if _gravity_to_g(G, src, "shots.grav")[1] != "g":
            fail(src, "'shots.grav': the fixture layout holds gravity in g; this file's looks like m/s^2")
        g_unit, axes_note = "g", "device frame (fixture layout)"
    else:
        mag, grav = _triples(d["mag"], src, "mag"), _triples(d["grav"], src, "grav")
        if len(mag) != len(grav):
            fail(src, f"'mag' has {len(mag)} readings and 'grav' {len(grav)}: one of each per shot")
        check_shots(grav, mag, src)
        from_file = {k: d.get(k) for k in ("mag_axes", "grav_axes")}
        ma = mag_axes if mag_axes is not None else from_file["mag_axes"]
        ga = grav_axes if grav_axes is not None else from_file["grav_axes"]
        ga = ga if ga is not None else ma
        if ma is None:
            hint = (f"the mounting is not given (no mag_axes= / grav_axes=, and {src} has no mag_axes / grav_axes "
                    f"keys; {DEFAULT_AXES} assumed): give mag_axes= and grav_axes=")
        ma, ga = ma or DEFAULT_AXES, ga or DEFAULT_AXES
        for key, v in (("mag_axes", ma), ("grav_axes", ga)):  # the settings were checked above; these are the file's
            parse_axes(v, f"{src}: the file's {key}")
        B = device_to_tool(_field_to_nT(sensor_to_device(mag, ma, "mag_axes"), src))
        G_dev, g_unit = _gravity_to_g(sensor_to_device(grav, ga, "grav_axes"), src)
        G = device_to_tool(G_dev)
        axes_note = (f"sensor frames mapped to the device frame with mag_axes {str(ma).upper()}, "
                     f"grav_axes {str(ga).upper()} (mag_cal Axes{'; default: none given' if hint else ''})")
    frame = pd.DataFrame({"station": np.arange(len(G)), "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
                          "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2]})
    known = layout_groups(INSTRUMENT, len(G))
    meta = {"name": str(d.get("name", Path(path).stem)) if isinstance(d, dict) else Path(path).stem,
            "source": src, "instrument": INSTRUMENT,
            "description": f"circuitpython-mag-cal {layout} layout; {axes_note}; device axes (X right, Y pointing, "
                           f"Z up) -> tool (x, y, z) = (Z, X, Y); gravity {g_unit}"
                           + (" / 9.80665 -> g" if g_unit == "m/s^2" else "")
                           + f"; field uT x 1000 -> nT; {len(G)} shots; "
                           + (known.describe() if known else f"no known layout ({len(G)} shots is not "
                                                                f"{LAYOUT_SHOTS_RULE})")}
    rec = validate(frame, meta, source=src, require_reference=False)
    if groups == "column":
        fail(src, "groups=column: a circuitpython-mag-cal JSON has no group column; drop groups= (the layout), or "
                  "give groups=auto or shot ranges")
    if isinstance(groups, tuple):
        group = groups_from_ranges(rec.frame["station"].to_numpy(), groups)
        check_given(rec.frame.assign(group=group), group, src, "the shot ranges (groups=)")
        return ShotFile(rec._replace(frame=rec.frame.assign(group=group)), "ranges", known, hint)
    if known is not None and groups != "auto":
        group = groups_from_ranges(rec.frame["station"].to_numpy(), known.ranges)
        off = rolls_off_axis_deg(rec.G, rec.B, group)
        if off is not None:
            raise GroupingError(f"{src}: the {known.describe()}: its rolls turn about an axis {off:.0f} deg or more "
                                f"from the pointing axis (tool z; at most {AXIS_TO_Z_DEG:g}): the mounting is not the "
                                "device's; probable cause: "
                                + (hint or "the mounting strings (mag_axes / grav_axes) are not this device's"))
        return ShotFile(rec._replace(frame=rec.frame.assign(group=group)), "layout", known, hint)
    return ShotFile(rec, None, known, hint)
