"""Well positions of a survey by minimum curvature, through welleng, and what a correction moves.

Where a survey has measured depth (the contract's optional ``md`` column, m), the stations'
inclination and azimuth place the well: :func:`positions` runs welleng's ``Survey`` (the
minimum-curvature method the industry uses, ISCWSA's reference implementation in Python) on them
and returns north, east and true vertical depth per station. :func:`position_change` does that for
the raw and for the corrected attitude and reports how far the correction moves the bottom hole
(and, where the survey has a reference attitude, how far each one lies from the reference's).

The positions are in the survey's azimuth frame: true north where the metadata gives a declination
(or the field model does), magnetic otherwise; the tie-on is the first station at (0, 0, 0). How a
corrected survey goes on into welleng's ``Survey`` with an ISCWSA error model: docs/qc.md.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from icgo.core.errors import DataError

#: Measured-depth column of the data contract (m).
MD_COLUMN = "md"


def check_md(md, source: str = "survey") -> np.ndarray:
    """``md`` as a float64 array that increases strictly from station to station.

    Raises:
        DataError: one line naming the first station where it does not.
    """
    md = np.asarray(md, np.float64)
    if md.ndim != 1 or len(md) < 2:
        raise DataError(f"{source}: positions need at least two stations with measured depth")
    step = np.diff(md)
    if not np.all(step > 0):
        i = int(np.argmax(~(step > 0)))
        raise DataError(f"{source}: column 'md' must increase from station to station for positions (row {i + 2}: "
                        f"{md[i + 1]:g} m after {md[i]:g} m); sort the survey by depth and keep one shot per depth")
    return md


def positions(md, inc_deg, azi_deg, start=(0.0, 0.0, 0.0)) -> pd.DataFrame:
    """North, east and TVD of every station by minimum curvature (welleng ``Survey``), tie-on at ``start``.

    Args:
        md: (N,) measured depth, m, strictly increasing. inc_deg, azi_deg: (N,) inclination and azimuth, deg.
        start: (north, east, TVD) of the first station, m (the origin; a streamed survey's chunk starts at the last
            station of the chunk before: :class:`icgo.survey.apply_stream.StreamedPositions`).
    Returns:
        DataFrame with ``north_m``, ``east_m``, ``tvd_m`` (float64, m).
    """
    from welleng.survey import Survey  # imported here: ~1 s, and only surveys with depth need it

    md = check_md(md)
    s = Survey(md=md, inc=np.asarray(inc_deg, np.float64), azi=np.mod(np.asarray(azi_deg, np.float64), 360.0),
               deg=True, start_nev=[float(v) for v in start])
    return pd.DataFrame({"north_m": np.asarray(s.n, np.float64), "east_m": np.asarray(s.e, np.float64),
                         "tvd_m": np.asarray(s.tvd, np.float64)})


def _shift(a: pd.DataFrame, b: pd.DataFrame) -> dict:
    """Bottom-hole position of ``b`` minus ``a``: north, east, TVD, horizontal and 3-D distance (m)."""
    d = b.iloc[-1].to_numpy(float) - a.iloc[-1].to_numpy(float)
    return {"north_m": float(d[0]), "east_m": float(d[1]), "tvd_m": float(d[2]), "horizontal_m": float(np.hypot(*d[:2])),
            "distance_m": float(np.linalg.norm(d))}


def position_change(md, inc_raw, azi_raw, inc_corrected, azi_corrected, inc_ref=None, azi_ref=None
                    ) -> tuple[pd.DataFrame, dict]:
    """Positions from the raw and the corrected attitude, and the change of the bottom-hole position.

    Args:
        md: (N,) measured depth, m. inc_raw, azi_raw, inc_corrected, azi_corrected: (N,) deg.
        inc_ref, azi_ref: the survey's reference attitude (deg), or None.
    Returns:
        (table with ``north_raw_m, east_raw_m, tvd_raw_m, north_m, east_m, tvd_m`` (corrected), summary):
        the summary holds the measured depth of the last station (``md_m``), the bottom-hole shift the
        correction makes (``correction``: corrected minus raw) and, with a reference, each one's distance
        from the reference's bottom hole (``raw_vs_reference``, ``corrected_vs_reference``).
    """
    raw = positions(md, inc_raw, azi_raw)
    cor = positions(md, inc_corrected, azi_corrected)
    table = pd.concat([raw.add_suffix("_raw").rename(columns=lambda c: c.replace("_m_raw", "_raw_m")), cor], axis=1)
    ref = positions(md, inc_ref, azi_ref) if inc_ref is not None and azi_ref is not None else None
    return table, position_summary(float(np.asarray(md, float)[-1]), len(raw), raw, cor, ref)


def position_summary(md_m: float, stations: int, raw: pd.DataFrame, cor: pd.DataFrame,
                     ref: pd.DataFrame | None = None) -> dict:
    """:func:`position_change`'s summary from the positions' last rows (``raw``, ``cor``, ``ref``: frames whose last
    row is the bottom hole), the last station's measured depth ``md_m`` (m) and the number of stations."""
    summary = {"md_m": md_m, "stations": stations,
               "bottom_hole_raw": {k: float(v) for k, v in raw.iloc[-1].items()},
               "bottom_hole_corrected": {k: float(v) for k, v in cor.iloc[-1].items()},
               "correction": _shift(raw, cor)}
    if ref is not None:
        summary["raw_vs_reference"] = _shift(ref, raw)
        summary["corrected_vs_reference"] = _shift(ref, cor)
    return summary


def trajectory_sentence(summary: dict) -> str:
    """One line: how far the correction moves the bottom hole (and the distances from the reference's)."""
    c = summary["correction"]
    s = (f"bottom hole at {summary['md_m']:.1f} m MD moves {c['distance_m']:.2f} m with the correction (north "
         f"{c['north_m']:+.2f}, east {c['east_m']:+.2f}, TVD {c['tvd_m']:+.2f} m; minimum curvature, welleng)")
    if "corrected_vs_reference" in summary:
        s += (f"; from the reference's bottom hole: raw {summary['raw_vs_reference']['distance_m']:.2f} m, corrected "
              f"{summary['corrected_vs_reference']['distance_m']:.2f} m")
    return s
