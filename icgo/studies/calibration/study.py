"""Magnetometer calibration from grouped static shots: every method, in-sample and held out, with sanity.

A recording is static shots (``G`` g, ``B`` nT) with a ``group`` column: shots of
one group share one true direction. Groups of at least :data:`icgo.physics.rolls.MIN_ROLLED_SHOTS` shots are
*rolled groups* (turned about the pointing axis); the others are single shots. No
reference attitude is needed.

Methods (unit-sphere fits; :func:`fit_recording`):

* ``ellipsoid``: accelerometer and magnetometer ellipsoid fits;
* ``twelve+axis``: 12-parameter least squares (dot invariance eq. 5 + modulus), then
  one rotation putting the rolled groups' roll axis on tool z;
* ``misma+axis``: MISMA on the same objective, in a box in the data's units that
  contains the least-squares solution (:func:`misma_box`), then the axis rotation;
* ``joint``: ``twelve+axis`` with the accelerometer's 12 parameters refitted on the rolls' directions, one
  dip and unit spheres, regularised toward small accelerometer errors with its strength chosen by
  leave-one-group-out (:mod:`icgo.models.joint`);
* ``twelve+axis+relm``: ``twelve+axis`` plus a RELM on its field residual, trained by group
  consistency with its ridge chosen by leave-one-group-out on the training shots (:mod:`icgo.models.mag_relm`);
* the peer package circuitpython-mag-cal side by side (``peer_*``), when installed.

Splits (:func:`splits`): in-sample (fit and score on every shot) and one held-out
split per rolled group (fit without it, score on it; one roll: its two interleaved halves). Score: the peer's metric
(:func:`icgo.models.cal_pointing.group_spread_deg`, deg) on the scored rolled groups. Every
fit also gets its physical sanity on all shots (:func:`icgo.models.cal_sanity.sanity`);
a degenerate fit's score is withheld (NaN) and it is never counted as a win, and its mean dip and |B|
(:mod:`icgo.models.cal_site`), checked against the site where it is known. Inside every held-out split the
training shots are split again (:func:`held_out_splits`) for the nested accuracy of the recommendation
(:func:`icgo.studies.calibration.select.recommend`). Every group of a recording is checked to be a plausible
roll first (:func:`icgo.physics.rolls.check_groups`) unless its reader did (a layout's groups are kept where the
data disagree, and named).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.core.errors import DataError
from icgo.core.settings import is_int, need
from icgo.models import calibration as cal
from icgo.models import joint, mag_relm
from icgo.models.cal_pointing import align_to_axis, group_spread_deg, pointing_directions
from icgo.models.cal_sanity import sanity
from icgo.models.cal_site import site_check, site_values
from icgo.models.misma_objective import MismaObjective
from icgo.artifacts.calibration import MagCalibration, mag_calibration, with_residual
from icgo.optim import base
from icgo.optim import misma as misma_opt
from icgo.optim.registry import get
from icgo.physics.rolls import MIN_ROLLED_SHOTS, check_groups, rolled_ids
from icgo.studies.calibration.peer import PEER_METHODS, peer_available, peer_rows
from icgo.studies.common.study import Study

log = logging.getLogger(__name__)

#: Our methods, in table order.
METHODS = ("ellipsoid", "twelve+axis", "misma+axis", "joint", "twelve+axis+relm")


#: ``misma_bounds`` values (see :class:`CalibrationConfig`).
MISMA_BOUNDS = ("around_lsq", "paper")


@dataclasses.dataclass(frozen=True)
class CalibrationConfig:
    """Settings of the calibration of grouped shots.

    Attributes:
        peer: run circuitpython-mag-cal side by side (skipped with a notice when not installed).
        misma_iter: MISMA iterations. misma_repeats: independent MISMA runs (the lowest fitness is kept).
        misma_pop: MISMA population.
        misma_bounds: ``around_lsq`` (:func:`misma_box`: around the ellipsoid fit, in the data's units,
            grown to contain the least-squares solution) or ``paper`` (the paper's 128 / -68 uT,
            :func:`icgo.optim.misma.paper_bounds`).
    """

    peer: bool = True
    misma_iter: int = 300
    misma_repeats: int = 4
    misma_pop: int = 30
    misma_bounds: str = "around_lsq"

    def __post_init__(self):
        need(isinstance(self.peer, bool), "peer", f"must be true or false, got {self.peer!r}")
        need(self.misma_bounds in MISMA_BOUNDS, "misma_bounds",
             f"must be one of {', '.join(MISMA_BOUNDS)}, got {self.misma_bounds!r}")
        for name, lo in (("misma_iter", 1), ("misma_repeats", 1), ("misma_pop", 4)):
            v = getattr(self, name)
            need(is_int(v) and v >= lo, name, f"must be an integer >= {lo}, got {v!r}")


def model_label(recording: str, method: str) -> str:
    """File-name label of a saved calibration: ``<recording>_<method>`` with ``+`` -> ``_``."""
    return f"{recording}_{method.replace('+', '_')}"


def held_out_splits(groups, within=None, prefix: str = "") -> list[tuple]:
    """(label, train mask, score mask) of the held-out splits of the shots ``within`` (default: all).

    With two or more rolls among them, one split per roll held out (fit without it, score on it). With one
    roll of at least 2 x MIN_ROLLED_SHOTS of them, its two interleaved halves are held out in turn (odd shots,
    then even shots, in shot order: each half still spans the roll): a weaker test, since the fit sees the
    other half of the same direction. With one shorter roll (or none), no split. ``prefix`` starts the labels
    (an inner split's names its outer split).
    """
    groups = np.asarray(groups)
    within = np.ones(len(groups), bool) if within is None else np.asarray(within, bool)
    ids = [g for g in rolled_ids(groups) if (within & (groups == g)).sum() >= MIN_ROLLED_SHOTS]
    if len(ids) > 1:
        return [(f"{prefix}held-out group {g}", within & (groups != g), within & (groups == g)) for g in ids]
    out = []
    if ids and (within & (groups == ids[0])).sum() >= 2 * MIN_ROLLED_SHOTS:
        rows = np.flatnonzero(within & (groups == ids[0]))
        for half, name in ((rows[1::2], "odd"), (rows[0::2], "even")):
            score = np.zeros(len(groups), bool)
            score[half] = True
            out.append((f"{prefix}held-out half of group {ids[0]} ({name} shots)", within & ~score, score))
    return out


def splits(groups) -> list[tuple]:
    """(label, train mask, score mask): in-sample, then the held-out splits (:func:`held_out_splits`).

    Raises ValueError (one line) when the recording has no rolled group.
    """
    groups = np.asarray(groups)
    if not rolled_ids(groups):
        raise ValueError(f"calibration: no rolled group (a group of {MIN_ROLLED_SHOTS} or more shots about one "
                         "pointing direction); the group column has none")
    allrows = np.ones(len(groups), bool)
    return [("in-sample", allrows, allrows)] + held_out_splits(groups)


def misma_box(x_centre, x_lsq, field_scale_nT: float, matrix_halfwidth: float = 0.05,
              bias_halfwidth: float = 0.02, margin: float = 1.5):
    """MISMA's box in the data's units, grown until it contains the least-squares solution.

    The box of eqs. 9-11 around the ellipsoid fit ``x_centre``
    (:func:`icgo.optim.misma.misma_bounds`): matrix entries +/- ``matrix_halfwidth``
    x their largest magnitude, biases +/- ``bias_halfwidth`` x the median |B| of
    the data (``field_scale_nT``, nT; 1.0 here would pin the biases to
    +/- 0.02 nT). Each half-width is then at least ``margin`` x the
    distance from the centre to the 12-parameter least-squares solution
    ``x_lsq``, so the box contains it with room on both sides.

    Returns:
        (lb, ub), two (12,) arrays (matrix: per unit-sphere fit unit, biases: nT).
    """
    x_centre = np.asarray(x_centre, np.float64)
    lb, ub = misma_opt.misma_bounds(x_centre, float(field_scale_nT), matrix_halfwidth, bias_halfwidth)
    h = np.maximum(ub - x_centre, margin * np.abs(np.asarray(x_lsq, np.float64) - x_centre))
    return x_centre - h, x_centre + h


#: MISMA's fitness on static shots (default weights, one segment). The shots travel as ``aux`` and replace
#: its own two placeholder rows (numpy, so importing this module starts no JAX backend), so this one
#: instance, the runner's static fitness, serves every recording; JAX compiles once per recording size.
_SHOTS_OBJECTIVE = MismaObjective(cal.CalData(np.ones((2, 3)), np.ones((2, 3)), np.zeros(2, np.int32), np.zeros(2),
                                              np.float64(1.0), np.ones(2), np.ones(2)))


def misma_on_shots(G_cal, B, config: CalibrationConfig, box, key, weights=None) -> np.ndarray:
    """MISMA on static shots (unit-sphere field) in ``box``, ``misma_repeats`` repeats; the lowest-fitness (12,).

    ``weights``: (N,) 0/1, the shots it fits (default all): the others enter with zero weight, so every split
    of a recording has one shape."""
    R = int(config.misma_repeats)
    data = cal.make_caldata(G_cal, B, 1.0, weights=weights)
    aux = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (R,) + jnp.shape(a)), data)
    r = base.run_batch(get("misma"), _SHOTS_OBJECTIVE, box, jax.random.split(key, R), int(config.misma_pop),
                       int(config.misma_iter), aux=aux)
    return np.asarray(r.best_x[int(np.argmin(np.asarray(r.best_f)))])


class GeometryError(DataError):
    """The shots do not span the orientations the linear fits need (one line)."""


def fit_recording(G, B, groups, config: CalibrationConfig, key, header: dict, train=None) -> dict:
    """Our methods fitted on the ``train`` shots, as :class:`MagCalibration` s (see the module doc).

    Every jitted fit sees all N shots of the recording, the held-out ones with zero weight, so one
    recording compiles each fit once whatever the split (the closed forms run on the training rows).

    Args:
        G, B: (N, 3) raw shots, g and nT. groups: (N,) group ids. train: (N,) bool (default all).
    Raises:
        GeometryError: the ellipsoid or 12-parameter fit refuses the shots' geometry.
    """
    groups = np.asarray(groups)
    train = np.ones(len(groups), bool) if train is None else np.asarray(train, bool)
    Gt, Bt, gt = G[train], B[train], groups[train]
    try:
        xg = cal.ellipsoid_fit_accel(Gt)
        xm = cal.ellipsoid_fit(Bt, 1.0, Gt)
        cal.check_orientations(Gt, Bt)
    except ValueError as e:
        raise GeometryError(str(e).splitlines()[0]) from None
    G_c = np.asarray(cal.correct(jnp.asarray(xg), G))
    scale = float(np.median(np.linalg.norm(Bt, axis=1)))

    def model(method, x, alignment=None, x_accel=xg, extra=None):
        return mag_calibration(method, x, Gt, Bt, {**header, **(extra or {})}, x_accel=x_accel, alignment=alignment,
                               field_scale_nT=scale)

    def aligned(method, x, extra=None):
        return model(method, x, align_to_axis(G_c[train], np.asarray(cal.correct(jnp.asarray(x), Bt)), gt),
                     extra=extra)

    try:
        x12 = cal.fit_twelve(G_c, B, 1.0, x0=xm, weights=train.astype(float), check=False)
    except ValueError as e:
        raise GeometryError(str(e).splitlines()[0]) from None
    if config.misma_bounds == "paper":
        (lb, ub), box = misma_opt.paper_bounds(), "icgo.optim.misma.paper_bounds (128 / -68 uT)"
    else:
        (lb, ub), box = misma_box(xm, x12, scale), "icgo.studies.calibration.study.misma_box (defaults)"
    out = {"ellipsoid": model("ellipsoid", xm), "twelve+axis": aligned("twelve", x12)}
    out["misma+axis"] = aligned("misma", misma_on_shots(G_c, B, config, (lb, ub), key, train.astype(float)),
                                {"misma_box_lb": lb.tolist(), "misma_box_ub": ub.tolist(), "misma_box": box})
    lin = out["twelve+axis"]
    Q = lin.params.alignment
    rot = lambda x: np.concatenate([(Q @ np.asarray(x[:9]).reshape(3, 3)).ravel(), np.asarray(x[9:])])
    j = joint.fit(G, B, groups, train, rot(xg), rot(x12))
    out["joint"] = model("joint", j.xm, x_accel=j.xg, extra={"joint_lambda": j.lam, "joint_cv": j.cv.tolist(),
                                                             "joint_gauss_newton_gap": j.gap})
    Gc_lin, Bc_lin = lin.corrected(G, B)
    nl = mag_relm.fit(Gc_lin, Bc_lin, groups, train=train)
    out["twelve+axis+relm"] = with_residual(lin, nl, {**lin.config, "relm_lambda_deg2": nl.lam,
                                                      "relm_hidden": int(nl.hidden.shape[1]),
                                                      "relm_cv_deg2": nl.cv.tolist()})
    return out


def group_score(model: MagCalibration, G, B, groups, score_mask) -> float:
    """The peer metric (deg) of a calibration on the rows of ``score_mask``."""
    Gc, Bc = model.corrected(G, B)
    return group_spread_deg(Gc[score_mask], Bc[score_mask], groups[score_mask])[0]


def model_sanity(model: MagCalibration, G, B):
    """:func:`icgo.models.cal_sanity.sanity` of a calibration on all the shots."""
    Gc, Bc = model.corrected(G, B)
    return sanity(Gc, Bc, np.asarray(model.params.x_mag[:9]).reshape(3, 3))


def site_row(model: MagCalibration, G, B, site=None) -> dict:
    """The site columns of a calibration on shots (G, B): mean dip and |B| with their spreads
    (:func:`icgo.models.cal_site.site_values`) and, with ``site`` (dip deg, |B| nT), the check against it."""
    Gc, Bc = model.corrected(G, B)
    v = site_values(Gc, Bc, np.asarray(model.params.x_mag[:9]).reshape(3, 3))
    row = {"dip_deg": v.dip_deg, "dip_std_deg": v.dip_std_deg, "field_nT": v.field_nT, "field_std_nT": v.field_std_nT,
           "site_dip_off_deg": np.nan, "site_field_off_pct": np.nan, "site_flag": False, "site_reason": ""}
    if site is not None:
        c = site_check(v, *site)
        row.update({"site_dip_off_deg": c.dip_off_deg, "site_field_off_pct": c.field_off_pct, "site_flag": c.flagged,
                    "site_reason": c.reason})
    return row


def evaluate(recordings: dict, config: CalibrationConfig, key, *, check: bool = True,
             sites: dict | None = None) -> tuple[pd.DataFrame, dict]:
    """Every recording x split x method: score (NaN when degenerate), sanity and site values, long format.

    Besides the in-sample and held-out splits (:func:`splits`, column ``outer`` empty), every held-out split's
    training shots are split again (:func:`held_out_splits`, column ``outer`` naming the split they are inside):
    our methods are fitted and scored there too, with sanity and site values judged on that outer split's
    training shots only, so that :func:`recommend` can make its choice inside each outer split (nested).

    Args:
        recordings: name -> :class:`icgo.io.recording.Recording` with a ``group`` column.
        config: :class:`CalibrationConfig`. key: PRNG key (split once per fit).
        check: refuse a group that is not a plausible roll (the front door checks and names them when it
            reads the shots; a layout's groups are then kept even where the data disagree).
        sites: name -> (dip deg, |B| nT) of the site a recording was taken at, or None (no site check).
    Returns:
        (table with columns recording, split, outer, method, score_deg, dip_spread_deg, b_spread_pct, cond,
        degenerate, reasons, dip_deg, dip_std_deg, field_nT, field_std_nT, site_dip_off_deg, site_field_off_pct,
        site_flag, site_reason; {"<recording>_<method>": in-sample calibration}).
    """
    peer = config.peer and peer_available()
    if config.peer and not peer:
        log.warning("circuitpython-mag-cal is not installed: the peer's columns are left out")
    rows, models = [], {}
    for name, rec in recordings.items():
        G, B, groups = rec.G, rec.B, rec.frame["group"].to_numpy()
        site = (sites or {}).get(name)
        if check:
            bad = {g: c for g, c in check_groups(G, B, groups).items() if not c.ok}
            if bad:  # a group that is not a roll would be scored as one: never silently
                g, c = next(iter(bad.items()))
                raise DataError(f"{name}: group {g} is not a plausible roll: {'; '.join(c.reasons)} "
                                "(icgo.physics.rolls; docs/calibrate.md)")
        outer = splits(groups)
        todo = [(split, train, score, "", np.ones(len(groups), bool)) for split, train, score in outer]
        for split, train, _ in outer[1:]:
            todo += [(s2, t2, sc2, split, train) for s2, t2, sc2 in held_out_splits(groups, train, f"{split} / ")]
        for split, train, score, within, scope in todo:
            key, sub = jax.random.split(key)
            header = {"study": "calibration", "recording": name, "split": split, **dataclasses.asdict(config)}
            try:
                fitted = fit_recording(G, B, groups, config, sub, header, train)
            except GeometryError as e:  # the fits refuse a geometry they cannot solve: say where, and what helps
                raise GeometryError(f"{split}: {e} (the fits need shots in many "
                                    "orientations besides the rolls, e.g. the 8 single shots of the mag_cal "
                                    "procedure)") from None
            for m, c in fitted.items():
                s = model_sanity(c, G[scope], B[scope])
                rows.append({"recording": name, "split": split, "outer": within, "method": m,
                             "score_deg": group_score(c, G, B, groups, score), **s.row(),
                             **site_row(c, G[scope], B[scope], site)})
            if peer and not within:
                rows += [{"recording": name, "split": split, "outer": "", **r}
                         for r in peer_rows(G, B, groups, train, score)]
            if split == "in-sample":
                models.update({model_label(name, m): c for m, c in fitted.items()})
            log.info("  %-6s %-18s %s", name, split, " ".join(
                f"{r['method']}={r['score_deg']:.3f}{'(DEGENERATE)' if r['degenerate'] else ''}"
                for r in rows if r["recording"] == name and r["split"] == split))
    df = pd.DataFrame(rows)
    df.loc[df["degenerate"], "score_deg"] = np.nan  # a degenerate fit has no score (module doc)
    return df, models


def outer_rows(df: pd.DataFrame) -> pd.DataFrame:
    """The in-sample and held-out rows of :func:`evaluate`'s table (the inner splits left out)."""
    return df[df["outer"].fillna("") == ""] if "outer" in df.columns else df


def summary(df: pd.DataFrame) -> pd.DataFrame:
    """Per method: mean score in-sample and held out over the sound fits, how many fits were degenerate, and the
    largest dip spread and condition number over all its fits (degenerate ones included); inner splits left out."""
    df = outer_rows(df)
    order = [m for m in METHODS + PEER_METHODS if m in set(df["method"])]
    out = []
    for m in order:
        g = df[df["method"] == m]
        ins, held = g[g["split"] == "in-sample"], g[g["split"] != "in-sample"]
        out.append({"method": m, "in-sample mean (deg)": ins["score_deg"].mean(),
                    "held-out mean (deg)": held["score_deg"].mean(),
                    "degenerate fits": f"{int(g['degenerate'].sum())} of {len(g)}",
                    "max dip spread (deg)": g["dip_spread_deg"].max(), "max cond": g["cond"].max()})
    return pd.DataFrame(out).set_index("method")


def wide(df: pd.DataFrame) -> pd.DataFrame:
    """One row per recording and split (inner splits left out), one column per method: the score (deg), or
    ``degenerate`` for a fit the sanity check rejects (its reasons in the long table)."""
    df = outer_rows(df)
    order = [m for m in METHODS + PEER_METHODS if m in set(df["method"])]
    cell = df.assign(cell=[("degenerate" if d else f"{s:.3f}") for s, d in zip(df["score_deg"], df["degenerate"])])
    out = cell.pivot(index=["recording", "split"], columns="method", values="cell")[order]
    return out.reindex(pd.unique(pd.MultiIndex.from_frame(df[["recording", "split"]]))).reset_index()


def roll_directions(model: MagCalibration, G, B, groups) -> pd.DataFrame:
    """Per roll: its mean pointing direction after a calibration (azimuth magnetic and inclination, deg) and
    the spread of the shots about it (the peer's metric, deg)."""
    Gc, Bc = model.corrected(G, B)
    d = pointing_directions(Gc, Bc)
    _, spread = group_spread_deg(Gc, Bc, groups, min_size=MIN_ROLLED_SHOTS)
    rows = []
    for g in rolled_ids(groups):
        m = np.mean(d[np.asarray(groups) == g], axis=0)
        m /= np.linalg.norm(m)
        rows.append({"group": int(g), "azimuth_deg": float(np.mod(np.degrees(np.arctan2(m[1], m[0])), 360.0)),
                     "inclination_deg": float(np.degrees(np.arccos(np.clip(m[2], -1.0, 1.0)))),
                     "spread_deg": spread[int(g)]})
    return pd.DataFrame(rows)


class CalibrationResult(NamedTuple):
    """Attributes: records (``fits``: the long table of :func:`evaluate`; ``summary``: :func:`summary`),
    models (``<recording>_<method>`` in-sample calibrations)."""

    records: dict
    models: dict


def run(data: dict, config: CalibrationConfig, key) -> CalibrationResult:
    """Every recording of ``data`` (name -> Recording with a ``group`` column) through :func:`evaluate`."""
    df, models = evaluate(data, config, key)
    return CalibrationResult({"fits": df, "summary": summary(df).reset_index()}, models)


def example() -> tuple[dict, CalibrationConfig]:
    """A tiny real instance: one bundled device, MISMA 3 iterations x 2 repeats, no peer."""
    from icgo.io.mag_cal_bundled import load_mag_cal_device

    return {"ab": load_mag_cal_device("ab")}, CalibrationConfig(peer=False, misma_iter=3, misma_repeats=2, misma_pop=6)


STUDY = Study("calibration", CalibrationConfig, run, "magnetometer calibration of grouped static shots: "
              "ellipsoid, 12-parameter LSQ + axis, MISMA + axis, joint, LSQ + axis + RELM, the peer; "
              "in-sample and held out, with physical sanity", example)
