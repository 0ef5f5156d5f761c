"""circuitpython-mag-cal JSON recordings -> contract :class:`icgo.io.recording.Recording` (issue 16).

Two layouts are read (``docs/calibrate.md``):

* **fixture** (mag_cal's ``tests/fixtures/cal_data``, the 9 bundled devices):
  ``{"shots": {"mag": [x, y, z, x, ...], "grav": [...]}, ...}``, flat lists padded
  with null/NaN, already in the device frame, gravity in g, field in uT. 24 shots:
  0-7 eight distinct orientations, 8-15 and 16-23 rolled about the pointing axis
  (mag_cal ``read_fixture``).
* **raw** (newer mag_cal): ``{"mag": [[x, y, z], ...], "grav": [[x, y, z], ...]}`` in
  the *sensor* frames, with the mounting given by axis strings (``mag_axes``,
  ``grav_axes``, mag_cal ``Axes``: for each device axis X, Y, Z the sensor axis
  and its sign, e.g. ``+x+y-z``), gravity in m/s^2 and field in uT. The strings
  come from the JSON (keys ``mag_axes`` / ``grav_axes``) or from the caller; the
  rolled groups are found from the data (:func:`roll_groups`).

Units are converted and stated in the recording's ``description``: gravity to g
(m/s^2 / 9.80665 when the median |G| is near 9.8), field uT -> nT (x 1000). The
device frame (X right, Y pointing, Z up) maps to the tool frame as for the bundled
devices (:data:`icgo.io.recording.MAG_CAL_DEVICE_TO_TOOL`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from icgo.core.errors import DataError
from icgo.io.files import read_text_bounded
from icgo.io.recording import STANDARD_GRAVITY, UT_TO_NT, Recording, device_to_tool, fail, fixture_shots, validate
from icgo.methods.calibration import MIN_ROLLED_SHOTS

#: Median |G| bands that identify the gravity unit of a raw recording.
#: Largest JSON recording read (bytes; docs/data.md): ten times the largest recording calibrate takes.
MAX_JSON_BYTES = 4 << 20
G_UNIT_BANDS = {"g": (0.5, 1.5), "m/s^2": (5.0, 15.0)}
#: Median |B| band (uT) of a magnetometer reading the earth's field in uT.
B_UT_BAND = (5.0, 500.0)
#: Roll-group finder: consecutive shots whose tool-z components of G (g) and of B (relative
#: to the median |B|) stay within these tolerances of the run's mean, at least MIN_ROLLED_SHOTS (icgo.methods.calibration)
#: long and spanning at least MIN_ROLL_SPAN_DEG of toolface, are one rolled group (one true
#: direction). A hand-held roll wobbles: on the 9 bundled devices the pointing axis moves by up
#: to 0.13 g in G_z and 0.06 |B| in B_z within a roll, and two rolls differ by 0.17 |B| in B_z.
ROLL_G_TOL = 0.15
ROLL_B_TOL = 0.10
MIN_ROLL_SPAN_DEG = 90.0


class AxesNotApplicable(DataError):
    """``mag_axes`` / ``grav_axes`` given for a fixture-layout file (already in the device frame): a bad setting."""


def parse_axes(axes: str, what: str) -> tuple[list[int], list[int]]:
    """mag_cal's axis string (``+X+Y+Z``, case-insensitive) -> (sensor index, sign) per device axis.

    Raises:
        DataError: one line naming ``what`` and the expected form.
    """
    s = str(axes).strip().upper()
    bad = f"{axes!r}: expected 6 characters, a sign and one of X, Y, Z per device axis, e.g. +x+y-z"
    if len(s) != 6 or any(s[i] not in "+-" or s[i + 1] not in "XYZ" for i in (0, 2, 4)):
        fail(what, bad)
    idx = ["XYZ".index(s[i + 1]) for i in (0, 2, 4)]
    if sorted(idx) != [0, 1, 2]:
        fail(what, bad + " (each axis once)")
    return idx, [1 if s[i] == "+" else -1 for i in (0, 2, 4)]


def sensor_to_device(data, axes: str, what: str) -> np.ndarray:
    """Sensor-frame (N, 3) readings -> device frame: ``device[:, i] = sign_i * sensor[:, idx_i]`` (mag_cal Axes)."""
    idx, sign = parse_axes(axes, what)
    data = np.asarray(data, np.float64)
    return data[:, idx] * np.asarray(sign, np.float64)


def roll_groups(G, B) -> np.ndarray:
    """Group ids of rolled shots (one true direction each), found from the data; other shots alone.

    A roll about the pointing axis (tool z) keeps the tool-z components of gravity and of the
    field (a body-fixed bias included) while the toolface turns. Consecutive shots within
    :data:`ROLL_G_TOL` (g) and :data:`ROLL_B_TOL` (x median |B|) of the run's mean form a
    run; a run of at least :data:`icgo.methods.calibration.MIN_ROLLED_SHOTS` spanning at least :data:`MIN_ROLL_SPAN_DEG` of
    toolface is a group. Group ids: singles 0, 1, ... in shot order, then the rolled groups.

    Args:
        G: (N, 3) tool-frame gravity, g. B: (N, 3) tool-frame field (any unit).
    Returns:
        (N,) int64 group ids.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    bscale = float(np.median(np.linalg.norm(B, axis=1)))
    tf = np.degrees(np.arctan2(G[:, 1], -G[:, 0]))
    runs, start = [], 0
    for k in range(1, len(G) + 1):
        if (k == len(G) or abs(G[k, 2] - G[start:k, 2].mean()) > ROLL_G_TOL
                or abs(B[k, 2] - B[start:k, 2].mean()) > ROLL_B_TOL * bscale):
            runs.append((start, k))
            start = k
    rolled = []
    for a, b in runs:
        if b - a >= MIN_ROLLED_SHOTS:
            t = np.sort(np.mod(tf[a:b], 360.0))
            gaps = np.diff(np.concatenate([t, t[:1] + 360.0]))
            if 360.0 - gaps.max() >= MIN_ROLL_SPAN_DEG:
                rolled.append((a, b))
    group = np.full(len(G), -1, np.int64)
    n_single = 0
    for k in range(len(G)):
        if not any(a <= k < b for a, b in rolled):
            group[k] = n_single
            n_single += 1
    for j, (a, b) in enumerate(rolled):
        group[a:b] = n_single + j
    return group


def _triples(v, src: str, key: str) -> np.ndarray:
    """A raw-layout list of [x, y, z] readings -> (N, 3) float64, or a one-line DataError."""
    if not isinstance(v, list) or not v:
        fail(src, f"'{key}' must be a non-empty list of [x, y, z] readings")
    for i, t in enumerate(v):
        if not (isinstance(t, list) and len(t) == 3 and all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                                              and math.isfinite(c) for c in t)):
            fail(src, f"'{key}[{i}]' must be [x, y, z] with 3 finite numbers, got {str(t)[:60]}")
    return np.asarray(v, np.float64)


def _gravity_to_g(grav: np.ndarray, src: str) -> tuple[np.ndarray, str]:
    med = float(np.median(np.linalg.norm(grav, axis=1)))
    for unit, (lo, hi) in G_UNIT_BANDS.items():
        if lo <= med <= hi:
            return (grav / STANDARD_GRAVITY if unit == "m/s^2" else grav), unit
    fail(src, f"'grav': median |G| = {med:.4g} is neither g (~1) nor m/s^2 (~9.81)")


def _field_to_nT(mag: np.ndarray, src: str) -> np.ndarray:
    med = float(np.median(np.linalg.norm(mag, axis=1)))
    if not B_UT_BAND[0] <= med <= B_UT_BAND[1]:
        fail(src, f"'mag': median |B| = {med:.4g}; expected the earth's field in uT "
                   f"({B_UT_BAND[0]:g}-{B_UT_BAND[1]:g})")
    return mag * UT_TO_NT


def layout_of(d) -> str:
    """``"fixture"`` or ``"raw"`` for a parsed JSON document, else a DataError naming both layouts."""
    if isinstance(d, dict) and isinstance(d.get("shots"), dict) and {"mag", "grav"} <= set(d["shots"]):
        return "fixture"
    if isinstance(d, dict) and {"mag", "grav"} <= set(d):
        return "raw"
    raise DataError("expected a circuitpython-mag-cal JSON: the fixture layout {\"shots\": {\"mag\": [...], "
                    "\"grav\": [...]}} or the raw layout {\"mag\": [[x, y, z], ...], \"grav\": [[x, y, z], ...]}")


def read_mag_cal_json(path, mag_axes: str | None = None, grav_axes: str | None = None) -> Recording:
    """A circuitpython-mag-cal JSON file (either layout) as a contract Recording with a ``group`` column.

    Args:
        path: the JSON file.
        mag_axes, grav_axes: mounting strings for the raw layout (override the file's keys;
            default ``+X+Y+Z``, grav default = mag, as mag_cal). Refused for the fixture layout,
            which is in the device frame already.
    Returns:
        Recording (station = shot index; no reference attitude, no field metadata).
    Raises:
        DataError: one line naming the file and what is wrong.
    """
    src = str(path)
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
    if layout == "fixture":
        if mag_axes is not None or grav_axes is not None:
            raise AxesNotApplicable(f"{src}: mag_axes / grav_axes apply to the raw layout; this fixture-layout file "
                                    "is in the device frame already: drop them")
        G, B, group = fixture_shots(d, src)
        g_unit, axes_note = "g", "device frame (fixture layout)"
    else:
        mag, grav = _triples(d["mag"], src, "mag"), _triples(d["grav"], src, "grav")
        if len(mag) != len(grav):
            fail(src, f"'mag' has {len(mag)} readings and 'grav' {len(grav)}: one of each per shot")
        ma = mag_axes if mag_axes is not None else d.get("mag_axes", "+X+Y+Z")
        ga = grav_axes if grav_axes is not None else d.get("grav_axes", ma)
        G_dev, g_unit = _gravity_to_g(sensor_to_device(grav, ga, f"{src}: grav_axes"), src)
        G = device_to_tool(G_dev)
        B = device_to_tool(_field_to_nT(sensor_to_device(mag, ma, f"{src}: mag_axes"), src))
        group = roll_groups(G, B)
        axes_note = f"sensor frames mapped to the device frame with mag_axes {str(ma).upper()}, " \
                    f"grav_axes {str(ga).upper()} (mag_cal Axes)"
    frame = pd.DataFrame({"station": np.arange(len(G)), "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
                          "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2], "group": group})
    n_rolled = int(sum(np.sum(group == g) >= 2 for g in np.unique(group)))
    meta = {"name": str(d.get("name", Path(path).stem)) if isinstance(d, dict) else Path(path).stem,
            "source": src,
            "description": f"circuitpython-mag-cal {layout} layout; {axes_note}; device axes (X right, Y pointing, "
                           f"Z up) -> tool (x, y, z) = (Z, X, Y); gravity {g_unit}"
                           + (" / 9.80665 -> g" if g_unit == "m/s^2" else "")
                           + f"; field uT x 1000 -> nT; {n_rolled} rolled group(s)"}
    return validate(frame, meta, source=src, require_reference=False)
