"""Which grouping a recording of static shots gets: its layout checked against the data, or the data's own rolls.

A recording in a known instrument layout (:func:`icgo.io.grouping.layout_groups`) is grouped by its layout:
the procedure that took it says which shots are rolls, and a search of the data can only guess (one device's
rolls found at shots 9-13 and 16-23 instead of 8-15 and 16-23 raised its held-out score from 1.27 to 1.85 deg).
:func:`by_layout` checks every group of the layout against the data (:func:`icgo.physics.rolls.group_findings`:
the criteria a group fails and the shots that leave its roll plane), searches the data as a second opinion
(:func:`icgo.models.rolls.find_rolls`) and names both where they differ, but uses the layout; only a mounting
that turns every roll about another axis than the pointing axis is refused, by the reader (nothing calibrates
then).
:func:`by_data` finds the rolls where no layout is known, or where the user asks for it (``groups=auto``), and
names the layout's grouping where one is known and differs.

Both return a :class:`Grouping` whose ``record`` (JSON) the calibrate report prints: the grouping used, where
it came from, and the one the data suggest when they differ.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from icgo.core.errors import GroupingError
from icgo.models.rolls import find_rolls
from icgo.physics.rolls import (
    AXIS_TO_Z_DEG,
    MIN_ROLLED_SHOTS,
    group_findings,
    rolled_ids,
    shot_ranges,
)


class Grouping(NamedTuple):
    """The groups a recording is calibrated with, and why.

    Attributes:
        groups: (n,) int64 group ids (single shots and rolls).
        notices: one line each: how the groups were made, what the data say against them.
        record: ``{"origin", "layout", "used", "data_suggest", "disagreements"}`` (JSON): ``origin`` ``layout``
            or ``data``; ``layout`` the layout's description or None; ``used`` and ``data_suggest`` the rolls'
            shot ranges (``data_suggest`` None when it equals ``used``, or the reason no roll was found);
            ``disagreements`` one phrase per group the data disagree with.
    """

    groups: np.ndarray
    notices: tuple
    record: dict


def rolls_text(station, groups) -> str:
    """``"rolls at shots 8-15; 16-23"`` for a grouping, or ``"no roll"``."""
    station, groups = np.asarray(station), np.asarray(groups)
    ids = rolled_ids(groups)
    return ("rolls at shots " + "; ".join(shot_ranges(station[groups == g]) for g in ids)) if ids else "no roll"


def _same_rolls(a, b) -> bool:
    """Whether two groupings have the same rolls (sets of shots), whatever their ids."""
    def rolls(g):
        g = np.asarray(g)
        return {tuple(np.flatnonzero(g == i)) for i in rolled_ids(g)}
    return rolls(a) == rolls(b)


def _data_suggest(G, B, station):
    """(groups found in the data or None, the phrase for the report)."""
    found = find_rolls(G, B)
    if found.too_noisy:
        return None, f"no grouping ({found.too_noisy})"
    if not found.runs:
        return None, "no roll"
    return found.groups, rolls_text(station, found.groups)


def by_layout(G, B, station, groups, layout: str, source: str) -> Grouping:
    """The layout's groups, checked against the data (module doc).

    Args:
        G, B: (n, 3) raw shots, tool frame (g; B any unit). station: (n,) shot numbers.
        groups: (n,) the layout's group ids. layout: the layout in words (:meth:`icgo.io.grouping.Layout.describe`).
        source: the file, for messages.

    A layout whose rolls all turn about another axis (a mounting not the device's) is refused by the reader
    (:func:`icgo.io.mag_cal_json.read_mag_cal_json`), before this.
    """
    G, B, station, groups = (np.asarray(v) for v in (G, B, station, groups))
    findings = group_findings(G, B, station, groups)
    suggested, suggest_text = _data_suggest(G, B, station)
    used = rolls_text(station, groups)
    notices = [f"grouped by the {layout}"]
    if findings:
        notices.append("the data disagree with the layout: " + "; ".join(findings.values())
                       + "; the layout is used (groups=auto uses the rolls found in the data)")
    differs = suggested is None or not _same_rolls(suggested, groups)
    if differs:
        notices.append(f"the data suggest {suggest_text} (the layout: {used}); the layout is used (groups=auto "
                       "uses the data's)")
    record = {"origin": "layout", "layout": layout, "used": used, "data_suggest": suggest_text if differs else None,
              "disagreements": list(findings.values())}
    return Grouping(np.asarray(groups, np.int64), tuple(notices), record)


def by_data(G, B, station, source: str, layout: tuple | None = None, no_roll_hint: str = "") -> Grouping:
    """The rolls found in the data (:func:`icgo.models.rolls.find_rolls`), every other shot its own group.

    Args:
        G, B, station: as :func:`by_layout`. source: the file, for messages.
        layout: (the layout in words, its (n,) group ids) when the recording has one (``groups=auto`` chosen
            over it), to name where the two differ; None otherwise.
        no_roll_hint: the probable cause to name when no roll is found.
    Raises:
        GroupingError: the shots scatter too much to find rolls, or none is found (one line, with the cause).
    """
    G, B, station = (np.asarray(v) for v in (G, B, station))
    found = find_rolls(G, B)
    if found.too_noisy:
        raise GroupingError(f"{source}: {found.too_noisy}; give the rolls (groups=[first-last,...])"
                        + ("" if layout is None else " or drop groups=auto (the layout's)"))
    if not found.runs:
        other = [f"shots {shot_ranges(station[a:b])} turn about an axis {c.axis_to_z_deg:.0f} deg from it"
                 for a, b, c in found.rejected if c.axis_to_z_deg > AXIS_TO_Z_DEG]
        raise GroupingError(f"{source}: no roll about the pointing axis (tool z) found: no run of "
                        f"{MIN_ROLLED_SHOTS} or more consecutive shots turned about it (docs/calibrate.md, Rolls)"
                        + (f"; {', '.join(other)}" if other else "")
                        + (f"; probable cause: {no_roll_hint}" if no_roll_hint else
                           "; give the rolls with groups=[first-last,...] if they are not in shot order"))
    groups = found.groups
    used = rolls_text(station, groups)
    notices = [f"rolls found from the data: {used}"]
    notices += [f"shots {shot_ranges(station[a:b])} turn together but are not a roll about the pointing axis "
                f"({'; '.join(c.reasons)}): kept as single shots" for a, b, c in found.rejected]
    differs = layout is not None and not _same_rolls(layout[1], groups)
    if differs:
        notices.append(f"the {layout[0]} differs: {rolls_text(station, layout[1])}; the data's are used (groups=auto)")
    record = {"origin": "data", "layout": None if layout is None else layout[0], "used": used,
              "data_suggest": None, "disagreements": []}
    if differs:
        record["layout_grouping"] = rolls_text(station, layout[1])
    return Grouping(np.asarray(groups, np.int64), tuple(notices), record)
