"""The data contract's schema: its columns, metadata keys and limits, the reference field, the one-line error.

The contract itself (columns, units, metadata) is described in :mod:`icgo.io.recording`, which reads and writes
it; :mod:`icgo.io.checks` holds the checks that use the limits below. Every refusal is one line naming the
file, row and column (:func:`fail`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from icgo.core.errors import DataError

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
#: How the stations were taken: ``"rig": "turntable"`` (every station turned about one pivot) and the sensor's lever
#: arm from it (``sensor_lever_m``, m, tool frame), read by the discrepancy workflow (``magnetic_body``).
RIG_KEYS = ("rig", "sensor_lever_m")
KNOWN_META_KEYS = FIELD_KEYS + LOCATION_KEYS + DESCRIPTIVE_KEYS + RIG_KEYS

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


def is_number(v) -> bool:
    """True for an int or float (numpy's too), False for a bool and anything else."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
