"""Rolled groups of static shots: what makes a group a roll, finding rolls in a recording, checking given ones.

A *roll* is a run of shots taken while the instrument is turned about its pointing axis (tool z) with the
pointing direction held fixed: the shots share one true direction, which the calibrations and the peer's
score (:func:`icgo.methods.calibration.group_spread_deg`) rely on. A roll keeps the component of gravity and
of the field along the roll axis constant while the rest turns, so the raw readings of each sensor lie on
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
* it has at least :data:`icgo.methods.calibration.MIN_ROLLED_SHOTS` shots;
* and, among the rolls of one recording (:func:`check_groups`), each turns about the same body axis as the
  others within :data:`ROLLS_AXIS_AGREE_DEG` (a group whose shots point two ways fits a tilted plane).

:func:`find_rolls` finds them from the data (runs of consecutive shots, then the same search with the
rolls' common axes held fixed), after checking that the shots' scatter (:func:`scatter`) lets rolls be
told apart at all.

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

from icgo.methods.calibration import MIN_ROLLED_SHOTS

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
#: Largest scatter of the shots about each sensor's ellipsoid fit (:func:`scatter`; g, and x median |B|) at
#: which rolls are searched for: a roll's 8 shots leave its plane by up to about 2.5 x the gravity scatter,
#: so above PLANE_TOL_G / 2.5 true rolls break up and a plane tilted to fit a few shots of two rolls passes
#: by chance (seen at 100 x the industrial noise, 30 mg). The field's limit is looser (its scatter about an
#: ellipsoid holds the sensor's non-linearity too). The bundled devices scatter 0.4-0.9 mg and 0.06-0.5 %
#: of the median |B|.
MAX_SCATTER_G = PLANE_TOL_G / 2.5
MAX_SCATTER_B = PLANE_TOL_B


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


def _plane(v):
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


def _angle_deg(u, v) -> float:
    return float(np.degrees(np.arccos(np.clip(abs(float(u @ v)), 0.0, 1.0))))


def _plane_fits(G, B, b_scale):
    """(gravity normal, its plane distance, field normal, its plane distance / b_scale, their angle)."""
    ng, dg = _plane(G)
    nb, db = _plane(B / b_scale)
    return ng, dg, nb, db, _angle_deg(ng, nb)


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
    ng, dg, nb, db, agree = _plane_fits(G, B, b_scale)
    to_z = _angle_deg(ng, np.array([0.0, 0.0, 1.0]))
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


def _coplanar(G, B, b_scale, any_axis: bool, axes=None) -> bool:
    """The plane and axis criteria (what a growing run must keep; radius and span are judged at its end).

    ``any_axis``: do not ask the roll axis to be near tool z (to find rolls about another axis, the sign of
    a mounting not given). ``axes``: (gravity normal, field normal) held fixed instead of fitted: the
    components along them must stay within the tolerances of their mean."""
    if len(G) < 4 and axes is None:
        return True
    if axes is not None:
        hg, hb = G @ axes[0], (B / b_scale) @ axes[1]
        return bool(np.max(np.abs(hg - hg.mean())) <= PLANE_TOL_G and np.max(np.abs(hb - hb.mean())) <= PLANE_TOL_B)
    ng, dg, _, db, agree = _plane_fits(G, B, b_scale)
    return (dg <= PLANE_TOL_G and db <= PLANE_TOL_B and agree <= AXIS_AGREE_DEG
            and (any_axis or _angle_deg(ng, np.array([0.0, 0.0, 1.0])) <= AXIS_TO_Z_DEG))


def _runs(G, B, b_scale, **criterion) -> list:
    """Maximal runs of consecutive shots meeting :func:`_coplanar` (``criterion``), at least MIN_ROLLED_SHOTS long."""
    n = len(G)

    def grow(s):  # end (exclusive) of the longest run from s, or s when its first shots do not qualify
        e = s + MIN_ROLLED_SHOTS
        if e > n or not _coplanar(G[s:e], B[s:e], b_scale, **criterion):
            return s
        while e < n and _coplanar(G[s:e + 1], B[s:e + 1], b_scale, **criterion):
            e += 1
        return e

    runs, s = [], 0
    while s + MIN_ROLLED_SHOTS <= n:
        e = grow(s)
        # a shot before a roll that happens to fit the roll's first shots stops the run early;
        # starting one shot later then runs further
        while e > s and grow(s + 1) > e:
            s += 1
            e = grow(s)
        if e == s:
            s += 1
            continue
        runs.append((s, e))
        s = e
    return runs


def scatter(G, B) -> tuple[float, float]:
    """The shots' scatter about each sensor's ellipsoid fit (:func:`icgo.methods.calibration.ellipsoid_fit`):
    RMS of ``|G_c| - 1`` (g) and of ``|B_c| - 1`` times the fitted radius in raw units over the median raw |B|
    (the units of :data:`PLANE_TOL_B`); noise and non-linearity together. (nan, nan) when the shots do not
    span the orientations the fits need; (inf, inf) when they do but no ellipsoid fits them."""
    from icgo.methods.calibration import MIN_ORIENTATIONS_ELLIPSOID, count_distinct_orientations, ellipsoid_fit

    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    if count_distinct_orientations(G, B) < MIN_ORIENTATIONS_ELLIPSOID:
        return float("nan"), float("nan")
    out = []
    for v in (G, B):
        try:
            x = ellipsoid_fit(v, 1.0, check=False)
        except ValueError:  # enough orientations, yet no ellipsoid: the shots scatter too much for one
            return float("inf"), float("inf")
        m = x[:9].reshape(3, 3)
        rms = float(np.sqrt(np.mean((np.linalg.norm((v - x[9:]) @ m.T, axis=1) - 1.0) ** 2)))
        radius = abs(float(np.linalg.det(m))) ** (-1.0 / 3.0)  # raw units per unit of the fitted sphere
        out.append(rms if v is G else rms * radius / float(np.median(np.linalg.norm(B, axis=1))))
    return out[0], out[1]


class Rolls(NamedTuple):
    """Rolls found in a recording (:func:`find_rolls`).

    Attributes:
        groups: (n,) int64 group ids: single shots 0, 1, ... in shot order, then the rolls.
        runs: ((start, stop), ...) shot ranges of the rolls (stop exclusive).
        rejected: ((start, stop, RollCheck), ...) runs of coplanar shots that are not plausible rolls. When
            no roll is found, the runs rolled about any axis: rolls about another axis than tool z say that
            the mounting (``mag_axes`` / ``grav_axes``) is probably not the one given.
        too_noisy: why no roll was searched for (the shots scatter more than :data:`MAX_SCATTER_G` /
            :data:`MAX_SCATTER_B`), or "".
    """

    groups: np.ndarray
    runs: tuple
    rejected: tuple
    too_noisy: str = ""


def groups_from_runs(n: int, runs) -> np.ndarray:
    """(n,) group ids: every shot outside ``runs`` its own group 0, 1, ... in shot order, then one id per run."""
    group = np.full(n, -1, np.int64)
    for j, (a, b) in enumerate(runs):
        group[a:b] = j
    singles = np.flatnonzero(group < 0)
    out = np.empty(n, np.int64)
    out[singles] = np.arange(singles.size)
    for j, (a, b) in enumerate(runs):
        out[a:b] = singles.size + j
    return out


def find_rolls(G, B, any_axis: bool = False) -> Rolls:
    """Rolls in a recording, found from the data: maximal runs of consecutive shots that are plausible rolls.

    From each shot in turn, a run grows while its shots stay within the plane tolerances
    (:data:`PLANE_TOL_G`, :data:`PLANE_TOL_B`, :data:`AXIS_AGREE_DEG`); when the run from the next shot
    reaches further, the first shot is dropped (a single shot that happened to fit the first shots of a
    roll). A run of at least :data:`icgo.methods.calibration.MIN_ROLLED_SHOTS` shots that passes
    :func:`check_roll` is a roll, one that fails is kept in ``rejected``; the search goes on after it. Two rolls taken one after the other in
    different directions break the run where the second begins (its shots leave the first one's planes).

    First the shots' scatter (:func:`scatter`) is checked: above :data:`MAX_SCATTER_G` /
    :data:`MAX_SCATTER_B` no roll is searched for (``too_noisy`` says why).

    Args:
        G: (n, 3) raw gravity, tool frame, g. B: (n, 3) raw field, tool frame (any unit).
        any_axis: grow runs rolled about any axis (they fail :func:`check_roll` unless about tool z).
            Without it and when no roll is found, the search is repeated with it, and the runs it finds are
            returned as ``rejected``.
    Returns:
        :class:`Rolls`.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    n = len(G)
    b_scale = float(np.median(np.linalg.norm(B, axis=1)))
    sg, sb = scatter(G, B)
    if sg > MAX_SCATTER_G or sb > MAX_SCATTER_B:
        return Rolls(groups_from_runs(n, []), (), (), f"the shots scatter {sg:.3g} g and {sb:.3g} |B| about "
                     f"each sensor's ellipsoid (at most {MAX_SCATTER_G:.3g} g and {MAX_SCATTER_B:.3g} |B|): too noisy "
                     "to tell rolls apart from the data")
    runs, rejected = [], []
    for a, b in _runs(G, B, b_scale, any_axis=any_axis):
        chk = check_roll(G[a:b], B[a:b], b_scale)
        (runs if chk.ok else rejected).append((a, b) if chk.ok else (a, b, chk))
    if runs and not any_axis:
        # the device's roll axis is one body axis: with each sensor's axis averaged over the rolls found and
        # held fixed, shots of two rolls in different directions differ in their components along it, even
        # where a plane tilted to fit a few shots of each let them pass the first search
        axes = []
        for sensor, scale in ((G, 1.0), (B, b_scale)):
            acc = sum((b - a) * _plane(sensor[a:b] / scale)[0] for a, b in runs)
            axes.append(acc / np.linalg.norm(acc))
        runs = [(a, b) for a, b in _runs(G, B, b_scale, any_axis=False, axes=tuple(axes))
                if check_roll(G[a:b], B[a:b], b_scale).ok]
    if not runs and not any_axis:
        return Rolls(groups_from_runs(n, runs), (), find_rolls(G, B, any_axis=True).rejected)
    return Rolls(groups_from_runs(n, runs), tuple(runs), tuple(rejected))


def rolled_ids(groups) -> list:
    """Ids of the groups with at least :data:`icgo.methods.calibration.MIN_ROLLED_SHOTS` shots (the rolls), sorted."""
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
            apart = max(_angle_deg(out[g].axes[k], out[h].axes[k]) for k in (0, 1))
            if apart > ROLLS_AXIS_AGREE_DEG:
                for a, b in ((g, h), (h, g)):
                    out[a] = out[a]._replace(reasons=out[a].reasons + (
                        f"it turns about an axis {apart:.1f} deg from group {b}'s (> {ROLLS_AXIS_AGREE_DEG:g}: one "
                        "device has one roll axis)",))
    return out


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
