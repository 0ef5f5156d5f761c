"""What makes a group of static shots a roll, and the check of a given group against its shots.

A *roll* is a run of shots taken while the instrument is turned about its pointing axis (tool z) with the
pointing direction held fixed: the shots share one true direction, which the calibrations and the peer's
score (:func:`icgo.models.cal_pointing.group_spread_deg`) rely on. Turning about one axis keeps the component of
gravity and of the field along that axis constant while the rest turns, so the raw readings of each sensor lie on
one plane perpendicular to the roll axis (an affine sensor model maps the circle they trace to an ellipse
in a plane: bias, scale, cross-axis and hard iron do not move them off it). A group of shots is a
**plausible roll** (:func:`check_roll`) when

* the raw gravity readings lie within :data:`PLANE_TOL_G` (g) of one plane and the raw field readings within
  :data:`PLANE_TOL_B` (x median |B|) of one plane: the pointing axis' gravity and field components are
  constant within those tolerances;
* the two planes' normals (the roll axis seen by each sensor) agree within :data:`AXIS_AGREE_DEG`;
* the roll axis is within :data:`AXIS_TO_Z_DEG` of tool z (the pointing axis of the mounting given);
* both sensors turn (the circle radius of gravity is at least :data:`MIN_RADIUS_G` g and of the field at
  least :data:`MIN_RADIUS_B` x median |B|: a pointing axis away from vertical and from the field line),
  and the roll angles span at least :data:`MIN_SPAN_DEG` (the largest gap between consecutive roll
  angles is at most 360 - MIN_SPAN_DEG);
* it has at least :data:`MIN_ROLLED_SHOTS` shots;
* and, among the rolls of one recording (:func:`check_groups`), each turns about the same body axis as the
  others within :data:`ROLLS_AXIS_AGREE_DEG` (a group whose shots point two ways fits a tilted plane).

:func:`off_plane_shots` names the shots of a group that leave its planes (the shots that disagree with a
layout's group). Finding rolls where no layout says where they are is an algorithm, in
:mod:`icgo.models.rolls`; this module is the definition both it and the readers of :mod:`icgo.io` check
against.

Tolerances (measured on the 9 bundled circuitpython-mag-cal devices, 18 rolls, with
``tests/test_rolls.py::test_bundled_rolls_are_plausible_and_merged_rolls_are_not``): within a roll the
raw gravity leaves its plane by at most 0.0035 g and the field by at most 0.002 |B|; the two sensors'
roll axes agree within 1.7 deg and lie 1.3-3.8 deg from tool z. The two rolls of a device are 7 deg
apart (0.13 g in raw G_z); merged into one group they leave the planes by 0.064-0.069 g and
0.083-0.108 |B|. The tolerances sit between: 0.03 g (about 1.7 deg of pointing wobble) and 0.03 |B|,
about 9x the largest within-roll value and half the merged one, so two rolls 0.06 g (3.5 deg) or more
apart are never one group; 10 deg between the sensors' axes (a consumer magnetometer's soft iron turns the
field plane's normal by a few degrees); 25 deg from tool z (a mounting error is 90 or 180 deg).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Smallest group treated as rolled about the pointing axis (axis alignment, joint fit, roll finding).
MIN_ROLLED_SHOTS = 4

#: Largest out-of-plane distance of a roll's raw gravity readings, g.
PLANE_TOL_G = 0.03
#: ... of its raw field readings, as a fraction of the recording's median |B|.
PLANE_TOL_B = 0.03
#: Largest angle between the gravity and the field roll axes, deg.
AXIS_AGREE_DEG = 10.0
#: Largest angle between the roll axis and tool z (the pointing axis), deg.
AXIS_TO_Z_DEG = 25.0
#: Largest angle between the roll axes of two rolls of one recording (each sensor's), deg: the roll axis is a
#: body axis. The two rolls of each bundled device agree within 0.2 deg; half a roll pointing 4 deg
#: elsewhere tilts its fitted plane by 2.7 deg while staying within the plane tolerances.
ROLLS_AXIS_AGREE_DEG = 2.0
#: Smallest circle radius of the gravity readings (g) and of the field (x median |B|) about the roll axis.
MIN_RADIUS_G = 0.15
MIN_RADIUS_B = 0.15
#: Smallest span of the roll angles, deg.
MIN_SPAN_DEG = 90.0


class RollCheck(NamedTuple):
    """What :func:`check_roll` measured on one group of shots.

    Attributes:
        n: shots. plane_g: largest out-of-plane distance of gravity, g. plane_b: of the field, x median |B|.
        axis_agree_deg: angle between the gravity and field plane normals. axis_to_z_deg: roll axis vs tool z.
        radius_g: median circle radius of gravity (g). radius_b: of the field (x median |B|).
        span_deg: span of the roll angles (360 minus the largest gap).
        inclination_deg: mean raw inclination of the shots (from gravity, deg from vertical).
        reasons: one short phrase per failed criterion (empty: a plausible roll).
        axes: (gravity plane normal (3,), field plane normal (3,)), each with a non-negative z, or None.
    """

    n: int
    plane_g: float
    plane_b: float
    axis_agree_deg: float
    axis_to_z_deg: float
    radius_g: float
    radius_b: float
    span_deg: float
    inclination_deg: float
    reasons: tuple
    axes: tuple | None = None

    @property
    def ok(self) -> bool:
        return not self.reasons


def plane_fit(v):
    """Total-least-squares plane of points (n, 3): (unit normal with n_z >= 0, largest |distance|)."""
    c = v.mean(0)
    normal = np.linalg.svd(v - c)[2][-1]
    normal = normal if normal[2] >= 0 else -normal
    return normal, float(np.max(np.abs((v - c) @ normal)))


def _angles_about(v, normal):
    """Roll angles (deg) and median radius of points v (n, 3) about the axis through the origin along ``normal``."""
    perp = v - np.outer(v @ normal, normal)
    e1 = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    return np.degrees(np.arctan2(perp @ e2, perp @ e1)), float(np.median(np.linalg.norm(perp, axis=1)))


def span_deg(angles) -> float:
    """360 minus the largest gap between the sorted angles (deg): the arc the angles cover."""
    a = np.sort(np.mod(np.asarray(angles, np.float64), 360.0))
    if a.size < 2:
        return 0.0
    return float(360.0 - np.max(np.diff(np.concatenate([a, a[:1] + 360.0]))))


def axis_angle_deg(u, v) -> float:
    """Angle (deg, 0-90) between two axes given by unit vectors (their signs ignored)."""
    return float(np.degrees(np.arccos(np.clip(abs(float(u @ v)), 0.0, 1.0))))


def plane_fits(G, B, b_scale):
    """(gravity normal, its plane distance, field normal, its plane distance / b_scale, their angle)."""
    ng, dg = plane_fit(G)
    nb, db = plane_fit(B / b_scale)
    return ng, dg, nb, db, axis_angle_deg(ng, nb)


def check_roll(G, B, b_scale: float) -> RollCheck:
    """Whether shots are a plausible roll about the pointing axis (the module doc's criteria).

    Args:
        G: (n, 3) raw gravity, tool frame, g. B: (n, 3) raw field, tool frame (any unit).
        b_scale: the recording's median |B|, same unit as B.
    Returns:
        :class:`RollCheck` (``reasons`` empty for a plausible roll).
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    n = len(G)
    inc = float(np.degrees(np.mean(np.arccos(np.clip(G[:, 2] / np.linalg.norm(G, axis=1), -1, 1))))) if n else np.nan
    if n < 3:
        return RollCheck(n, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, 0.0, inc,
                         (f"{n} shots < {MIN_ROLLED_SHOTS}",))
    ng, dg, nb, db, agree = plane_fits(G, B, b_scale)
    to_z = axis_angle_deg(ng, np.array([0.0, 0.0, 1.0]))
    ang_g, rg = _angles_about(G, ng)
    _, rb = _angles_about(B / b_scale, nb)
    span = span_deg(ang_g)
    reasons = []
    if n < MIN_ROLLED_SHOTS:
        reasons.append(f"{n} shots < {MIN_ROLLED_SHOTS}")
    if dg > PLANE_TOL_G:
        reasons.append(f"gravity leaves the roll plane by {dg:.3f} g > {PLANE_TOL_G:g} g")
    if db > PLANE_TOL_B:
        reasons.append(f"the field leaves the roll plane by {db:.3f} |B| > {PLANE_TOL_B:g} |B|")
    if rg < MIN_RADIUS_G or rb < MIN_RADIUS_B:
        reasons.append(f"the sensors barely turn (circle radius {rg:.3f} g, {rb:.3f} |B|; at least "
                       f"{MIN_RADIUS_G:g} each): pointing near vertical or along the field, or not rolled")
    else:
        if agree > AXIS_AGREE_DEG:
            reasons.append(f"gravity and field turn about axes {agree:.1f} deg apart > {AXIS_AGREE_DEG:g}")
        if to_z > AXIS_TO_Z_DEG:
            reasons.append(f"the roll axis is {to_z:.1f} deg from the pointing axis (tool z) > {AXIS_TO_Z_DEG:g}")
        if span < MIN_SPAN_DEG:
            reasons.append(f"roll angles span {span:.0f} deg < {MIN_SPAN_DEG:g}")
    return RollCheck(n, dg, db, agree, to_z, rg, rb, span, inc, tuple(reasons), (ng, nb))


def rolled_ids(groups) -> list:
    """Ids of the groups with at least :data:`MIN_ROLLED_SHOTS` shots (the rolls), sorted."""
    groups = np.asarray(groups)
    ids, counts = np.unique(groups, return_counts=True)
    return [g for g, c in zip(ids.tolist(), counts) if c >= MIN_ROLLED_SHOTS]


def check_groups(G, B, groups) -> dict:
    """:func:`check_roll` of every group with at least MIN_ROLLED_SHOTS shots, and the rolls' axes compared.

    Every pair of rolls whose gravity (or field) roll axes are more than :data:`ROLLS_AXIS_AGREE_DEG`
    apart gets a reason on both: one device turns about one body axis, and a group whose shots point in
    two directions fits a plane tilted away from it.

    Returns:
        {group id: RollCheck}.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    groups = np.asarray(groups)
    b_scale = float(np.median(np.linalg.norm(B, axis=1)))
    out = {g: check_roll(G[groups == g], B[groups == g], b_scale) for g in rolled_ids(groups)}
    turning = [g for g, c in out.items() if c.axes is not None and c.radius_g >= MIN_RADIUS_G
               and c.radius_b >= MIN_RADIUS_B]
    for i, g in enumerate(turning):
        for h in turning[i + 1:]:
            apart = max(axis_angle_deg(out[g].axes[k], out[h].axes[k]) for k in (0, 1))
            if apart > ROLLS_AXIS_AGREE_DEG:
                for a, b in ((g, h), (h, g)):
                    out[a] = out[a]._replace(reasons=out[a].reasons + (
                        f"it turns about an axis {apart:.1f} deg from group {b}'s (> {ROLLS_AXIS_AGREE_DEG:g}: one "
                        "device has one roll axis)",))
    return out


def off_plane_shots(G, B, b_scale: float) -> list[int]:
    """Positions (0-based, within the group) of the shots that leave a group's roll planes.

    The shot farthest from the planes fitted to the group's other shots is set aside, and again, while the
    remaining shots leave their planes by more than :data:`PLANE_TOL_G` / :data:`PLANE_TOL_B` and at least
    :data:`MIN_ROLLED_SHOTS` remain: what is set aside are the shots that disagree with the rest.

    Args:
        G: (n, 3) raw gravity, g. B: (n, 3) raw field. b_scale: the recording's median |B|, B's unit.
    Returns:
        sorted positions; empty when the group's shots lie on their planes (or too few to tell).
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64) / b_scale
    keep = list(range(len(G)))
    out = []
    while len(keep) > MIN_ROLLED_SHOTS:
        _, dg = plane_fit(G[keep])
        _, db = plane_fit(B[keep])
        if dg <= PLANE_TOL_G and db <= PLANE_TOL_B:
            break
        worst, far = None, -1.0
        for i in keep:
            rest = [k for k in keep if k != i]
            (ng, _), (nb, _) = plane_fit(G[rest]), plane_fit(B[rest])
            d = max(abs(float((G[i] - G[rest].mean(0)) @ ng)) / PLANE_TOL_G,
                    abs(float((B[i] - B[rest].mean(0)) @ nb)) / PLANE_TOL_B)
            if d > far:
                worst, far = i, d
        keep.remove(worst)
        out.append(worst)
    return sorted(out)

def shot_ranges(idx) -> str:
    """Compact ranges of sorted integer ids: ``[0, 1, 2, 5]`` -> ``"0-2, 5"``."""
    idx = sorted(int(i) for i in idx)
    out, start = [], None
    for k, i in enumerate(idx):
        if start is None:
            start = i
        if k + 1 == len(idx) or idx[k + 1] != i + 1:
            out.append(f"{start}" if start == i else f"{start}-{i}")
            start = None
    return ", ".join(out)


def group_findings(G, B, station, groups) -> dict:
    """One phrase per group that is not a plausible roll (:func:`check_groups`), naming its shots, every criterion
    it fails and the shots that leave its planes (:func:`off_plane_shots`).

    Args:
        G, B: (N, 3) raw shots (g; B any unit). station: (N,) shot numbers. groups: (N,) group ids.
    Returns:
        {group id: phrase}, empty when every group of MIN_ROLLED_SHOTS or more shots is a plausible roll.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    station, groups = np.asarray(station), np.asarray(groups)
    b_scale = float(np.median(np.linalg.norm(B, axis=1)))
    out = {}
    for g, c in check_groups(G, B, groups).items():
        if c.ok:
            continue
        rows = np.flatnonzero(groups == g)
        off = off_plane_shots(G[rows], B[rows], b_scale)
        which = f"; shots {shot_ranges(station[rows][off])} leave its roll plane" if off else ""
        out[g] = f"group {g} (shots {shot_ranges(station[rows])}) is not a plausible roll: {'; '.join(c.reasons)}{which}"
    return out


def rolls_off_axis_deg(G, B, groups) -> float | None:
    """When every group of ``groups`` that turns as a roll does (its shots on their planes, radius above
    :data:`MIN_RADIUS_G` / :data:`MIN_RADIUS_B`) turns about an axis more than :data:`AXIS_TO_Z_DEG` from tool z,
    the smallest such angle (deg): the mounting given is not the device's (a layout's rolls then say nothing
    about tool z). Else None (also when no group turns as a roll at all)."""
    turning = [c for c in check_groups(G, B, groups).values()
               if c.radius_g >= MIN_RADIUS_G and c.radius_b >= MIN_RADIUS_B and c.plane_g <= PLANE_TOL_G
               and c.plane_b <= PLANE_TOL_B]
    if turning and all(c.axis_to_z_deg > AXIS_TO_Z_DEG for c in turning):
        return min(c.axis_to_z_deg for c in turning)
    return None

