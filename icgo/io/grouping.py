"""Which shots of a recording share one true direction: the ``groups=`` setting, the instrument's layout, given groups.

Every front door that reads grouped static shots (``experiments.calibrate``, ``experiments.discrepancy``,
``python -m icgo.io check|convert``) takes one ``groups=`` setting (:func:`parse_groups`):

* unset: a recording in a known instrument layout (:data:`LAYOUTS`, :func:`layout_groups`) is grouped by
  its layout; a contract CSV by its ``group`` column; any other recording by the rolls found from the data;
* ``auto``: the rolls found from the data (:mod:`icgo.models.rolls`), whatever the layout;
* ``column``: the recording's ``group`` column as given;
* shot ranges ``[8-15,16-23]`` (or the string ``"8-15,16-23"``): each range of ``station`` values (both
  ends included) is one roll, every other shot its own group.

This module reads and makes groups; it does not search the data. Groups given (a column, ranges) must be
plausible rolls (:func:`check_given`, against :mod:`icgo.physics.rolls`), else the recording is refused in one
line naming the group, its shots and the criterion it fails; a layout's groups are checked and the shots
that disagree named by :mod:`icgo.models.grouping`, which also finds rolls where no layout is known.
"""

from __future__ import annotations

import re
from typing import NamedTuple

import numpy as np
import pandas as pd

from icgo.core.errors import DataError, SettingError
from icgo.physics import rolls

#: The named ``groups=`` modes.
GROUP_MODES = ("auto", "column")
_RANGE = re.compile(r"^\s*(\d+)\s*(?:-\s*(\d+))?\s*$")


class Layout(NamedTuple):
    """A known instrument layout of a recording: where its rolls are by the procedure that took it.

    Attributes:
        name: e.g. ``circuitpython-mag-cal``. rule: the procedure in words. ranges: ((first, last), ...) the
        rolls' shot numbers, both ends included.
    """

    name: str
    rule: str
    ranges: tuple

    def describe(self) -> str:
        return f"{self.name} layout ({self.rule}: rolls at shots {', '.join(f'{a}-{b}' for a, b in self.ranges)})"


#: Shots of the circuitpython-mag-cal procedure before its rolls (single shots in distinct orientations), and
#: the shots per roll (mag_cal docs/howto.rst; ``read_fixture`` reads shots 8-15 and 16-23 of its 24).
MAG_CAL_SINGLES = 8
MAG_CAL_ROLL = 8
#: The known layouts, by name: the rule in words (docs/calibrate.md, "Layouts").
LAYOUTS = {"circuitpython-mag-cal": f"{MAG_CAL_SINGLES} single shots, then rolls of {MAG_CAL_ROLL}"}


def layout_groups(name: str, n_shots: int) -> Layout | None:
    """The layout of an ``n_shots`` recording of instrument ``name``, or None when the count does not fit it.

    circuitpython-mag-cal: ``8 + 8 k`` shots (k >= 1; 24 is the procedure's two rolls) are 8 single shots,
    then k rolls of 8 consecutive shots.
    """
    if name != "circuitpython-mag-cal":
        return None
    k, extra = divmod(n_shots - MAG_CAL_SINGLES, MAG_CAL_ROLL)
    if n_shots <= MAG_CAL_SINGLES or extra:
        return None
    ranges = tuple((MAG_CAL_SINGLES + j * MAG_CAL_ROLL, MAG_CAL_SINGLES + (j + 1) * MAG_CAL_ROLL - 1) for j in range(k))
    return Layout(name, LAYOUTS[name], ranges)

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


def groups_from_ranges(station: np.ndarray, ranges) -> np.ndarray:
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


def check_given(frame: pd.DataFrame, groups, source: str, what: str = "the groups") -> None:
    """Refuse groups given by the user (a ``group`` column, shot ranges) that are not plausible rolls.

    Args:
        frame: contract frame (``station``, ``gx..gz`` g, ``bx..bz``). groups: (n,) group ids.
        source: the file, for messages. what: how the groups were given, for the fix.
    Raises:
        DataError: one line naming the first bad group, its shots (those leaving its planes among them) and
            the criteria it fails; or no roll among the groups.
    """
    G = frame[["gx", "gy", "gz"]].to_numpy(np.float64)
    B = frame[["bx", "by", "bz"]].to_numpy(np.float64)
    bad = rolls.group_findings(G, B, frame["station"].to_numpy(), groups)
    if bad:
        g, phrase = next(iter(bad.items()))
        c = rolls.check_groups(G, B, groups)[g]
        two = " (two rolls in one group?)" if c.plane_g > rolls.PLANE_TOL_G or c.plane_b > rolls.PLANE_TOL_B else ""
        raise DataError(f"{source}: {phrase}{two}"
                        f"{'' if len(bad) == 1 else f'; {len(bad) - 1} more such group(s)'}"
                        f"; fix {what} or let icgo find the rolls (groups=auto)")
    if not rolls.rolled_ids(groups):
        raise DataError(f"{source}: no roll ({rolls.MIN_ROLLED_SHOTS} or more shots about one pointing direction) "
                        f"among {what}")


def roll_table(frame: pd.DataFrame) -> pd.DataFrame:
    """The rolls of a grouped frame, one row each: group, shots (station ranges), n, raw inclination (deg),
    roll span (deg), out-of-plane distances of gravity (g) and field (x median |B|), roll axis vs tool z (deg), and
    the criteria it fails (:func:`icgo.physics.rolls.check_groups`; a layout's group may fail them)."""
    G = frame[["gx", "gy", "gz"]].to_numpy(np.float64)
    B = frame[["bx", "by", "bz"]].to_numpy(np.float64)
    groups = frame["group"].to_numpy()
    rows = []
    for g, c in rolls.check_groups(G, B, groups).items():
        rows.append({"group": int(g), "shots": _station_ids(frame, groups, g), "n": c.n,
                     "inclination_deg": c.inclination_deg, "roll_span_deg": c.span_deg, "plane_g": c.plane_g,
                     "plane_b": c.plane_b, "axis_to_z_deg": c.axis_to_z_deg,
                     "check": "; ".join(c.reasons) or "a plausible roll"})
    return pd.DataFrame(rows)
