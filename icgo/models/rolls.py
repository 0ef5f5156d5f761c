"""Finding rolls in a recording where no layout says where they are: runs of consecutive shots that are rolls.

What a roll is, and the check of a group against its shots, is :mod:`icgo.physics.rolls`; the readers of
:mod:`icgo.io` group a recording by its instrument's layout or by groups given. :func:`find_rolls` searches the
data (runs of consecutive shots, then the same search with the rolls' common axes held fixed), after checking
that the shots' scatter (:func:`scatter`) lets rolls be told apart at all. :mod:`icgo.models.grouping` composes
the two: a layout checked against what the data suggest, or the data's rolls where no layout is known.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from icgo.physics.rolls import (
    AXIS_AGREE_DEG,
    AXIS_TO_Z_DEG,
    MIN_ROLLED_SHOTS,
    PLANE_TOL_B,
    PLANE_TOL_G,
    axis_angle_deg,
    check_roll,
    plane_fit,
    plane_fits,
)

#: Largest scatter of the shots about each sensor's ellipsoid fit (:func:`scatter`; g, and x median |B|) at
#: which rolls are searched for: a roll's 8 shots leave its plane by up to about 2.5 x the gravity scatter,
#: so above PLANE_TOL_G / 2.5 true rolls break up and a plane tilted to fit a few shots of two rolls passes
#: by chance (seen at 100 x the industrial noise, 30 mg). The field's limit is looser (its scatter about an
#: ellipsoid holds the sensor's non-linearity too). The bundled devices scatter 0.4-0.9 mg and 0.06-0.5 %
#: of the median |B|.
MAX_SCATTER_G = PLANE_TOL_G / 2.5
MAX_SCATTER_B = PLANE_TOL_B


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
    ng, dg, _, db, agree = plane_fits(G, B, b_scale)
    return (dg <= PLANE_TOL_G and db <= PLANE_TOL_B and agree <= AXIS_AGREE_DEG
            and (any_axis or axis_angle_deg(ng, np.array([0.0, 0.0, 1.0])) <= AXIS_TO_Z_DEG))


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


def scatter(G, B) -> tuple[float, float, str]:
    """The shots' scatter about each sensor's ellipsoid fit (:func:`icgo.models.calibration.ellipsoid_fit`):
    RMS of ``|G_c| - 1`` (g) and of ``|B_c| - 1`` times the fitted radius in raw units over the median raw |B|
    (the units of :data:`PLANE_TOL_B`); noise and non-linearity together.

    Returns:
        (gravity scatter g, field scatter x median |B|, why not measured): both NaN with an empty reason when
        the shots do not span the orientations the fits need (nothing to judge); both NaN with the reason when
        they do but no ellipsoid fits one sensor's shots (they scatter too much for one).
    """
    from icgo.models.calibration import MIN_ORIENTATIONS_ELLIPSOID, count_distinct_orientations, ellipsoid_fit

    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    if count_distinct_orientations(G, B) < MIN_ORIENTATIONS_ELLIPSOID:
        return float("nan"), float("nan"), ""
    out = []
    for v, name in ((G, "gravity"), (B, "field")):
        try:
            x = ellipsoid_fit(v, 1.0, check=False)
        except ValueError:  # enough orientations, yet no ellipsoid: the shots scatter too much for one
            return float("nan"), float("nan"), f"no ellipsoid could be fitted to the {name} shots"
        m = x[:9].reshape(3, 3)
        rms = float(np.sqrt(np.mean((np.linalg.norm((v - x[9:]) @ m.T, axis=1) - 1.0) ** 2)))
        radius = abs(float(np.linalg.det(m))) ** (-1.0 / 3.0)  # raw units per unit of the fitted sphere
        out.append(rms if v is G else rms * radius / float(np.median(np.linalg.norm(B, axis=1))))
    return out[0], out[1], ""


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
    roll). A run of at least :data:`icgo.physics.rolls.MIN_ROLLED_SHOTS` shots that passes
    :func:`icgo.physics.rolls.check_roll` is a roll, one that fails is kept in ``rejected``; the search goes on after it. Two rolls taken one after the other in
    different directions break the run where the second begins (its shots leave the first one's planes).

    First the shots' scatter (:func:`scatter`) is checked: above :data:`MAX_SCATTER_G` /
    :data:`MAX_SCATTER_B` no roll is searched for (``too_noisy`` says why).

    Args:
        G: (n, 3) raw gravity, tool frame, g. B: (n, 3) raw field, tool frame (any unit).
        any_axis: grow runs rolled about any axis (they fail :func:`icgo.physics.rolls.check_roll` unless about tool z).
            Without it and when no roll is found, the search is repeated with it, and the runs it finds are
            returned as ``rejected``.
    Returns:
        :class:`Rolls`.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    n = len(G)
    b_scale = float(np.median(np.linalg.norm(B, axis=1)))
    sg, sb, why = scatter(G, B)
    if why:
        return Rolls(groups_from_runs(n, []), (), (), f"{why}: the shots scatter too much to tell rolls apart from "
                     "the data")
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
            acc = sum((b - a) * plane_fit(sensor[a:b] / scale)[0] for a, b in runs)
            axes.append(acc / np.linalg.norm(acc))
        runs = [(a, b) for a, b in _runs(G, B, b_scale, any_axis=False, axes=tuple(axes))
                if check_roll(G[a:b], B[a:b], b_scale).ok]
    if not runs and not any_axis:
        return Rolls(groups_from_runs(n, runs), (), find_rolls(G, B, any_axis=True).rejected)
    return Rolls(groups_from_runs(n, runs), tuple(runs), tuple(rejected))


