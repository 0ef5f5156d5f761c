"""compare: where simulation and measurement disagree, as data.

Sign convention: every residual here is **measured - predicted** (tool-frame
G in g and B in nT, total field in nT, dip and azimuth in deg), the same as
:func:`icgo.discrepancy.model.residuals`. :func:`compare` gives the residuals
and where they concentrate; :func:`find_pattern` the findings a reader needs
(which :mod:`icgo.discrepancy.report` turns into sentences); :func:`gap` the
held-out gap of a fitted model.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from icgo.discrepancy.model import Prediction
from icgo.discrepancy.noise import NOISE, Noise
from icgo.discrepancy.stations import Stations
from icgo.physics.frames import angle_diff, azimuth_from_gv, inclination_from_g

#: Residual component names, in the order of the (n, 6) residual arrays.
COMPONENTS = ("gx", "gy", "gz", "bx", "by", "bz")


class Bin(NamedTuple):
    """One bin of a binned residual: [lo, hi) deg, n stations, RMS |dB| (nT), RMS azimuth error (deg)."""

    lo: float
    hi: float
    n: int
    rms_b_nT: float
    rms_azimuth_deg: float


class Comparison(NamedTuple):
    """Residuals measured - predicted at each station and where they concentrate.

    Attributes:
        resid: (n, 6) tool-frame residuals, g and nT (:data:`COMPONENTS`).
        total_field_nT, dip_deg, azimuth_deg: (n,) residuals of derived quantities.
        valid: (n,) stations used. az_ok: (n,) stations whose azimuth is scored
            (valid and inclination in (3, 177) deg).
        rms: component name -> RMS residual over valid stations (g or nT).
        rms_total_field_nT, mean_total_field_nT, rms_dip_deg, rms_azimuth_deg: summaries.
        toolface: (n,) the toolface the model assumed, deg.
        bins: ``toolface`` / ``inclination`` / ``azimuth`` -> tuple of :class:`Bin`.
        harmonics: ``x`` / ``y`` / ``z`` -> fractions of the B residual's mean square
            explained by the ``constant``, ``1st`` and ``2nd`` toolface harmonics.
        correlations: extra column (and ``station_order``) -> (6,) |correlation|
            with each residual component.
        r2_axial: R^2 of the azimuth residual against sin I sin A (axial interference).
    """

    resid: np.ndarray
    total_field_nT: np.ndarray
    dip_deg: np.ndarray
    azimuth_deg: np.ndarray
    valid: np.ndarray
    az_ok: np.ndarray
    rms: dict
    rms_total_field_nT: float
    mean_total_field_nT: float
    rms_dip_deg: float
    rms_azimuth_deg: float
    toolface: np.ndarray
    bins: dict
    harmonics: dict
    correlations: dict
    r2_axial: float


def azimuth_scored(G, valid) -> np.ndarray:
    """(n,) bool: valid stations whose azimuth is scored (inclination from G in (3, 177) deg)."""
    inc = np.asarray(inclination_from_g(np.asarray(G)))
    return np.asarray(valid, bool) & (inc > 3.0) & (inc < 177.0)


def _harmonic_fractions(y, t_deg) -> dict:
    """Fractions of var(y) (about 0) explained by the constant, 1st and 2nd toolface harmonics."""
    t = np.deg2rad(t_deg)
    X = np.stack([np.ones_like(t), np.cos(t), np.sin(t), np.cos(2 * t), np.sin(2 * t)], 1)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    tot = max(float(np.sum(y**2)), 1e-300)
    parts = {"constant": X[:, :1] @ coef[:1], "1st": X[:, 1:3] @ coef[1:3], "2nd": X[:, 3:] @ coef[3:]}
    return {k: float(np.sum(v**2)) / tot for k, v in parts.items()}


def _dip(g, b):
    c = np.sum(g * b, 1) / (np.linalg.norm(g, axis=1) * np.linalg.norm(b, axis=1))
    return np.rad2deg(np.arcsin(np.clip(c, -1, 1)))


def compare(st: Stations, pred: Prediction, valid=None, n_bins=8) -> Comparison:
    """compare: residuals in the tool frame and derived quantities, and where they concentrate.

    Args:
        st: the measured stations (n). pred: the model's :class:`Prediction` at them.
        valid: (n,) stations to use (default all). n_bins: bins over each angle.
    Returns:
        :class:`Comparison` (residuals measured - predicted).
    """
    G, B = np.asarray(st.G), np.asarray(st.B)
    Gp, Bp = np.asarray(pred.G), np.asarray(pred.B)
    valid = np.ones(len(G), bool) if valid is None else np.asarray(valid, bool)
    r = np.concatenate([G - Gp, B - Bp], 1)
    d_total = np.linalg.norm(B, axis=1) - np.linalg.norm(Bp, axis=1)
    d_dip = _dip(G, B) - _dip(Gp, Bp)
    d_az = np.asarray(angle_diff(azimuth_from_gv(G, B), azimuth_from_gv(Gp, Bp)))
    az_ok = azimuth_scored(G, valid)
    T, A, I = (np.asarray(x) for x in (pred.toolface, pred.azimuth, pred.inclination))
    bmag = np.linalg.norm(r[:, 3:], axis=1)
    bins = {}
    for name, x, lo, hi in (("toolface", np.mod(T, 360), 0, 360), ("inclination", I, 0, 180),
                            ("azimuth", np.mod(A, 360), 0, 360)):
        edges = np.linspace(lo, hi, n_bins + 1)
        k = np.clip(np.digitize(x, edges) - 1, 0, n_bins - 1)
        rows = []
        for b in range(n_bins):
            m = valid & (k == b)
            ma = az_ok & (k == b)
            rows.append(Bin(float(edges[b]), float(edges[b + 1]), int(m.sum()),
                            float(np.sqrt(np.mean(bmag[m] ** 2))) if m.any() else float("nan"),
                            float(np.sqrt(np.mean(d_az[ma] ** 2))) if ma.any() else float("nan")))
        bins[name] = tuple(rows)
    harm = {c: _harmonic_fractions(r[valid, 3 + j], T[valid]) for j, c in enumerate("xyz")}
    corr = {}
    for name, x in dict(st.extras or {}, station_order=np.arange(len(G), dtype=float)).items():
        x = np.asarray(x, float)
        if np.std(x[valid]) > 0:
            corr[name] = [abs(float(np.corrcoef(x[valid], r[valid, j])[0, 1])) if np.std(r[valid, j]) > 0 else 0.0
                          for j in range(6)]
    # azimuth error vs the axial-interference signature sin I sin A (ENGINEERING-NOTES, ISCWSA)
    sig = np.sin(np.deg2rad(I)) * np.sin(np.deg2rad(A))
    r2_axial = 0.0
    if az_ok.sum() > 3 and np.std(sig[az_ok]) > 0 and np.std(d_az[az_ok]) > 0:
        r2_axial = float(np.corrcoef(sig[az_ok], d_az[az_ok])[0, 1] ** 2)
    return Comparison(
        resid=r, total_field_nT=d_total, dip_deg=d_dip, azimuth_deg=d_az, valid=valid, az_ok=az_ok,
        rms={c: float(np.sqrt(np.mean(r[valid, j] ** 2))) for j, c in enumerate(COMPONENTS)},
        rms_total_field_nT=float(np.sqrt(np.mean(d_total[valid] ** 2))),
        mean_total_field_nT=float(np.mean(d_total[valid])),
        rms_dip_deg=float(np.sqrt(np.mean(d_dip[valid] ** 2))),
        rms_azimuth_deg=float(np.sqrt(np.mean(d_az[az_ok] ** 2))) if az_ok.any() else float("nan"),
        toolface=T, bins=bins, harmonics=harm, correlations=corr, r2_axial=r2_axial)


class Correlated(NamedTuple):
    """An extra column that a residual component follows: |r| > 0.5."""

    column: str
    component: str
    abs_r: float


class Pattern(NamedTuple):
    """The findings about a residual (from a :class:`Comparison`), as data.

    Attributes:
        b_rms_nT: per-axis RMS of the B residual, nT. g_rms_g: of the G residual, g.
        noise: the sensor noise the findings are measured against.
        concentrated_on: the component holding > 60 % of the mean square of the
            sensor further above its noise, or None.
        cross_axial_harmonic: when the B residual exceeds 2 sigma: ``constant``
            (> 50 % of the cross-axial residual; the source turns with the tool),
            ``1st`` (> 50 %; earth-fixed source or tilted reference) or ``2nd``
            (> 30 %; scale-factor or cross-coupling-like); else None.
        cross_axial_fraction: that harmonic's share (nan when None).
        total_field_offset_nT: mean total-field residual when beyond 3 sigma_b, else None.
        axial_r2: R^2 against sin I sin A when > 0.5 (axial interference), else None.
        azimuth_hotspot: the inclination bin whose RMS azimuth error exceeds 1.5x
            the overall RMS (``rms_azimuth_deg``), else None.
        rms_azimuth_deg: overall RMS azimuth residual, deg.
        correlated: extra columns a residual component follows.
    """

    b_rms_nT: float
    g_rms_g: float
    noise: Noise
    concentrated_on: str | None
    cross_axial_harmonic: str | None
    cross_axial_fraction: float
    total_field_offset_nT: float | None
    axial_r2: float | None
    azimuth_hotspot: Bin | None
    rms_azimuth_deg: float
    correlated: tuple


def find_pattern(cmp: Comparison, noise: Noise = NOISE) -> Pattern:
    """Where the residual of a :class:`Comparison` concentrates (thresholds in :class:`Pattern`)."""
    rms = cmp.rms
    b_rms = math.sqrt(sum(rms[c] ** 2 for c in ("bx", "by", "bz")) / 3)
    g_rms = math.sqrt(sum(rms[c] ** 2 for c in ("gx", "gy", "gz")) / 3)
    axes = ("bx", "by", "bz") if b_rms / noise.sigma_b_nT >= g_rms / noise.sigma_g else ("gx", "gy", "gz")
    top = max(axes, key=lambda c: rms[c])
    concentrated = top if rms[top] ** 2 > 0.6 * sum(rms[c] ** 2 for c in axes) else None
    h = cmp.harmonics
    hx = {k: (h["x"][k] + h["y"][k]) / 2 for k in h["x"]}
    harmonic = None
    if b_rms > 2 * noise.sigma_b_nT:
        if hx["constant"] > 0.5:
            harmonic = "constant"
        elif hx["1st"] > 0.5:
            harmonic = "1st"
        elif hx["2nd"] > 0.3:
            harmonic = "2nd"
    offset = cmp.mean_total_field_nT if abs(cmp.mean_total_field_nT) > 3 * noise.sigma_b_nT else None
    hotspot = None
    rows = [r for r in cmp.bins["inclination"] if r.n > 0 and np.isfinite(r.rms_azimuth_deg)]
    if rows and cmp.rms_azimuth_deg > 0:
        worst = max(rows, key=lambda r: r.rms_azimuth_deg)
        if worst.rms_azimuth_deg > 1.5 * cmp.rms_azimuth_deg:
            hotspot = worst
    correlated = []
    for name, cs in cmp.correlations.items():
        j = int(np.argmax(cs))
        if cs[j] > 0.5:
            correlated.append(Correlated(name, COMPONENTS[j], cs[j]))
    return Pattern(b_rms, g_rms, noise, concentrated, harmonic,
                   hx[harmonic] if harmonic else float("nan"), offset,
                   cmp.r2_axial if cmp.r2_axial > 0.5 else None, hotspot, cmp.rms_azimuth_deg, tuple(correlated))


class Gap(NamedTuple):
    """The held-out gap between a fitted model and the measurements.

    Attributes:
        mag_rms_nT: RMS magnetometer residual per axis, nT.
        azimuth_rms_deg: RMS azimuth residual, deg (nan if no station is scored).
        accel_rms_g: RMS accelerometer residual per axis, g.
        chi2_per_residual: mean squared noise-normalized residual.
        excess_over_noise: ``sqrt(max(chi2 / floor - 1, 0))``: 0 for a model that
            leaves only noise (``floor`` from :func:`~icgo.discrepancy.noise.noise_floor`).
    """

    mag_rms_nT: float
    azimuth_rms_deg: float
    accel_rms_g: float
    chi2_per_residual: float
    excess_over_noise: float


def gap(r_held, az_err, valid, az_ok, sig, floor: float) -> Gap:
    """Held-out gap of one model.

    Args:
        r_held: (n, 6) held-out residuals measured - predicted (g, nT).
        az_err: (n,) held-out azimuth residual (deg). valid, az_ok: (n,) bool.
        sig: (n, 6) noise sigmas. floor: noise-only chi2 per residual.
    """
    chi2 = np.mean((r_held[valid] / sig[valid]) ** 2)
    return Gap(mag_rms_nT=float(np.sqrt(np.mean(r_held[valid, 3:] ** 2))),
               azimuth_rms_deg=float(np.sqrt(np.mean(az_err[az_ok] ** 2))) if az_ok.any() else float("nan"),
               accel_rms_g=float(np.sqrt(np.mean(r_held[valid, :3] ** 2))),
               chi2_per_residual=float(chi2),
               excess_over_noise=float(np.sqrt(max(chi2 / floor - 1.0, 0.0))))
