"""Grouped static shots from any file a front door takes: a contract CSV or a circuitpython-mag-cal JSON.

:func:`read_shots` is what ``experiments.calibrate``, ``experiments.discrepancy`` and
``python -m icgo.io check|convert`` call for a file of grouped shots, so that the mounting strings and the
``groups=`` setting mean the same everywhere:

* ``.json``: :func:`icgo.io.mag_cal_json.read_mag_cal_json` (either layout; ``mag_axes`` / ``grav_axes`` for
  the raw layout; rolls found from the data unless ``groups=`` says otherwise);
* anything else: a contract CSV (:func:`icgo.io.recording.read_recording`, the ``.meta.json`` beside it
  optional); its ``group`` column unless ``groups=`` says otherwise; ``mag_axes`` / ``grav_axes`` refused
  (a contract CSV is in the tool frame already).
"""

from __future__ import annotations

from icgo.core.errors import SettingError
from icgo.io.grouping import assign_groups, parse_groups
from icgo.io.mag_cal_json import read_mag_cal_json
from icgo.io.recording import Recording, read_recording

#: The settings :func:`read_shots` takes (``key=value`` on every command line).
SETTINGS = ("mag_axes", "grav_axes", "groups")


def is_json(path) -> bool:
    """Whether a ``data=`` path names a circuitpython-mag-cal JSON (by its suffix)."""
    return str(path).lower().endswith(".json")


def read_shots(path, mag_axes=None, grav_axes=None, groups=None, columns=None) -> Recording:
    """A recording of grouped static shots with a checked ``group`` column.

    Args:
        path: a ``.json`` (circuitpython-mag-cal) or a contract CSV.
        mag_axes, grav_axes: mounting strings (raw-layout JSON only), or None.
        groups: the ``groups=`` setting (:func:`icgo.io.grouping.parse_groups`), or None (the file's default).
        columns: a column map for a CSV field export (:mod:`icgo.io.columns`), or None.
    Raises:
        SettingError: a bad setting (exit 2). DataError: bad data (exit 1). Both one line.
    """
    spec = parse_groups(groups)
    axes = {k: (None if v is None else str(v)) for k, v in (("mag_axes", mag_axes), ("grav_axes", grav_axes))}
    if is_json(path):
        return read_mag_cal_json(path, groups=spec, **axes)
    if any(v is not None for v in axes.values()):
        raise SettingError("mag_axes / grav_axes apply to a raw-layout JSON file; a contract CSV is in the tool "
                           "frame already")
    rec = read_recording(path, require_meta=False, require_reference=False, columns=columns)
    frame, notices = assign_groups(rec.frame, spec, str(path), default="column")
    return rec._replace(frame=frame, notices=notices + list(rec.notices))
