"""Which shots of a recording share one true direction: the ``groups=`` setting, rolls found or given, checked.

Every front door that reads grouped static shots (``experiments.calibrate``, ``experiments.discrepancy``,
``python -m icgo.io check|convert``) takes one ``groups=`` setting (:func:`parse_groups`):

* ``auto``: the rolls are found from the data (:func:`icgo.methods.rolls.find_rolls`); the default for a
  circuitpython-mag-cal JSON;
* ``column``: the recording's ``group`` column as given; the default for a contract CSV;
* shot ranges ``[8-15,16-23]`` (or the string ``"8-15,16-23"``): each range of ``station`` values (both
  ends included) is one roll, every other shot its own group.

Whatever their origin, every group of :data:`icgo.methods.calibration.MIN_ROLLED_SHOTS` or more shots must
be a plausible roll (:func:`icgo.methods.rolls.check_roll`), else the recording is refused with one line
naming the group, its shots and the criterion it fails (:func:`assign_groups`). A recording with no roll
is refused with the probable cause.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd

from icgo.core.errors import DataError, SettingError
from icgo.methods import rolls

#: The named ``groups=`` modes.
GROUP_MODES = ("auto", "column")
_RANGE = re.compile(r"^\s*(\d+)\s*(?:-\s*(\d+))?\s*$")


def parse_groups(spec):
    """A ``groups=`` value -> ``"auto"``, ``"column"``, ``None`` (the reader's default) or ``((lo, hi), ...)``.

    Args:
        spec: None, ``auto``, ``column``, a list of ``"lo-hi"`` strings (or ints), or one string of them
            separated by commas.
    Raises:
        SettingError: one line naming ``groups`` and the expected forms.
    """
    if spec is None or (isinstance(spec, str) and spec.strip() in ("", "null")):
        return None
    if isinstance(spec, str) and spec.strip().lower() in GROUP_MODES:
        return spec.strip().lower()
    items = spec.split(",") if isinstance(spec, str) else list(spec) if isinstance(spec, (list, tuple)) else None
    usage = ("expected auto, column or shot ranges such as [8-15,16-23] (station numbers, both ends included, "
             "one roll each)")
    if not items:
        raise SettingError("groups", f"{spec!r}: {usage}")
    out = []
    for it in items:
        m = _RANGE.match(str(it))
        if m is None or isinstance(it, bool):
            raise SettingError("groups", f"{str(it)!r} is not a shot range: {usage}")
        lo, hi = int(m.group(1)), int(m.group(2) if m.group(2) is not None else m.group(1))
        if hi < lo:
            raise SettingError("groups", f"range {lo}-{hi} ends before it starts")
        out.append((lo, hi))
    out.sort()
    for (a, b), (c, d) in zip(out, out[1:]):
        if c <= b:
            raise SettingError("groups", f"ranges {a}-{b} and {c}-{d} overlap: a shot belongs to one group")
    return tuple(out)


def _groups_from_ranges(station: np.ndarray, ranges) -> np.ndarray:
    """(n,) group ids from station ranges: every shot outside them its own group, each range one group."""
    runs = []
    for lo, hi in ranges:
        m = (station >= lo) & (station <= hi)
        if m.sum() < rolls.MIN_ROLLED_SHOTS:
            raise SettingError("groups", f"range {lo}-{hi} holds {int(m.sum())} shot(s); a roll needs at least "
                               f"{rolls.MIN_ROLLED_SHOTS}")
        runs.append(m)
    out = np.full(len(station), -1, np.int64)
    singles = ~np.any(runs, axis=0)
    out[singles] = np.arange(int(singles.sum()))
    for j, m in enumerate(runs):
        out[m] = int(singles.sum()) + j
    return out


def _station_ids(frame: pd.DataFrame, groups, g) -> str:
    return rolls.shot_ranges(frame["station"].to_numpy()[np.asarray(groups) == g])


def assign_groups(frame: pd.DataFrame, spec, source: str, *, default: str = "column",
                  no_roll_hint: str = "") -> tuple[pd.DataFrame, list]:
    """The frame with its ``group`` column set by ``spec`` and every roll checked.

    Args:
        frame: contract frame (``station``, ``gx..gz`` g, ``bx..bz``; ``group`` for ``column``).
        spec: a :func:`parse_groups` value (None: ``default``).
        source: the file, for messages.
        default: the mode when ``spec`` is None.
        no_roll_hint: the probable cause to add when no roll is found (e.g. a mounting not given).
    Returns:
        (frame with an int64 ``group`` column, notices).
    Raises:
        DataError: no ``group`` column for ``column``; no roll; a group that is not a plausible roll.
        SettingError: a shot range that holds fewer shots than a roll needs.
    """
    mode = default if spec is None else spec
    G = frame[["gx", "gy", "gz"]].to_numpy(np.float64)
    B = frame[["bx", "by", "bz"]].to_numpy(np.float64)
    notices = []
    if mode == "column":
        if "group" not in frame.columns:
            raise DataError(f"{source}: no 'group' column: give one (shots of one true direction share a group), "
                            "or let icgo find the rolls (groups=auto), or give them (groups=[first-last,...])")
        groups = frame["group"].to_numpy()
    elif mode == "auto":
        found = rolls.find_rolls(G, B)
        groups = found.groups
        if found.runs:
            notices.append("rolls found from the data: " + "; ".join(
                f"shots {_station_ids(frame, groups, groups[a])}" for a, _ in found.runs))
        if found.too_noisy:
            raise DataError(f"{source}: {found.too_noisy}; give the rolls (groups=[first-last,...])")
        if not found.runs:
            other = [f"shots {rolls.shot_ranges(frame['station'].to_numpy()[a:b])} turn about an axis "
                     f"{c.axis_to_z_deg:.0f} deg from it" for a, b, c in found.rejected if c.axis_to_z_deg > rolls.AXIS_TO_Z_DEG]
            raise DataError(f"{source}: no roll about the pointing axis (tool z) found: no run of "
                            f"{rolls.MIN_ROLLED_SHOTS} or more consecutive shots turned about it (docs/calibrate.md, "
                            "Rolls)" + (f"; {', '.join(other)}" if other else "")
                            + (f"; probable cause: {no_roll_hint}" if no_roll_hint else
                               "; give the rolls with groups=[first-last,...] if they are not in shot order"))
        for a, b, c in found.rejected:
            notices.append(f"shots {rolls.shot_ranges(frame['station'].to_numpy()[a:b])} turn together but are not "
                           f"a roll about the pointing axis ({'; '.join(c.reasons)}): kept as single shots")
    else:
        groups = _groups_from_ranges(frame["station"].to_numpy(), mode)
    bad = {g: c for g, c in rolls.check_groups(G, B, groups).items() if not c.ok}
    if bad:
        g, c = next(iter(bad.items()))
        two = " (two rolls in one group?)" if c.plane_g > rolls.PLANE_TOL_G or c.plane_b > rolls.PLANE_TOL_B else ""
        fix = "fix the groups or let icgo find the rolls (groups=auto)" if mode != "auto" else "give groups="
        raise DataError(f"{source}: group {g} (shots {_station_ids(frame, groups, g)}) is not a plausible roll: "
                        f"{'; '.join(c.reasons)}{two}{'' if len(bad) == 1 else f'; {len(bad) - 1} more such group(s)'}"
                        f"; {fix}")
    if not rolls.rolled_ids(groups):
        raise DataError(f"{source}: no roll ({rolls.MIN_ROLLED_SHOTS} or more shots about one pointing direction) "
                        "among the groups" + (f"; probable cause: {no_roll_hint}" if no_roll_hint else ""))
    return frame.assign(group=np.asarray(groups, np.int64)), notices


def roll_table(frame: pd.DataFrame) -> pd.DataFrame:
    """The rolls of a grouped frame, one row each: group, shots (station ranges), n, raw inclination (deg),
    roll span (deg), out-of-plane distances of gravity (g) and field (x median |B|), roll axis vs tool z (deg)."""
    G = frame[["gx", "gy", "gz"]].to_numpy(np.float64)
    B = frame[["bx", "by", "bz"]].to_numpy(np.float64)
    groups = frame["group"].to_numpy()
    rows = []
    for g, c in rolls.check_groups(G, B, groups).items():
        rows.append({"group": int(g), "shots": _station_ids(frame, groups, g), "n": c.n,
                     "inclination_deg": c.inclination_deg, "roll_span_deg": c.span_deg, "plane_g": c.plane_g,
                     "plane_b": c.plane_b, "axis_to_z_deg": c.axis_to_z_deg})
    return pd.DataFrame(rows)
