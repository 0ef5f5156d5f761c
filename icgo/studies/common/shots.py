"""Grouped static shots for the front doors: the file as read (:mod:`icgo.io.shots`), grouped (:mod:`icgo.models.grouping`).

:func:`read_shots` is what ``experiments.calibrate`` and ``experiments.discrepancy`` call for a file of grouped
shots. The groups, in order of precedence:

* shot ranges given (``groups=[8-15,16-23]``) or a contract CSV's ``group`` column: as given, checked against
  the data (a group that is not a plausible roll is refused, naming it);
* ``groups=auto``: the rolls found from the data (the layout's grouping named where it differs);
* a recording in a known layout (a circuitpython-mag-cal recording of 8 + 8 k shots): the layout's groups,
  checked against the data, the shots that disagree named and the data's own grouping reported where it
  differs; the layout is used;
* otherwise the rolls found from the data.

The recording's metadata gains ``grouping`` (:attr:`icgo.models.grouping.Grouping.record`): the report prints it.
"""

from __future__ import annotations

import numpy as np

from icgo.core.errors import DataError
from icgo.io.grouping import groups_from_ranges
from icgo.io.recording import Recording
from icgo.io.shots import read_shot_file
from icgo.models.grouping import by_data, by_layout, rolls_text


def read_shots(path, mag_axes=None, grav_axes=None, groups=None, columns=None, max_shots: int | None = None) -> Recording:
    """A recording of grouped static shots with a ``group`` column and ``meta["grouping"]`` (module doc).

    Args:
        path: a ``.json`` (circuitpython-mag-cal) or a contract CSV.
        mag_axes, grav_axes: mounting strings (raw-layout JSON only), or None.
        groups: the ``groups=`` setting (:func:`icgo.io.grouping.parse_groups`), or None.
        columns: a column map for a CSV field export (:mod:`icgo.io.columns`), or None.
        max_shots: refuse a recording of more shots before any search of its data (None: no limit).
    Raises:
        SettingError: a bad setting (exit 2). DataError: bad data (exit 1); GroupingError (a DataError): shots read
        but no groups can be made of them. All one line.
    """
    f = read_shot_file(path, mag_axes, grav_axes, groups, columns)
    rec, src = f.recording, str(path)
    frame = rec.frame
    if max_shots is not None and len(frame) > max_shots:
        raise DataError(f"{src}: {len(frame)} shots; this door takes at most max_shots={max_shots} (its time and "
                        "memory grow with them; docs/data.md): split the recording, or raise max_shots=")
    G = frame[["gx", "gy", "gz"]].to_numpy(np.float64)
    B = frame[["bx", "by", "bz"]].to_numpy(np.float64)
    station = frame["station"].to_numpy()
    if f.origin in ("column", "ranges"):
        how = "the group column" if f.origin == "column" else "the shot ranges given (groups=)"
        used = rolls_text(station, frame["group"].to_numpy())
        record = {"origin": f.origin, "layout": None if f.layout is None else f.layout.describe(), "used": used,
                  "data_suggest": None, "disagreements": []}
        notices = (f"grouped by {how}: {used}",)
        return rec._replace(meta={**rec.meta, "grouping": record}, notices=list(notices) + list(rec.notices))
    if f.origin == "layout":
        g = by_layout(G, B, station, frame["group"].to_numpy(), f.layout.describe(), src)
    else:
        layout = None if f.layout is None else (f.layout.describe(), groups_from_ranges(station, f.layout.ranges))
        g = by_data(G, B, station, src, layout, f.hint)
    return rec._replace(frame=frame.assign(group=g.groups), meta={**rec.meta, "grouping": g.record},
                        notices=list(g.notices) + list(rec.notices))
