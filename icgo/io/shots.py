"""Grouped static shots from any file a front door takes, as read: a contract CSV or a circuitpython-mag-cal JSON.

:func:`read_shot_file` reads the file and gives it the groups that are known without searching the data, so
that the mounting strings and the ``groups=`` setting mean the same everywhere:

* ``.json``: :func:`icgo.io.mag_cal_json.read_mag_cal_json` (either layout; ``mag_axes`` / ``grav_axes`` for
  the raw layout; the circuitpython-mag-cal layout's groups, or shot ranges given);
* anything else: a contract CSV (:func:`icgo.io.recording.read_recording`, the ``.meta.json`` beside it
  optional, a column map for a field export); its ``group`` column (checked), or shot ranges given, or the
  layout of the ``instrument`` its metadata names; ``mag_axes`` / ``grav_axes`` refused (a contract CSV is in
  the tool frame already).

Where no group is known (``groups=auto``, or no layout and no column), the rolls are found from the data by
:mod:`icgo.models.grouping`; :func:`icgo.studies.common.shots.read_shots` composes the two for the front doors.
"""

from __future__ import annotations

from icgo.core.errors import DataError, SettingError
from icgo.io.grouping import check_given, groups_from_ranges, layout_groups, parse_groups
from icgo.io.mag_cal_json import ShotFile, read_mag_cal_json
from icgo.io.recording import read_recording

#: The settings :func:`read_shot_file` takes (``key=value`` on every command line).
SETTINGS = ("mag_axes", "grav_axes", "groups")


def is_json(path) -> bool:
    """Whether a ``data=`` path names a circuitpython-mag-cal JSON (by its suffix)."""
    return str(path).lower().endswith(".json")


def read_shot_file(path, mag_axes=None, grav_axes=None, groups=None, columns=None, lazy: bool = False) -> ShotFile:
    """A recording of static shots with the groups known without a search (:class:`icgo.io.mag_cal_json.ShotFile`).

    Args:
        path: a ``.json`` (circuitpython-mag-cal) or a contract CSV.
        mag_axes, grav_axes: mounting strings (raw-layout JSON only), or None.
        groups: the ``groups=`` setting (:func:`icgo.io.grouping.parse_groups`; raw or parsed), or None.
        columns: a column map for a CSV field export (:mod:`icgo.io.columns`), or None.
        lazy: a CSV's every failure at once (:func:`icgo.io.recording.read_recording`, ``python -m icgo.io check``).
    Raises:
        SettingError: a bad setting (exit 2). DataError: bad data, or given groups that are not rolls (exit 1).
    """
    spec = groups if isinstance(groups, tuple) else parse_groups(groups)
    axes = {k: (None if v is None else str(v)) for k, v in (("mag_axes", mag_axes), ("grav_axes", grav_axes))}
    if is_json(path):
        if columns:
            raise SettingError("columns / columns_file apply to a CSV field export; a circuitpython-mag-cal JSON has "
                               "no columns to map")
        return read_mag_cal_json(path, groups=spec, **axes)
    if any(v is not None for v in axes.values()):
        raise SettingError("mag_axes / grav_axes apply to a raw-layout JSON file; a contract CSV is in the tool "
                           "frame already")
    rec = read_recording(path, require_meta=False, require_reference=False, columns=columns, lazy=lazy)
    frame, src = rec.frame, str(path)
    layout = layout_groups(str(rec.meta.get("instrument", "")), len(frame))
    if isinstance(spec, tuple):
        group = groups_from_ranges(frame["station"].to_numpy(), spec)
        check_given(frame, group, src, "the shot ranges (groups=)")
        return ShotFile(rec._replace(frame=frame.assign(group=group)), "ranges", layout)
    if spec == "auto":
        return ShotFile(rec._replace(frame=frame.drop(columns="group", errors="ignore")), None, layout)
    if "group" in frame.columns:
        check_given(frame, frame["group"].to_numpy(), src, "the group column")
        return ShotFile(rec, "column", layout)
    if spec is None and layout is not None:
        group = groups_from_ranges(frame["station"].to_numpy(), layout.ranges)
        return ShotFile(rec._replace(frame=frame.assign(group=group)), "layout", layout)
    raise DataError(f"{src}: no 'group' column: give one (shots of one true direction share a group), or let icgo "
                    "find the rolls (groups=auto), or give them (groups=[first-last,...])")
