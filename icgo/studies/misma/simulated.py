"""The MISMA study's simulated part (MISMA paper, Yang & Cai): MISMA vs SMA on one ``rotating_drill`` variant.

MISMA and the standard SMA minimise the penalised MISMA fitness
(:class:`icgo.models.misma_objective.MismaObjective`: dot invariance eq. 5, Pearson
constraint eqs. 6-7, field modulus eq. 8 and, in the paper's magneto-inertial
reading, the gyro term J_gyro on the reference field M_omega of
:mod:`icgo.models.gyro_reference`) over the 12 parameters ``[R^-1, b]`` (eqs. 2-4),
``repeats`` vmapped repeats each, population ``pop_size``, one comparison row at a time
(:mod:`icgo.studies.misma.compare`); :func:`gyro_sweep` repeats MISMA over gyro grades.
Scored by :func:`simulated_variant` (see :mod:`icgo.studies.misma`).
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.datasets import drill_string as datasets
from icgo.datasets import instruments as ins
from icgo.datasets.dataset import Dataset
from icgo.maths import stats
from icgo.models import calibration as cal
from icgo.models import calibration_params as cal_params
from icgo.models.cal_sanity import sanity
from icgo.models.gyro_reference import fit_to_reference, gyro_reference, reference_at
from icgo.models.misma_objective import MismaObjective
from icgo.artifacts.calibration import mag_calibration
from icgo.optim import misma as misma_opt
from icgo.physics.qc import survey_qc
from icgo.studies.misma import compare
from icgo.studies.misma.config import SimulatedConfig

log = logging.getLogger(__name__)

#: Names of the 12 parameters ``[R^-1 row-major, b]`` in the tables.
PARAM_NAMES = tuple(f"Rinv_{i}{j}" for i in range(1, 4) for j in range(1, 4)) + ("b_x_nT", "b_y_nT", "b_z_nT")


class Problem(NamedTuple):
    """One rotating_drill variant prepared for the search.

    Attributes:
        G, B: (N, 3) all samples, g and nT. static: (N,) bool zero-velocity samples.
        t: (N,) time, s. sel: (N,) bool samples the fitness uses.
        ref_nT: |M_omega|, the modulus of the gyro-rotated reference field (nT).
        objective: the study's penalised fitness (:class:`icgo.models.misma_objective.MismaObjective`; with
            J_gyro when the gyro term is on). objective_mag: the same without J_gyro.
        x_true: (12,) true parameters. f_true, f_true_mag: their fitness under the two objectives.
        az_ref: (n_static,) true magnetic azimuth at the static samples, deg.
        gyro: the :class:`icgo.models.gyro_reference.GyroReference` (None with the term off).
    """

    G: np.ndarray
    B: np.ndarray
    static: np.ndarray
    t: np.ndarray
    sel: np.ndarray
    ref_nT: float
    objective: Any
    objective_mag: Any
    x_true: np.ndarray
    f_true: float
    f_true_mag: float
    az_ref: np.ndarray
    gyro: Any


def prepare_problem(ds: Dataset, scfg: SimulatedConfig) -> Problem:
    """Fitness data of one variant: every ``subsample``-th rotating sample plus all static ones.

    Segments (for the Pearson constraint, eqs. 6-7) are the intervals between
    stops; the dot-invariance term (eq. 5) sees the static samples (or all);
    the gyro term (:mod:`icgo.models.gyro_reference`) every sample of its windows.
    """
    fr, meta, truth = ds.frame, ds.meta, ds.truth
    G, B = fr[["gx", "gy", "gz"]].to_numpy(float), fr[["bx", "by", "bz"]].to_numpy(float)
    static = fr["static"].to_numpy().astype(bool)
    t = fr["time_s"].to_numpy(float)
    seg = (t // float(truth["stop_every_s"])).astype(np.int32)
    ref = float(meta["total_field_nT"])  # |M_omega| (docs/misma.md)
    sel = static | (np.arange(len(t)) % int(scfg.subsample) == 0)
    dotw = static[sel].astype(float) if scfg.dot_samples == "static" else None
    data = cal.make_caldata(G[sel], B[sel], ref, seg[sel], ~static[sel], dot_weights=dotw)
    ob = scfg.objective
    args = (data, ob.pearson_threshold, ob.pearson_mode, ob.mu_magnitude, ob.mu_pearson)
    obj_mag = MismaObjective(*args)
    gref, obj = None, obj_mag
    if scfg.gyro.on:
        gref = gyro_reference(G, fr[["wx", "wy", "wz"]].to_numpy(float), t, static, float(meta["latitude"]), ref,
                              float(meta["dip_deg"]), scfg.gyro.window_s, scfg.gyro.bias)
        obj = MismaObjective(*args, gyro=(gref, B[gref.index]), mu_gyro=scfg.gyro.mu)
    x_true = np.asarray(cal.params_from_error_model(np.asarray(truth["R"]), np.asarray(truth["b_nT"])))
    f_true, f_true_mag = (float(o(x_true[None])[0]) for o in (obj, obj_mag))
    return Problem(G, B, static, t, sel, ref, obj, obj_mag, x_true, f_true, f_true_mag,
                   fr["azimuth_deg"].to_numpy(float)[static], gref)


def misma_centre(p: Problem):
    """U (eqs. 9-10): the gyro-reference fit with the gyro term, else the modulus fit; and the modulus fit."""
    u_mod = cal.modulus_fit(p.B[p.sel], p.ref_nT)
    if p.gyro is None:
        return u_mod, u_mod
    return fit_to_reference(p.B[p.gyro.index], p.gyro, u_mod), u_mod


def prior_box(ref_nT, matrix_halfwidth, bias_halfwidth):
    """SMA's prior-knowledge bounds: ``R^-1 = I +/- m``, ``b = 0 +/- h |M_omega|``; two (12,) arrays."""
    c = np.concatenate([np.eye(3).ravel(), np.zeros(3)])
    h = np.concatenate([np.full(9, matrix_halfwidth), np.full(3, bias_halfwidth * ref_nT)])
    return c - h, c + h


def boxes(p: Problem, U, U_mod, scfg: SimulatedConfig) -> tuple[dict, dict]:
    """The search boxes of the comparison ({name: (lb, ub)}) and a one-line description of each (units)."""
    mc, sc = scfg.misma, scfg.sma
    out = {"prior": prior_box(p.ref_nT, sc.matrix_halfwidth, sc.bias_halfwidth),
           "U": misma_opt.misma_bounds(U_mod, p.ref_nT, mc.matrix_halfwidth, mc.bias_halfwidth),
           "paper": misma_opt.paper_bounds()}
    text = {"prior": f"prior: R^-1 = I +/- {sc.matrix_halfwidth:g}, b = 0 +/- {sc.bias_halfwidth * p.ref_nT:.0f} nT",
            "U": f"U (modulus fit) +/- {mc.matrix_halfwidth:g} max(abs(U_R)) and {mc.bias_halfwidth * p.ref_nT:.0f} nT",
            "paper": "paper: 128 / -68 uT (R^-1 entries -68 .. 128, b -68 000 .. 128 000 nT)"}
    if p.gyro is not None:
        out["U_omega"] = misma_opt.misma_bounds(U, p.ref_nT, mc.matrix_halfwidth, mc.bias_halfwidth)
        text["U_omega"] = (f"U_omega (gyro-reference fit) +/- {mc.matrix_halfwidth:g} max(abs(U_R)) and "
                           f"{mc.bias_halfwidth * p.ref_nT:.0f} nT")
    return out, text


def search(p: Problem, U, U_mod, scfg: SimulatedConfig, key) -> tuple[dict, dict]:
    """Every row of :func:`icgo.studies.misma.compare.rows`, ``repeats`` repeats each, on the same keys.

    Returns:
        ({Row: RowRun}, {box name: description}).
    """
    box, text = boxes(p, U, U_mod, scfg)
    keys = jax.random.split(key, int(scfg.repeats))
    objectives = {"mag": p.objective_mag, "mag+gyro": p.objective}
    runs = {}
    for row in compare.rows(scfg.gyro.on):
        log.info("  %s ...", row.label)
        runs[row] = compare.run_row(row, objectives[row.objective], box[row.box], keys, int(scfg.pop_size),
                                    int(scfg.n_iter), scfg.misma.optimizer_config(), scfg.sma.z)
    return runs, text


def corrected_field(x, G, B) -> np.ndarray:
    """The field (N, 3) after the 12 parameters ``x`` (eq. 4), by the calibration's own
    :func:`icgo.models.calibration_params.predict` (what a saved model of ``x`` applies). G, B: (N, 3)."""
    out = cal_params.predict(cal_params.CalibrationParams(x), np.hstack([G, B]))
    return np.ascontiguousarray(np.asarray(out)[:, 3:])


def static_azimuth_error(p: Problem, x) -> np.ndarray:
    """|azimuth error| (deg) at the static samples after correcting with ``x`` (None: raw), (n_static,)."""
    Gs, Bs = p.G[p.static], p.B[p.static]
    if x is not None:
        Bs = corrected_field(x, Gs, Bs)
    return np.abs(cal.azimuth_error_deg(Gs, Bs, p.az_ref))


def baselines(p: Problem, U, name: str) -> tuple[dict, Any]:
    """Mean static |azimuth error| (deg) of the true parameters, U and the 12-parameter least squares.

    Returns:
        ({label: deg}, x_twelve or None when the least squares refuses the geometry).
    """
    out = {"true parameters": float(np.mean(static_azimuth_error(p, p.x_true))),
           "U (modulus fit, MISMA's centre)": float(np.mean(static_azimuth_error(p, U)))}
    try:
        x12 = cal.fit_twelve(p.G[p.sel], p.B[p.sel], p.ref_nT, x0=U)
        out["12-parameter least squares"] = float(np.mean(static_azimuth_error(p, x12)))
    except ValueError as e:
        x12 = None
        out["12-parameter least squares"] = float("nan")
        log.warning("[%s] 12-parameter least squares: %s", name, e)
    return out, x12


def static_qc(p: Problem, meta: dict, fits: dict) -> dict:
    """Survey-QC counts (:func:`icgo.physics.qc.survey_qc`) at the static samples, raw and after each fit.

    Args:
        meta: the run's metadata (reference ``total_field_nT``, ``dip_deg``, ``gravity_g``).
        fits: label -> (12,) calibration parameters (None entries are skipped).
    Returns:
        ``{"raw": counts, label: counts, ...}``.
    """
    Gs, Bs = p.G[p.static], p.B[p.static]
    ref = (float(meta["total_field_nT"]), float(meta["dip_deg"]), float(meta.get("gravity_g", 1.0)))
    out = {"raw": survey_qc(Gs, Bs, *ref).counts}
    for lab, x in fits.items():
        if x is not None:
            out[lab] = survey_qc(Gs, corrected_field(x, Gs, Bs), *ref).counts
    return out


def identifiability(G, B, ref, x, gyro=None):
    """Singular values (descending, relative to the largest) of d(residuals)/d(scaled params) at x.

    Residuals: the dot-invariance deviations (eq. 5), the relative modulus
    deviations (eq. 8) and, with ``gyro = (GyroReference, B_window)``, the
    relative deviations from M_omega at the best headings (J_gyro's residuals);
    parameters scaled so R^-1 (1) and b (units of ``ref``) compare.

    Returns:
        (singular values (12,), the right singular vector of the smallest (12,), in scaled parameters).
    """
    scale = np.r_[np.full(9, 1.0), np.full(3, ref)]
    Gj, Bj = jnp.asarray(G), jnp.asarray(B)

    def res(u):
        Bc = cal.correct(u * scale, Bj)
        d = cal.normalized_dot(Gj, Bc)
        out = [d - jnp.mean(d), jnp.linalg.norm(Bc, axis=1) / ref - 1.0]
        if gyro is not None:
            Bw = cal.correct(u * scale, jnp.asarray(gyro[1]))
            out.append(((Bw - reference_at(Bw, gyro[0])[1]) / ref).ravel())
        return jnp.concatenate(out)

    _, s, vt = np.linalg.svd(np.asarray(jax.jacfwd(res)(jnp.asarray(x / scale))))
    return s / s[0], vt[-1]


def params_table(x_true, x_misma, x_sma, tol) -> pd.DataFrame:
    """Recovered vs true parameters (one row per parameter) with |error| and the tolerance."""
    return pd.DataFrame({"parameter": list(PARAM_NAMES), "true": x_true, "MISMA": x_misma, "SMA": x_sma,
                         "MISMA_abs_err": np.abs(x_misma - x_true), "SMA_abs_err": np.abs(x_sma - x_true),
                         "tolerance": tol, "MISMA_within": np.abs(x_misma - x_true) <= tol})


def modulus_table(moduli: dict, ref) -> pd.DataFrame:
    """|B| statistics (nT) per method: mean, std, mean |deviation| from |M_omega|; index = method."""
    return pd.DataFrame({k: {"mean_nT": v.mean(), "std_nT": v.std(), "mean_abs_dev_from_ref_nT": np.abs(v - ref).mean()}
                         for k, v in moduli.items()}).T


class VariantPlot(NamedTuple):
    """What the variant's figure shows.

    Attributes:
        curves: row label -> (R, T) best-so-far fitness (each on its own objective).
        threshold: threshold_factor x F(true) on the magnetometer objective.
        moduli: {"raw", "SMA", "MISMA"} -> (N,) |B| per sample, nT. ref_nT: |M_omega|. t: (N,) s.
        az_errors: {"before", "SMA", "MISMA"} -> (n_static,) |azimuth error|, deg.
    """

    curves: dict
    threshold: float
    moduli: dict
    ref_nT: float
    t: np.ndarray
    az_errors: dict


class VariantResult(NamedTuple):
    """One variant: its summary (JSON-able), tables, figure data and fitted calibrations."""

    summary: dict
    params: pd.DataFrame
    modulus: pd.DataFrame
    plot: VariantPlot
    models: dict
    fair: pd.DataFrame
    tests: pd.DataFrame
    sweep: pd.DataFrame
    headline_errors: dict  # {"MISMA": (R,), "SMA": (R,)} per-repeat errors of the headline rows (deg)


def _variant_models(name, p: Problem, res, U, x12, scfg) -> dict:
    """The calibrations the variant fitted: MISMA and SMA (lowest-fitness repeat each), U and least squares."""
    G, B = p.G[p.sel], p.B[p.sel]
    base_cfg = {"study": "misma", "variant": name, "ref_nT": p.ref_nT, "subsample": int(scfg.subsample)}
    out = {}
    for lab, r in res.items():
        i = int(np.argmin(np.asarray(r.best_f)))
        cfg = {**base_cfg, "selected_repeat": i, "selection": "lowest fitness over repeats",
               "fitness": float(np.asarray(r.best_f)[i]), "pop_size": int(scfg.pop_size), "n_iter": int(scfg.n_iter)}
        out[f"{name}_{lab.lower()}"] = mag_calibration(lab.lower(), np.asarray(r.best_x[i]), G, B, cfg)
    out[f"{name}_modulus"] = mag_calibration("modulus", U, G, B, base_cfg)
    if x12 is not None:
        out[f"{name}_twelve"] = mag_calibration("twelve", x12, G, B, base_cfg)
    return out


def median_repeat(run) -> np.ndarray:
    """The (12,) parameters of the median-fitness repeat of a row's runs."""
    return np.asarray(run.best_x[int(np.argsort(np.asarray(run.best_f))[len(run.best_f) // 2])])


class Scores(NamedTuple):
    """A row's scores: per repeat ``err`` (mean static |azimuth error|, deg) and ``within`` (parameters in
    tolerance, of 12); ``physics``: the median repeat's invariants at the stops (:func:`icgo.models.cal_sanity.sanity`:
    dip spread, |B| spread, cond(R^-1), degenerate)."""

    err: np.ndarray
    within: np.ndarray
    physics: dict


def _repeat_scores(p: Problem, run, tol) -> Scores:
    """:class:`Scores` of one row's repeats."""
    err = np.array([np.mean(static_azimuth_error(p, x)) for x in run.best_x])
    within = np.sum(np.abs(run.best_x - p.x_true) <= tol, axis=1)
    x = median_repeat(run)
    Bc = corrected_field(x, p.G[p.static], p.B[p.static])
    physics = sanity(p.G[p.static], Bc, x[:9].reshape(3, 3)).row()
    return Scores(err, within, physics)


def grade_dataset(ds: Dataset, overrides: dict, factor: float) -> Dataset:
    """The run ``ds`` (made with ``overrides``) again, its gyro errors and gyro noise times ``factor``.

    The magnetometer and accelerometer data are unchanged (their noise streams do not depend on the gyro).
    """
    gyro = ins.GyroErrors(**ds.truth["gyro"]).scaled(factor)
    noise = float(ds.truth["gyro_noise_deg_h"]) * factor
    return datasets.rotating_drill(int(ds.meta["seed"]), **{**overrides, "gyro": gyro, "gyro_noise_deg_h": noise})


def gyro_sweep(name: str, ds: Dataset, scfg: SimulatedConfig, key, no_gyro_errors) -> pd.DataFrame:
    """MISMA with the gyro term at each gyro grade of ``scfg.gyro.sweep`` against MISMA without it (item 4).

    Same repeat keys as :func:`search`, so each grade is paired with the
    no-gyro row repeat by repeat (Wilcoxon; Holm over every variant's grades together:
    :func:`icgo.studies.misma.compare.sweep_family`).

    Args:
        no_gyro_errors: (R,) per-repeat static |azimuth error| of MISMA without the gyro term (deg).
    Returns:
        One row per grade (factor, the gyro's errors, the reference's error at the true parameters, scores, test).
    """
    gcfg = dataclasses.replace(scfg, gyro=dataclasses.replace(scfg.gyro, term="vector"))
    row = compare.headline_misma(True, scfg.misma.bounds)
    keys = jax.random.split(key, int(scfg.repeats))
    tol = scfg.tolerance.vector()
    recs = []
    for f in scfg.gyro.sweep:
        gds = grade_dataset(ds, scfg.variants[name], f)
        p = prepare_problem(gds, gcfg)
        U, U_mod = misma_centre(p)
        rr = compare.run_row(row, p.objective, boxes(p, U, U_mod, gcfg)[0][row.box], keys, int(scfg.pop_size),
                             int(scfg.n_iter), scfg.misma.optimizer_config(), scfg.sma.z)
        err, within, physics = _repeat_scores(p, rr, tol)
        Bc = cal.correct(jnp.asarray(p.x_true), p.B[p.gyro.index])
        m = np.asarray(reference_at(Bc, p.gyro)[1])
        cosang = np.sum(np.asarray(Bc) * m, 1) / np.linalg.norm(Bc, axis=1) / np.linalg.norm(m, axis=1)
        g = gds.truth["gyro"]
        recs.append({"variant": name, "grade_factor": f, "bias_deg_h_max": float(np.max(np.abs(g["bias_deg_h"]))),
                     "scale_ppm_max": float(np.max(np.abs(g["scale"]))) * 1e6,
                     "noise_deg_h": float(gds.truth["gyro_noise_deg_h"]),
                     "reference_error_deg_rms": float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(cosang, -1, 1)) ** 2)))),
                     "U_omega_az_err_deg": float(np.mean(static_azimuth_error(p, U))),
                     "MISMA_gyro_az_err_mean_deg": float(err.mean()), "MISMA_gyro_az_err_max_deg": float(err.max()),
                     "MISMA_no_gyro_az_err_mean_deg": float(np.mean(no_gyro_errors)),
                     "params_within_median": float(np.median(within)), "repeats_all_12_within": int((within == 12).sum()),
                     **{f"median_repeat_{k}": v for k, v in physics.items()},
                     "MISMA_gyro_az_err_median_diff_deg": float(np.median(err - no_gyro_errors)),
                     "p": stats.wilcoxon_paired(err, no_gyro_errors).p_value})
    return pd.DataFrame(recs)


def simulated_variant(name: str, ds: Dataset, scfg: SimulatedConfig, key) -> VariantResult:
    """Run every comparison row on one rotating_drill variant and score it (see the module doc)."""
    p = prepare_problem(ds, scfg)
    U, U_mod = misma_centre(p)
    runs, box_text = search(p, U, U_mod, scfg, key)
    tol = scfg.tolerance.vector()
    scores = {row: _repeat_scores(p, rr, tol) for row, rr in runs.items()}
    errors = {row: sc.err for row, sc in scores.items()}
    fair = compare.fair_table(runs, scores, box_text)
    tests = compare.paired_tests(compare.contrasts(scfg.gyro.on), errors)
    head = {"MISMA": compare.headline_misma(scfg.gyro.on, scfg.misma.bounds), "SMA": compare.STANDARD_SMA}
    res = {lab: runs[row] for lab, row in head.items()}
    az = {lab: errors[row] for lab, row in head.items()}
    raw = float(np.mean(static_azimuth_error(p, None)))
    base_err, x12 = baselines(p, U_mod, name)
    if p.gyro is not None:
        base_err["U_omega (gyro-reference fit, MISMA's centre)"] = float(np.mean(static_azimuth_error(p, U)))

    # the paper's "converges X % faster": MISMA vs SMA on one objective (compare.convergence)
    mag_misma, mag_sma = compare.MISMA_U, compare.STANDARD_SMA
    conv = {"MISMA vs standard SMA, magnetometer objective": compare.convergence(runs[mag_misma], runs[mag_sma]),
            "MISMA vs SMA, same U box and coordinates, magnetometer objective (operators only)":
                compare.convergence(runs[mag_misma], runs[compare.SMA_U])}
    if scfg.gyro.on:
        conv["MISMA vs SMA, same U_omega box, objective with J_gyro"] = compare.convergence(
            runs[compare.MISMA_U_OMEGA], runs[compare.SMA_U_OMEGA])
    f_true = {"MISMA": p.f_true if head["MISMA"].objective == "mag+gyro" else p.f_true_mag, "SMA": p.f_true_mag}
    it = {lab: compare.iters_to(r.curve, scfg.threshold_factor * f_true[lab]) for lab, r in res.items()}
    med = {lab: float(np.nanmedian(v)) if np.isfinite(v).any() else float("nan") for lab, v in it.items()}

    # recovered parameters: the median-fitness repeat of each algorithm
    x_med = {lab: median_repeat(r) for lab, r in res.items()}
    params = params_table(p.x_true, x_med["MISMA"], x_med["SMA"], tol)
    sv, _ = identifiability(p.G[p.sel], p.B[p.sel], p.ref_nT, p.x_true)
    ident = {"magnetometer objective": sv.tolist()}
    if p.gyro is not None:
        sv_g, v_g = identifiability(p.G[p.sel], p.B[p.sel], p.ref_nT, p.x_true, (p.gyro, p.B[p.gyro.index]))
        ident["with J_gyro"] = sv_g.tolist()
        ident["with J_gyro: weakest direction (scaled parameters)"] = dict(zip(PARAM_NAMES, np.round(v_g, 3).tolist()))

    def modulus(x):
        return np.linalg.norm(corrected_field(x, p.G, p.B), axis=1)

    moduli = {"raw": np.linalg.norm(p.B, axis=1), "SMA": modulus(x_med["SMA"]), "MISMA": modulus(x_med["MISMA"])}
    summary = {
        "variant": name, "overrides": dict(scfg.variants[name]), "n_samples_fitness": int(p.sel.sum()),
        "n_samples_gyro": int(len(p.gyro.index)) if p.gyro is not None else 0,
        "MISMA_row": head["MISMA"].label, "MISMA_box": box_text[head["MISMA"].box],
        "SMA_box": box_text[head["SMA"].box],
        "F_true": f_true["MISMA"], "F_true_magnetometer_objective": p.f_true_mag,
        "MISMA_best_f_median": float(np.median(res["MISMA"].best_f)),
        "SMA_best_f_median": float(np.median(res["SMA"].best_f)),
        "MISMA_iters_to_threshold_median": med["MISMA"], "SMA_iters_to_threshold_median": med["SMA"],
        "MISMA_reached": int(np.isfinite(it["MISMA"]).sum()), "SMA_reached": int(np.isfinite(it["SMA"]).sum()),
        "az_err_raw_deg": raw, "az_err_SMA_deg_mean": float(az["SMA"].mean()),
        "az_err_MISMA_deg_mean": float(az["MISMA"].mean()), "az_err_MISMA_deg_max": float(az["MISMA"].max()),
        "az_reduction_MISMA_pct": 100 * (1 - az["MISMA"].mean() / raw),
        "az_reduction_SMA_pct": 100 * (1 - az["SMA"].mean() / raw), "baselines_az_err_deg": base_err,
        "params_within_tolerance_MISMA": int(params["MISMA_within"].sum()),
        "repeats_all_params_within_tolerance_MISMA": int((scores[head["MISMA"]].within == 12).sum()),
        "repeats_all_params_within_tolerance_SMA": int((scores[head["SMA"]].within == 12).sum()),
        "jacobian_singular_values": ident, "convergence": conv,
        "runtime_s": {row.label: rr.seconds for row, rr in runs.items()},
        "qc_static": static_qc(p, ds.meta, {"U": U, "twelve": x12, "SMA": x_med["SMA"], "MISMA": x_med["MISMA"]}),
    }
    thr = scfg.threshold_factor * p.f_true_mag
    plot = VariantPlot({f"{row.algorithm} ({row.box}; {row.objective})": rr.curve for row, rr in runs.items()}, thr,
                       moduli, p.ref_nT, p.t,
                       {"before": static_azimuth_error(p, None), "SMA": static_azimuth_error(p, x_med["SMA"]),
                        "MISMA": static_azimuth_error(p, x_med["MISMA"])})
    sweep = gyro_sweep(name, ds, scfg, key, errors[mag_misma]) if scfg.gyro.sweep else pd.DataFrame()
    return VariantResult(summary, params, modulus_table(moduli, p.ref_nT), plot,
                         _variant_models(name, p, res, U_mod, x12, scfg), fair, tests, sweep, az)


def simulated_table(summaries: list) -> pd.DataFrame:
    """The scalar entries of the variants' summaries, one column per variant."""
    rows = [{k: v for k, v in s.items() if not isinstance(v, (dict, list))} for s in summaries]
    return pd.DataFrame(rows).set_index("variant").T
