"""Discrepancy workflow: find where simulation and measurement disagree, name the
missing physical effect, add it to the model and show the gap shrink.

Five verbs (issue #7), all usable from a notebook with plain arguments:

* **simulate** — :func:`predict`: each station's G (g) and B (nT) from its
  reference attitude (or, without one, its group's fitted direction), the
  reference field (or field nuisances) and the effects in the model. Toolface
  comes from the *measured* G with the model's accelerometer effects removed
  (ENGINEERING-NOTES "Discrepancy fitting": refit as the parameters move, so an
  accelerometer bias cannot leak into the magnetometer residual).
* **compare** — :func:`compare`: residuals in the tool frame and in derived
  quantities (total field, dip, azimuth), binned over toolface / inclination /
  azimuth, toolface harmonics, correlation with extra columns; :func:`describe`
  turns them into sentences.
* **name** — :func:`evaluate_candidates`: for every vocabulary effect not yet in
  the model, the model + effect is fitted by Levenberg-Marquardt with exact
  (forward-mode) Jacobians, on k training folds and on all stations, in ONE
  jitted call vmapped over (candidate x fold). Scored by the k-fold held-out
  residual (in noise units) and by BIC; standard errors from the Gauss-Newton
  covariance; evidence margin over the runner-up as a paired z over held-out
  stations and a BIC difference.
* **add** — :func:`run_workflow`: greedy forward selection until no candidate
  improves the held-out residual beyond noise; verdicts ``no missing effect``,
  ``explained``, ``unexplained structure remains`` (+ pattern) and
  ``not separable`` (two candidates explain the same thing with these attitudes).
* **show** — :func:`gap_table`, :func:`result_to_json`, and the figure
  functions in the ``plots`` section at the bottom.

Non-separability (:func:`separability`, :func:`identifiability`): from the
noise-weighted Jacobian, the canonical correlations between an effect's
columns and those of the rest of the model (after the nuisances are projected
out). A canonical correlation of ~1 means a parameter direction that the
attitudes cannot tell apart from another effect; the workflow says so.

Units: G in g, B in nT, angles in degrees at every public boundary.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo import effects as _fx
from icgo.frames import (
    angle_diff,
    azimuth_from_gv,
    field_vector_ned,
    inclination_from_g,
    sensors_from_attitude,
    tool_to_earth,
    toolface_from_g,
)

#: Default sensor noise (1 sigma per axis): magnetometer nT, accelerometer g.
SIGMA_B_NT = 15.0
SIGMA_G = 3e-4
#: Scales of the reference-field nuisance parameters (total nT, dip deg, declination deg).
FIELD_SCALES = (300.0, 0.5, 0.5)
#: Scale of the per-group direction nuisances (deg).
GROUP_SCALE_DEG = 1.0
#: Stations whose inclination (from G) is within this of vertical are left out:
#: toolface, hence the predicted cross-axial field, is undefined there.
VERTICAL_EXCLUDE_DEG = 1.0


# =============================================================== data
class Stations(NamedTuple):
    """Measured stations, host-side numpy (the workflow's input).

    Attributes:
        G: (n, 3) measured gravity, g. B: (n, 3) measured field, nT.
        azimuth: (n,) reference azimuth (deg, true north), or None.
        inclination: (n,) reference inclination (deg), or None.
        group: (n,) int group id (same true direction), or None.
        field: (total_field_nT, dip_deg, declination_deg) or None (unknown: nuisances).
        gravity_g: magnitude of gravity, g.
        extras: name -> (n,) float extra columns (temperature_c, time_s, ...), used
            only to describe unexplained structure.
    """

    G: np.ndarray
    B: np.ndarray
    azimuth: np.ndarray | None = None
    inclination: np.ndarray | None = None
    group: np.ndarray | None = None
    field: tuple | None = None
    gravity_g: float = 1.0
    extras: dict | None = None

    @property
    def n(self) -> int:
        return int(self.G.shape[0])

    @property
    def has_reference(self) -> bool:
        return self.azimuth is not None and self.inclination is not None


def check_stations(st: Stations) -> None:
    """Raise ValueError (one line) for inputs the workflow cannot use."""
    G, B = np.asarray(st.G), np.asarray(st.B)
    if G.ndim != 2 or G.shape[1] != 3 or B.shape != G.shape:
        raise ValueError(f"stations: G and B must both be (n, 3), got {G.shape} and {B.shape}")
    if G.shape[0] < 6:
        raise ValueError(f"stations: need at least 6 stations, got {G.shape[0]}")
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(B))):
        raise ValueError("stations: G or B contains NaN/inf")
    if not st.has_reference:
        if st.group is None:
            raise ValueError("stations: need a reference attitude (azimuth, inclination) or a group column")
        if st.azimuth is not None or st.inclination is not None:
            raise ValueError("stations: give both azimuth and inclination, or neither")
    else:
        for name, v in (("azimuth", st.azimuth), ("inclination", st.inclination)):
            v = np.asarray(v)
            if v.shape != (G.shape[0],) or not np.all(np.isfinite(v)):
                raise ValueError(f"stations: {name} must be (n,) finite, got shape {v.shape}")
    if st.group is not None and np.asarray(st.group).shape != (G.shape[0],):
        raise ValueError(f"stations: group must be (n,), got {np.asarray(st.group).shape}")


def stations_from_recording(rec) -> Stations:
    """Convert an ``icgo.io.Recording`` (data contract) into :class:`Stations`.

    Uses the reference attitude when present, else the ``group`` column; the
    field from the metadata (or the field model) when present, else None.
    """
    fr = rec.frame
    has_ref = all(c in fr.columns for c in ("azimuth_deg", "inclination_deg"))
    field = None
    if rec.field is not None:
        field = (float(rec.field.total_field_nT), float(rec.field.dip_deg), float(rec.field.declination_deg))
    extras = {}
    for c in ("temperature_c", "time_s"):
        if c in fr.columns:
            extras[c] = fr[c].to_numpy(np.float64)
    grav = float(rec.field.gravity_g) if rec.field is not None else float(rec.meta.get("gravity_g", 1.0))
    return Stations(
        G=rec.G,
        B=rec.B,
        azimuth=fr["azimuth_deg"].to_numpy(np.float64) if has_ref else None,
        inclination=fr["inclination_deg"].to_numpy(np.float64) if has_ref else None,
        group=fr["group"].to_numpy(np.int64) if ("group" in fr.columns and not has_ref) else None,
        field=field,
        gravity_g=grav,
        extras=extras or None,
    )


# ============================================================ simulation
DESIGNS = ("random", "single_inclination", "rotation", "turntable", "turntable_fixed_toolface")


def design_attitudes(key, n, design="random", inclination_deg=45.0, azimuth_deg=30.0):
    """Station attitudes (A, I, T) in deg, each (n,), for a physical test design.

    Designs:
        ``random``: A, T uniform in [0, 360), I uniform in [5, 175].
        ``single_inclination``: I fixed at ``inclination_deg``, A, T random.
        ``rotation``: A and I fixed, only T varies (a tool rolled in place).
        ``turntable``: the patent's 3-axis plan (CN1888384 step 2): I in
            {3,5,10,15,25,35,45,55,65,75}, A and T every 30 deg (1440 points);
            ``n`` of them drawn without replacement (all when n >= 1440).
        ``turntable_fixed_toolface``: the lookup-table plan the patent replaced:
            toolface fixed at 0, I on the same grid, A every 30 deg (120 points).
    """
    ka, ki, kt = jax.random.split(key, 3)
    u = lambda k, lo, hi: np.asarray(jax.random.uniform(k, (n,), minval=lo, maxval=hi))
    if design == "random":
        return u(ka, 0.0, 360.0), u(ki, 5.0, 175.0), u(kt, 0.0, 360.0)
    if design == "single_inclination":
        return u(ka, 0.0, 360.0), np.full(n, float(inclination_deg)), u(kt, 0.0, 360.0)
    if design == "rotation":
        return np.full(n, float(azimuth_deg)), np.full(n, float(inclination_deg)), u(kt, 0.0, 360.0)
    incs = np.array([3, 5, 10, 15, 25, 35, 45, 55, 65, 75], float)
    grid30 = np.arange(0.0, 360.0, 30.0)
    if design == "turntable":
        I, A, T = (g.ravel() for g in np.meshgrid(incs, grid30, grid30, indexing="ij"))
    elif design == "turntable_fixed_toolface":
        I, A = (g.ravel() for g in np.meshgrid(incs, grid30, indexing="ij"))
        T = np.zeros_like(I)
    else:
        raise ValueError(f"design {design!r}: choose one of {DESIGNS}")
    if n < I.size:
        idx = np.sort(np.asarray(jax.random.choice(ka, I.size, (n,), replace=False)))
        A, I, T = A[idx], I[idx], T[idx]
    return A, I, T


def random_effect_params(key, name, lo=0.5, hi=1.5):
    """Random realistic parameters of one effect: each component ``typical * U(lo, hi) * (+-1)``."""
    e = _fx.EFFECTS[name]
    k1, k2 = jax.random.split(key)
    mag = jax.random.uniform(k1, (e.n_params,), minval=lo, maxval=hi)
    sign = jnp.where(jax.random.bernoulli(k2, 0.5, (e.n_params,)), 1.0, -1.0)
    return np.asarray(e.typical * mag * sign)


def simulate(key, n=240, effect_params=None, design="random", field=(50_000.0, 60.0, 0.0),
             sigma_b_nT=SIGMA_B_NT, sigma_g=SIGMA_G, gravity_g=1.0, **design_kw):
    """Simulate measured stations with hidden effects and white noise.

    Args:
        key: PRNG key. n: number of stations.
        effect_params: name -> (n_params,) physical parameters of the injected effects.
        design: see :func:`design_attitudes`.
        field: (total nT, dip deg, declination deg) of the site.
        sigma_b_nT, sigma_g: noise (1 sigma per axis).
    Returns:
        Stations with the reference attitude (the truth) and the field.
    """
    kd, kg, kb = jax.random.split(key, 3)
    A, I, T = design_attitudes(kd, n, design, **design_kw)
    n = A.shape[0]
    s = sensors_from_attitude(A, I, T, field[0], field[1], field[2], gravity_g=gravity_g)
    C = tool_to_earth(A, I, T)
    G, B = _fx.apply_effects(dict(effect_params or {}), s.G, s.B, C)
    G = np.asarray(G) + sigma_g * np.asarray(jax.random.normal(kg, (n, 3)))
    B = np.asarray(B) + sigma_b_nT * np.asarray(jax.random.normal(kb, (n, 3)))
    return Stations(G=G, B=B, azimuth=np.asarray(A), inclination=np.asarray(I),
                    field=tuple(float(f) for f in field), gravity_g=float(gravity_g))


# ============================================================ parameter layout
class Layout(NamedTuple):
    """Where each parameter lives in the flat vector theta (static, hashable).

    theta = [effects in ORDER | field nuisances (3) | group directions (2 per group)];
    physical value = scale * theta.
    """

    names: tuple
    starts: tuple
    sizes: tuple
    n_effect: int
    n_groups: int

    @property
    def n_params(self) -> int:
        return self.n_effect + 3 + 2 * self.n_groups

    def slice(self, name) -> slice:
        i = self.names.index(name)
        return slice(self.starts[i], self.starts[i] + self.sizes[i])

    def scales(self) -> np.ndarray:
        s = [np.full(_fx.EFFECTS[nm].n_params, _fx.EFFECTS[nm].typical, float) for nm in self.names]
        s.append(np.asarray(FIELD_SCALES, float))
        s.append(np.full(2 * self.n_groups, GROUP_SCALE_DEG))
        return np.concatenate(s)

    def labels(self) -> list[str]:
        out = []
        for nm, k in zip(self.names, self.sizes):
            comp = {"mag_cross_coupling": ("xy", "xz", "yz"), "external_field": ("N", "E", "D")}.get(nm, ("x", "y", "z"))
            out += [f"{nm}[{comp[j] if k == 3 else j}]" for j in range(k)]
        out += ["field[total]", "field[dip]", "field[declination]"]
        for g in range(self.n_groups):
            out += [f"group{g}[azimuth]", f"group{g}[inclination]"]
        return out


def make_layout(n_groups=0) -> Layout:
    names = tuple(_fx.ORDER)
    sizes = tuple(_fx.EFFECTS[n].n_params for n in names)
    starts = tuple(int(x) for x in np.cumsum((0,) + sizes)[:-1])
    return Layout(names, starts, sizes, int(sum(sizes)), int(n_groups))


class Data(NamedTuple):
    """Device-side arrays for the fits (a pytree)."""

    G: jnp.ndarray        # (n, 3) g
    B: jnp.ndarray        # (n, 3) nT
    A0: jnp.ndarray       # (n,) reference azimuth, or (n_groups,) initial group azimuth, deg
    I0: jnp.ndarray       # (n,) or (n_groups,) deg
    group: jnp.ndarray    # (n,) int index into A0/I0 (identity in reference mode)
    field0: jnp.ndarray   # (3,) total nT, dip deg, declination deg
    gravity: jnp.ndarray  # () g
    sig: jnp.ndarray      # (n, 6) effective 1-sigma of the residual components
    scales: jnp.ndarray   # (P,)


def _effective_sigma(G, B, sigma_b, sigma_g):
    """Per-station 1-sigma of (G, B) residual components, (n, 6).

    The model takes toolface from the measured G, so accelerometer noise turns
    the predicted cross-axial field: sigma_T = sigma_g / |G_xy| (rad), which adds
    (B_y sigma_T)^2 to bx's variance and (B_x sigma_T)^2 to by's.
    """
    gxy2 = np.maximum(G[:, 0] ** 2 + G[:, 1] ** 2, 1e-12)
    st2 = sigma_g**2 / gxy2
    sb = np.stack([np.sqrt(sigma_b**2 + B[:, 1] ** 2 * st2), np.sqrt(sigma_b**2 + B[:, 0] ** 2 * st2),
                   np.full(G.shape[0], sigma_b)], 1)
    return np.concatenate([np.full((G.shape[0], 3), sigma_g), sb], 1)


def _circmean_deg(a):
    r = np.deg2rad(a)
    return float(np.rad2deg(np.arctan2(np.mean(np.sin(r)), np.mean(np.cos(r)))))


def pad_stations(st: Stations, bucket: int):
    """Pad to a multiple of ``bucket`` stations by repeating the last one.

    Returns (padded Stations, real mask (n_pad,)). The padded stations are marked
    invalid (weight 0) so they change nothing, but every data set of up to
    ``bucket`` stations reuses one compiled fit (no recompilation per size).
    """
    n = st.n
    n_pad = max(bucket, int(math.ceil(n / bucket)) * bucket) if bucket else n
    real = np.arange(n_pad) < n
    if n_pad == n:
        return st, real
    rep = lambda a: None if a is None else np.concatenate([np.asarray(a), np.repeat(np.asarray(a)[-1:], n_pad - n, 0)])
    extras = None if st.extras is None else {k: rep(v) for k, v in st.extras.items()}
    return st._replace(G=rep(st.G), B=rep(st.B), azimuth=rep(st.azimuth), inclination=rep(st.inclination),
                       group=rep(st.group), extras=extras), real


def prepare(st: Stations, sigma_b_nT=SIGMA_B_NT, sigma_g=SIGMA_G):
    """Build (Layout, Data, valid mask, free-nuisance mask) from Stations.

    Without a field in ``st`` the field nuisances start from the data (median |B|
    and median G-B angle) and are free; without a reference attitude each group's
    direction starts from the circular mean of the raw attitudes and is free.
    """
    check_stations(st)
    G = np.asarray(st.G, np.float64)
    B = np.asarray(st.B, np.float64)
    n = G.shape[0]
    inc_g = np.asarray(inclination_from_g(G))
    valid = (inc_g > VERTICAL_EXCLUDE_DEG) & (inc_g < 180.0 - VERTICAL_EXCLUDE_DEG)
    if st.field is not None:
        field0 = np.asarray(st.field, np.float64)
    else:
        cosang = np.sum(G * B, 1) / (np.linalg.norm(G, axis=1) * np.linalg.norm(B, axis=1))
        field0 = np.array([np.median(np.linalg.norm(B, axis=1)),
                           np.median(np.rad2deg(np.arcsin(np.clip(cosang, -1, 1)))), 0.0])
    if st.has_reference:
        layout = make_layout(0)
        A0 = np.asarray(st.azimuth, np.float64)
        I0 = np.asarray(st.inclination, np.float64)
        gidx = np.arange(n)
    else:
        ug, gidx = np.unique(np.asarray(st.group), return_inverse=True)
        layout = make_layout(len(ug))
        # raw magnetic azimuth (declination 0 in group mode: directions are relative)
        a_raw = np.asarray(azimuth_from_gv(G, B))
        A0 = np.array([_circmean_deg(a_raw[gidx == g]) for g in range(len(ug))])
        I0 = np.array([float(np.mean(inc_g[gidx == g])) for g in range(len(ug))])
        field0[2] = 0.0
    free_nuis = np.zeros(layout.n_params, bool)
    ne = layout.n_effect
    if st.field is None:
        free_nuis[ne:ne + 2] = True  # total, dip
        if st.has_reference:
            free_nuis[ne + 2] = True  # declination (true azimuth reference)
    free_nuis[ne + 3:] = True  # group directions
    data = Data(jnp.asarray(G), jnp.asarray(B), jnp.asarray(A0), jnp.asarray(I0), jnp.asarray(gidx),
                jnp.asarray(field0), jnp.asarray(float(st.gravity_g)),
                jnp.asarray(_effective_sigma(G, B, sigma_b_nT, sigma_g)), jnp.asarray(layout.scales()))
    return layout, data, valid, free_nuis


# ============================================================ the forward model
def effect_params(theta, layout: Layout, scales):
    """name -> physical parameters from the flat scaled vector."""
    phys = theta * scales
    return {nm: phys[layout.slice(nm)] for nm in layout.names}


def _g_effects() -> tuple:
    """Names of the registered effects that change G (probed with their typical magnitude)."""
    G = np.array([[0.3, -0.4, 0.8]])
    out = []
    for nm, e in _fx.EFFECTS.items():
        with jax.ensure_compile_time_eval():
            g, _ = e.apply(jnp.full(e.n_params, e.typical), jnp.asarray(G), jnp.zeros((1, 3)), jnp.eye(3)[None])
        if not np.allclose(np.asarray(g), G, rtol=0, atol=0):
            out.append(nm)
    return tuple(out)


def _remove_accel_effects(params, G_meas, n_fixed=3):
    """Invert the G part of the effects by fixed-point iteration: G_true with apply(G_true) = G_meas.

    Works for any registered effect that acts on G (contraction by |effect| ~ 1e-3 per pass).
    """
    params = {k: v for k, v in params.items() if k in _g_effects()}
    if not params:
        return G_meas
    eye = jnp.broadcast_to(jnp.eye(3, dtype=G_meas.dtype), G_meas.shape[:-1] + (3, 3))
    zeroB = jnp.zeros_like(G_meas)
    g = G_meas
    for _ in range(n_fixed):
        gm, _ = _fx.apply_effects(params, g, zeroB, eye)
        g = g - (gm - G_meas)
    return g


def predict(theta, data: Data, layout: Layout):
    """simulate: predicted (G, B) at each station for parameters ``theta``.

    Returns:
        (G_pred (n, 3) g, B_pred (n, 3) nT, toolface (n,) deg, azimuth (n,) deg,
        inclination (n,) deg) — the attitude the model assumes.
    """
    params = effect_params(theta, layout, data.scales)
    ne = layout.n_effect
    fs = data.scales[ne:ne + 3]
    F = data.field0[0] + theta[ne] * fs[0]
    dip = data.field0[1] + theta[ne + 1] * fs[1]
    dec = data.field0[2] + theta[ne + 2] * fs[2]
    gdir = theta[ne + 3:].reshape(-1, 2) * GROUP_SCALE_DEG
    if layout.n_groups:
        A = (data.A0 + gdir[:, 0])[data.group]
        I = (data.I0 + gdir[:, 1])[data.group]
    else:
        A, I = data.A0, data.I0
    T = toolface_from_g(_remove_accel_effects(params, data.G))
    C = tool_to_earth(A, I, T)
    g_ned = jnp.stack([0.0 * F, 0.0 * F, data.gravity + 0.0 * F])
    G0 = jnp.einsum("nji,j->ni", C, g_ned)
    B0 = jnp.einsum("nji,j->ni", C, field_vector_ned(F, dip, dec))
    Gp, Bp = _fx.apply_effects(params, G0, B0, C)
    return Gp, Bp, T, A, I


def residuals(theta, data: Data, layout: Layout):
    """Noise-normalized residuals (prediction - measurement), (n, 6): G then B components."""
    Gp, Bp, *_ = predict(theta, data, layout)
    return jnp.concatenate([Gp - data.G, Bp - data.B], 1) / data.sig


# ============================================================ Levenberg-Marquardt
def _lm_fit(theta0, free, w, data, layout, n_iter):
    """Weighted LM with exact forward-mode Jacobians; only ``free`` parameters move.

    Args:
        theta0: (P,) start. free: (P,) float 0/1. w: (n,) station weights (0 = not used).
    Returns:
        (theta (P,), cost = sum of weighted squared residuals).
    """
    sw = jnp.sqrt(w)[:, None]

    def res(th):
        r = residuals(th, data, layout) * sw
        return jnp.where(jnp.isfinite(r), r, 1e6).ravel()

    def cost(th):
        return jnp.sum(res(th) ** 2)

    eye = jnp.eye(theta0.shape[0], dtype=theta0.dtype)

    def step(carry, _):
        th, lam, c = carry
        r = res(th)
        J = jax.jacfwd(res)(th) * free
        H = J.T @ J
        g = J.T @ r
        Hd = H + lam * jnp.diag(jnp.diag(H) + 1e-9) + (1.0 - free)[:, None] * eye + 1e-10 * eye
        delta = -jnp.linalg.solve(Hd, g) * free
        th_new = th + delta
        c_new = cost(th_new)
        ok = jnp.isfinite(c_new) & (c_new < c)
        return (jnp.where(ok, th_new, th), jnp.where(ok, lam * 0.3, lam * 10.0), jnp.where(ok, c_new, c)), None

    (th, _, c), _ = jax.lax.scan(step, (theta0, jnp.asarray(1e-3, theta0.dtype), cost(theta0)), None, length=n_iter)
    return th, c


@partial(jax.jit, static_argnames=("layout", "n_iter"))
def _evaluate(theta0, masks, train_w, test_w, valid_w, group_free, data, layout, n_iter):
    """Fit every model on every training fold and on all stations, in one call.

    Args:
        theta0: (P,) start. masks: (M, P) free parameters per model.
        train_w, test_w: (K, n) station weights of each fold. valid_w: (n,).
        group_free: (P,) the group-direction nuisances (re-fitted on all stations
            with the fold's global parameters fixed before held-out scoring).
    Returns:
        dict of arrays: theta_full (M, P), cost_full (M,), J_full (M, n*6, P),
        held-out per-station chi2 (M, n), held-out residual in physical units
        (M, n, 6), held-out prediction azimuth (M, n).
    """
    fit = lambda m, w: _lm_fit(theta0, m, w, data, layout, n_iter)
    th_fold, _ = jax.vmap(lambda m: jax.vmap(lambda w: fit(m, w))(train_w))(masks)  # (M, K, P)
    if layout.n_groups:
        refit = lambda th: _lm_fit(th, group_free, valid_w, data, layout, n_iter)[0]
        th_fold = jax.vmap(jax.vmap(refit))(th_fold)
    th_full, cost_full = jax.vmap(lambda m: fit(m, valid_w))(masks)

    def heldout(th):  # (n, 6) residuals, (n,) azimuth pred, for one fit
        Gp, Bp, *_ = predict(th, data, layout)
        return jnp.concatenate([Gp - data.G, Bp - data.B], 1), azimuth_from_gv(Gp, Bp)

    r_fold, az_fold = jax.vmap(jax.vmap(heldout))(th_fold)  # (M, K, n, 6), (M, K, n)
    sel = test_w[None, :, :, None]
    r_held = jnp.sum(r_fold * sel, 1)
    az_held = jnp.sum(az_fold * test_w[None], 1)  # each station is held out in exactly one fold
    chi2_held = jnp.sum((r_held / data.sig) ** 2, -1)

    def jac(th):
        return jax.jacfwd(lambda t: (residuals(t, data, layout) * jnp.sqrt(valid_w)[:, None]).ravel())(th)

    J_full = jax.vmap(jac)(th_full)
    return dict(theta_full=th_full, cost_full=cost_full, J_full=J_full, chi2_held=chi2_held,
                r_held=r_held, az_held=az_held)


# ============================================================ identifiability
def _orth(J, tol=1e-10):
    """Orthonormal basis of the column space of J (rows x cols), dropping null directions."""
    if J.shape[1] == 0:
        return np.zeros((J.shape[0], 0))
    u, s, _ = np.linalg.svd(J, full_matrices=False)
    return u[:, s > tol * max(s.max(initial=0.0), 1e-300)]


def canonical_independence(J_e, J_ctx):
    """How much of an effect's columns survive projection off a context.

    Args:
        J_e: (R, p) Jacobian columns of the effect. J_ctx: (R, q) columns of the
            model + nuisances it must be told apart from.
    Returns:
        (s, V, coef): s (p,) ascending in [0, 1] — for each direction V[:, i] of
        the effect's (column-normalized) parameters, the fraction of its residual
        signature that the context cannot mimic (s = sqrt(1 - canonical corr^2));
        coef (q, p): the context combination that best mimics each direction.
    """
    norms = np.linalg.norm(J_e, axis=0)
    live = norms > 1e-12 * max(norms.max(initial=0.0), 1e-300)
    Jn = np.where(live, J_e / np.where(live, norms, 1.0), 0.0)
    Q = _orth(J_ctx)
    P = Jn - Q @ (Q.T @ Jn)
    # generalized: minimize |P v| / |Jn v| over v
    Qe, Re = np.linalg.qr(Jn)
    keep = np.abs(np.diag(Re)) > 1e-9
    s_all = np.zeros(J_e.shape[1])
    V = np.eye(J_e.shape[1])
    if keep.any():
        Rinv = np.linalg.pinv(Re)
        M = P @ Rinv
        _, s, vt = np.linalg.svd(M, full_matrices=False)
        order = np.argsort(s)
        s = np.clip(s[order], 0, 1)
        V = Rinv @ vt[order].T
        V = V / np.maximum(np.linalg.norm(V, axis=0), 1e-300)
        s_all = s
    # columns with zero signature are unobservable (s = 0) even without context
    coef = np.linalg.lstsq(J_ctx, (Jn - P) @ V, rcond=None)[0] if J_ctx.shape[1] else np.zeros((0, V.shape[1]))
    return s_all, V, coef


def _describe_direction(v, labels_e, coef, labels_ctx, ctx_norms, thresh=0.3):
    parts = [labels_e[j] for j in np.argsort(-np.abs(v)) if abs(v[j]) > thresh * np.abs(v).max()]
    lhs = " + ".join(parts[:3])
    if coef.size == 0 or np.abs(coef).max() < 1e-6:
        return f"{lhs} leaves no trace in the residual (unobservable with these attitudes)"
    w = np.abs(coef) * ctx_norms
    rhs = [labels_ctx[j] for j in np.argsort(-w) if w[j] > thresh * w.max()]
    return f"{lhs} mimics {' + '.join(rhs[:3])}"


def identifiability(J, layout: Layout, effect: str, context_free, threshold=0.02):
    """Directions of ``effect`` that the context (model + nuisances) can mimic.

    Args:
        J: (R, P) noise-weighted Jacobian (all stations).
        effect: the candidate effect name.
        context_free: (P,) bool, the context's free parameters (the effect's own excluded).
        threshold: s below this counts as not separable (canonical correlation
            above sqrt(1 - threshold^2), 0.9998 for 0.02).
    Returns:
        list of (s, sentence) for the non-separable directions (empty if separable).
    """
    sl = layout.slice(effect)
    idx_ctx = np.flatnonzero(context_free)
    idx_ctx = idx_ctx[(idx_ctx < sl.start) | (idx_ctx >= sl.stop)]
    J = np.asarray(J)
    s, V, coef = canonical_independence(J[:, sl], J[:, idx_ctx])
    labels = layout.labels()
    le = labels[sl]
    lc = [labels[i] for i in idx_ctx]
    cn = np.linalg.norm(J[:, idx_ctx], axis=0) if len(idx_ctx) else np.zeros(0)
    out = [(float(s[i]), _describe_direction(V[:, i], le, coef[:, i] if coef.size else coef, lc, cn))
           for i in range(len(s)) if s[i] < threshold]
    # absolute observability: theta = 1 is the effect's typical magnitude, so a column
    # norm below 1 means that magnitude moves the chi2 by less than 1 (below the noise)
    norms = np.linalg.norm(J[:, sl], axis=0)
    for j in np.flatnonzero(norms < 1.0):
        out.append((0.0, f"{le[j]} leaves no trace above the noise (a typical {le[j]} changes chi2 by "
                         f"{norms[j] ** 2:.2g}): unobservable with these attitudes"))
    return out


def separability(st: Stations, effects=None, threshold=0.02, sigma_b_nT=SIGMA_B_NT, sigma_g=SIGMA_G):
    """Which effects (or parameter directions) a station design cannot tell apart.

    Evaluated at the ideal model (no effects) from the attitudes and field in
    ``st``: for every pair of effects, the canonical correlations between their
    Jacobian columns after projecting out the nuisances; for every effect, the
    directions unobservable on their own.

    Returns:
        dict with ``pairs``: list of {a, b, s_min, what} for pairs with a shared
        direction (s < threshold), and ``unobservable``: list of {effect, what}.
    """
    layout, data, valid, free_nuis = prepare(st, sigma_b_nT, sigma_g)
    names = list(effects or layout.names)
    theta = jnp.zeros(layout.n_params)
    J = np.asarray(jax.jacfwd(lambda t: (residuals(t, data, layout) * jnp.asarray(valid, float)[:, None]).ravel())(theta))
    out = {"pairs": [], "unobservable": []}
    for a in names:
        for d in identifiability(J, layout, a, free_nuis, threshold):
            if "leaves no trace" in d[1]:
                out["unobservable"].append({"effect": a, "s": d[0], "what": d[1]})
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            ctx = free_nuis.copy()
            ctx[layout.slice(b)] = True
            for s_, what in identifiability(J, layout, a, ctx, threshold):
                if "leaves no trace" in what:
                    continue
                if b in what:
                    out["pairs"].append({"a": a, "b": b, "s": s_, "what": what})
    return out


# ============================================================ compare / describe
def _harmonic_fractions(y, t_deg):
    """Fractions of var(y) (about 0) explained by the constant, 1st and 2nd toolface harmonics."""
    t = np.deg2rad(t_deg)
    X = np.stack([np.ones_like(t), np.cos(t), np.sin(t), np.cos(2 * t), np.sin(2 * t)], 1)
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    tot = max(float(np.sum(y**2)), 1e-300)
    parts = {"constant": X[:, :1] @ coef[:1], "1st": X[:, 1:3] @ coef[1:3], "2nd": X[:, 3:] @ coef[3:]}
    return {k: float(np.sum(v**2)) / tot for k, v in parts.items()}


def compare(st: Stations, G_pred, B_pred, toolface, azimuth, inclination, valid=None, n_bins=8):
    """compare: residuals in the tool frame and derived quantities, and where they concentrate.

    Args:
        G_pred, B_pred: (n, 3) model predictions. toolface, azimuth, inclination:
            (n,) the attitude the model assumed (deg).
    Returns:
        dict: ``resid`` (n, 6) measured - predicted (g, nT); ``total_field_nT``,
        ``dip_deg``, ``azimuth_deg`` (n,) measured - predicted; ``rms`` per
        component; ``bins`` (RMS |dB| and azimuth error over toolface,
        inclination, azimuth); ``harmonics`` of the B residual; ``correlations``
        with extra columns; ``sentences`` (see :func:`describe`).
    """
    G, B = np.asarray(st.G), np.asarray(st.B)
    Gp, Bp = np.asarray(G_pred), np.asarray(B_pred)
    valid = np.ones(len(G), bool) if valid is None else np.asarray(valid, bool)
    r = np.concatenate([G - Gp, B - Bp], 1)

    def dip(g, b):
        c = np.sum(g * b, 1) / (np.linalg.norm(g, axis=1) * np.linalg.norm(b, axis=1))
        return np.rad2deg(np.arcsin(np.clip(c, -1, 1)))

    d_total = np.linalg.norm(B, axis=1) - np.linalg.norm(Bp, axis=1)
    d_dip = dip(G, B) - dip(Gp, Bp)
    d_az = np.asarray(angle_diff(azimuth_from_gv(G, B), azimuth_from_gv(Gp, Bp)))
    az_ok = valid & (np.asarray(inclination_from_g(G)) > 3.0) & (np.asarray(inclination_from_g(G)) < 177.0)
    T, A, I = (np.asarray(x) for x in (toolface, azimuth, inclination))
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
            rows.append((float(edges[b]), float(edges[b + 1]), int(m.sum()),
                         float(np.sqrt(np.mean(bmag[m] ** 2))) if m.any() else float("nan"),
                         float(np.sqrt(np.mean(d_az[ma] ** 2))) if ma.any() else float("nan")))
        bins[name] = rows
    harm = {c: _harmonic_fractions(r[valid, 3 + j], T[valid]) for j, c in enumerate("xyz")}
    corr = {}
    for name, x in dict(st.extras or {}, station_order=np.arange(len(G), dtype=float)).items():
        x = np.asarray(x, float)
        if np.std(x[valid]) > 0:
            cs = [abs(float(np.corrcoef(x[valid], r[valid, j])[0, 1])) if np.std(r[valid, j]) > 0 else 0.0
                  for j in range(6)]
            corr[name] = cs
    # azimuth error vs the axial-interference signature sin I sin A (ENGINEERING-NOTES, ISCWSA)
    sig = np.sin(np.deg2rad(I)) * np.sin(np.deg2rad(A))
    r2_axial = float(np.corrcoef(sig[az_ok], d_az[az_ok])[0, 1] ** 2) if az_ok.sum() > 3 and np.std(sig[az_ok]) > 0 and np.std(d_az[az_ok]) > 0 else 0.0
    out = dict(resid=r, total_field_nT=d_total, dip_deg=d_dip, azimuth_deg=d_az, valid=valid, az_ok=az_ok,
               rms={c: float(np.sqrt(np.mean(r[valid, j] ** 2))) for j, c in enumerate(("gx", "gy", "gz", "bx", "by", "bz"))},
               rms_total_field_nT=float(np.sqrt(np.mean(d_total[valid] ** 2))),
               mean_total_field_nT=float(np.mean(d_total[valid])),
               rms_dip_deg=float(np.sqrt(np.mean(d_dip[valid] ** 2))),
               rms_azimuth_deg=float(np.sqrt(np.mean(d_az[az_ok] ** 2))) if az_ok.any() else float("nan"),
               toolface=T, bins=bins, harmonics=harm, correlations=corr, r2_axial=r2_axial)
    out["sentences"] = describe(out)
    return out


def describe(cmp: dict, sigma_b_nT=SIGMA_B_NT, sigma_g=SIGMA_G) -> list[str]:
    """Where the residual concentrates, in words (from a :func:`compare` dict)."""
    s = []
    rms = cmp["rms"]
    b_rms = math.sqrt(sum(rms[c] ** 2 for c in ("bx", "by", "bz")) / 3)
    g_rms = math.sqrt(sum(rms[c] ** 2 for c in ("gx", "gy", "gz")) / 3)
    s.append(f"magnetometer residual RMS {b_rms:.1f} nT per axis ({b_rms / sigma_b_nT:.1f}x noise), "
             f"accelerometer {g_rms * 1e3:.3f} mg ({g_rms / sigma_g:.1f}x noise)")
    axes = ("bx", "by", "bz") if b_rms / sigma_b_nT >= g_rms / sigma_g else ("gx", "gy", "gz")
    top = max(axes, key=lambda c: rms[c])
    if rms[top] ** 2 > 0.6 * sum(rms[c] ** 2 for c in axes):
        s.append(f"it concentrates on {top}")
    h = cmp["harmonics"]
    hx = {k: (h["x"][k] + h["y"][k]) / 2 for k in h["x"]}
    if b_rms > 2 * sigma_b_nT:
        if hx["constant"] > 0.5:
            s.append(f"the cross-axial field residual is constant in tool coordinates ({hx['constant']:.0%} of it): "
                     "the source turns with the tool (tool-fixed)")
        elif hx["1st"] > 0.5:
            s.append(f"the cross-axial field residual follows the 1st toolface harmonic ({hx['1st']:.0%}): "
                     "it rotates relative to the tool, as an earth-fixed source or a tilted reference does")
        elif hx["2nd"] > 0.3:
            s.append(f"the cross-axial field residual has a 2nd toolface harmonic ({hx['2nd']:.0%}): "
                     "scale-factor or cross-coupling-like")
    if abs(cmp["mean_total_field_nT"]) > 3 * sigma_b_nT:
        s.append(f"measured total field is off by {cmp['mean_total_field_nT']:+.0f} nT on average")
    if cmp["r2_axial"] > 0.5:
        s.append(f"azimuth error grows with sin I sin A (R^2 = {cmp['r2_axial']:.2f}): axial-interference signature")
    rows = [r for r in cmp["bins"]["inclination"] if r[2] > 0 and np.isfinite(r[4])]
    if rows and cmp["rms_azimuth_deg"] > 0:
        worst = max(rows, key=lambda r: r[4])
        if worst[4] > 1.5 * cmp["rms_azimuth_deg"]:
            s.append(f"azimuth error concentrates at inclination {worst[0]:.0f}-{worst[1]:.0f} deg "
                     f"(RMS {worst[4]:.2f} vs {cmp['rms_azimuth_deg']:.2f} deg overall)")
    comp = ("gx", "gy", "gz", "bx", "by", "bz")
    for name, cs in cmp["correlations"].items():
        j = int(np.argmax(cs))
        if cs[j] > 0.5:
            s.append(f"residual {comp[j]} correlates with {name} (|r| = {cs[j]:.2f}): "
                     "a dependence no vocabulary effect has")
    return s


# ============================================================ the workflow
class Step(NamedTuple):
    """One add step (the JSON "effects" entries)."""

    name: str
    params: list
    stderr: list
    units: str
    gap_before: dict
    gap_after: dict
    heldout_before: float
    heldout_after: float
    z_improvement: float
    runner_up: str | None
    margin_z: float
    delta_bic: float
    separable: bool
    equivalent: list
    notes: list
    candidates: list


class Result(NamedTuple):
    steps: list
    verdict: str
    kind: str               # no_missing_effect | explained | unexplained | not_separable
    model: list             # effect names in the final model
    theta: np.ndarray
    layout: Layout
    gaps: list              # gap dict per model (step 0 = reference model)
    compare_before: dict
    compare_after: dict
    pattern: list
    field: tuple            # fitted (total nT, dip deg, declination deg)
    seconds: float

    @property
    def named(self) -> list:
        return [s.name for s in self.steps if s.separable]


def _folds(st: Stations, valid, k, key):
    """(K, n) train and test weights: a random permutation, round-robin per group."""
    n = st.n
    idx = np.flatnonzero(valid)
    perm = idx[np.asarray(jax.random.permutation(key, idx.size))]
    fold = np.full(n, -1)
    if st.group is not None and not st.has_reference:
        g = np.asarray(st.group)[perm]
        for gid in np.unique(g):
            sel = perm[g == gid]
            fold[sel] = (np.arange(len(sel)) + int(gid)) % k
    else:
        fold[perm] = np.arange(perm.size) % k
    test = np.stack([(fold == i) & valid for i in range(k)]).astype(float)
    train = np.stack([(fold != i) & (fold >= 0) & valid for i in range(k)]).astype(float)
    return train, test


def _gap(r_held, az_err, valid, az_ok, sig, floor):
    """Held-out gap: RMS magnetometer residual (nT, per axis), RMS azimuth error (deg),
    RMS accelerometer residual (g), chi2 per residual, and the excess over noise
    ``sqrt(max(chi2 / floor - 1, 0))`` (0 for a model that leaves only noise;
    ``floor`` is the chi2 per residual that noise alone leaves, see :func:`noise_floor`)."""
    chi2 = np.mean((r_held[valid] / sig[valid]) ** 2)
    return {"mag_rms_nT": float(np.sqrt(np.mean(r_held[valid, 3:] ** 2))),
            "azimuth_rms_deg": float(np.sqrt(np.mean(az_err[az_ok] ** 2))) if az_ok.any() else float("nan"),
            "accel_rms_g": float(np.sqrt(np.mean(r_held[valid, :3] ** 2))),
            "chi2_per_residual": float(chi2),
            "excess_over_noise": float(np.sqrt(max(chi2 / floor - 1.0, 0.0)))}


def noise_floor(st: Stations, n_valid: int) -> float:
    """Expected chi2 per residual component when only noise is left.

    Each station's toolface is taken from its measured G, which absorbs one of
    its six residual components (5/6); in group mode each group's two direction
    nuisances absorb two more per group.
    """
    n_groups = 0 if st.has_reference else len(np.unique(np.asarray(st.group)))
    return max((5.0 * n_valid - 2.0 * n_groups) / (6.0 * n_valid), 0.1)


def run_workflow(st: Stations, *, k_folds=5, max_effects=4, min_rel_improvement=0.10, min_z=3.0,
                 ambiguity_z=2.0, noise_tolerance=1.5, separability_threshold=0.02, n_iter=12,
                 sigma_b_nT=SIGMA_B_NT, sigma_g=SIGMA_G, key=None, candidates=None, bucket=120,
                 verbose=False) -> Result:
    """name + add + show: greedy forward search over the effect vocabulary.

    At each step every effect not yet in the model is fitted together with the
    model (see :func:`_evaluate`). The best candidate (lowest held-out chi2) is
    added when it lowers the held-out chi2 by at least ``min_rel_improvement``
    (ENGINEERING-NOTES: 10 %) AND the paired per-station improvement is
    significant (z >= ``min_z``). If the runner-up qualifies too and the margin
    between them is not significant (z < ``ambiguity_z``), the step is marked
    not separable and both are reported (the representative is kept in the model
    so that the search can go on).

    Verdict: ``no missing effect`` when nothing was added and the held-out chi2
    per residual is within ``noise_tolerance`` x the noise floor; ``explained`` when effects were
    added and the rest is noise; ``unexplained structure remains`` (with the
    residual's pattern) otherwise; ``not separable`` when a step was ambiguous.

    Args:
        st: stations. k_folds: folds of the held-out score. max_effects: cap.
        candidates: effect names to consider (default: the whole vocabulary).
        key: PRNG key for the fold permutation (default PRNGKey(0)).
        bucket: pad the stations to a multiple of this (see :func:`pad_stations`);
            the Result's per-station arrays have the padded length, with
            ``compare_*["valid"]`` False on the pads.
    Returns:
        Result.
    """
    import time

    t0 = time.perf_counter()
    key = jax.random.PRNGKey(0) if key is None else key
    check_stations(st)
    st, real = pad_stations(st, bucket)
    layout, data, valid, free_nuis = prepare(st, sigma_b_nT, sigma_g)
    valid = valid & real
    names = list(layout.names)
    cand_names = list(candidates or names)
    _fx.check_names(cand_names)
    train, test = _folds(st, valid, k_folds, key)
    valid_w = valid.astype(float)
    group_free = np.zeros(layout.n_params)
    group_free[layout.n_effect + 3:] = 1.0
    sig = np.asarray(data.sig)
    scales = layout.scales()

    model: list[str] = []
    theta = np.zeros(layout.n_params)
    steps, gaps = [], []
    pattern_before = None
    kind = None
    n_res = 6 * int(valid.sum())
    floor = noise_floor(st, int(valid.sum()))

    def mask_for(effs):
        m = free_nuis.astype(float).copy()
        for e in effs:
            m[layout.slice(e)] = 1.0
        return m

    while True:
        # fixed number of models (current + every candidate) so that shapes, hence the
        # compiled function, stay the same across steps; effects already in the
        # model are evaluated as duplicates of the current model and ignored.
        trial = [None] + [c if c not in model else "" for c in cand_names]
        masks = np.stack([mask_for(model + ([c] if c else [])) for c in trial])
        out = _evaluate(jnp.asarray(theta), jnp.asarray(masks), jnp.asarray(train), jnp.asarray(test),
                        jnp.asarray(valid_w), jnp.asarray(group_free), data, layout, n_iter)
        out = {k: np.asarray(v) for k, v in out.items()}
        chi2 = out["chi2_held"]                     # (M, n)
        az_meas = np.asarray(azimuth_from_gv(st.G, st.B))
        cur = 0
        pred_cur = predict(jnp.asarray(out["theta_full"][cur]), data, layout)
        cmp_cur = compare(st, pred_cur[0], pred_cur[1], pred_cur[2], pred_cur[3], pred_cur[4], valid)
        az_ok = cmp_cur["az_ok"]

        def gap_of(m):
            return _gap(out["r_held"][m] * -1.0, np.asarray(angle_diff(az_meas, out["az_held"][m])), valid, az_ok, sig,
                        floor)

        if not gaps:
            gaps.append(gap_of(cur))
            pattern_before = cmp_cur
        S = chi2[:, valid].mean(1) / 6.0
        bic = out["cost_full"] + masks.sum(1) * np.log(max(n_res, 2))
        cands = []
        for m, c in enumerate(trial):
            if not c:
                continue
            d = chi2[cur, valid] - chi2[m, valid]
            z = float(d.mean() / max(d.std(ddof=1) / math.sqrt(d.size), 1e-9))
            ok = S[m] < (1.0 - min_rel_improvement) * S[cur] and z >= min_z
            p = out["theta_full"][m][layout.slice(c)] * scales[layout.slice(c)]
            cands.append((m, c, float(S[m]), float(bic[m]), z, ok, p))
        cands.sort(key=lambda t: t[2])
        if verbose:
            print(f"step {len(steps) + 1}: model {model or '[reference]'}; held-out chi2/residual {S[cur]:.3f}")
            for m, c, s_, b, z, ok, _ in cands:
                print(f"    {c:20s} held-out {s_:9.3f}  BIC {b:12.1f}  z {z:7.1f}  {'qualifies' if ok else ''}")
        if not cands or not cands[0][5] or len(model) >= max_effects:
            break
        m, c, s_best, b_best, z_best, _, p_best = cands[0]
        runner = cands[1] if len(cands) > 1 else None
        if runner is not None:
            d = chi2[runner[0], valid] - chi2[m, valid]
            margin_z = float(d.mean() / max(d.std(ddof=1) / math.sqrt(d.size), 1e-9))
            dbic = float(runner[3] - b_best)
        else:
            margin_z, dbic = float("inf"), float("inf")
        equivalent = []
        for r in cands[1:]:
            d = chi2[r[0], valid] - chi2[m, valid]
            zr = float(d.mean() / max(d.std(ddof=1) / math.sqrt(d.size), 1e-9))
            if r[5] and zr < ambiguity_z:
                equivalent.append(r[1])
        J = out["J_full"][m]  # all P columns (the Jacobian ignores the mask)
        notes = []
        ctx = mask_for(model).astype(bool)
        for s_, what in identifiability(J, layout, c, ctx, separability_threshold):
            notes.append(f"given the model: {what} (s = {s_:.1e})")
        for e in equivalent:
            ctx2 = ctx.copy()
            ctx2[layout.slice(e)] = True
            for s_, what in identifiability(J, layout, c, ctx2, 0.2):
                if e in what:
                    notes.append(f"{what} (canonical correlation {math.sqrt(max(1 - s_**2, 0)):.4f})")
        # standard errors from the Gauss-Newton covariance on all stations
        free_idx = np.flatnonzero(masks[m] > 0)
        Jf = J[:, free_idx]
        s2 = out["cost_full"][m] / max(n_res - len(free_idx), 1)
        cov = np.linalg.pinv(Jf.T @ Jf) * s2
        se_all = np.zeros(layout.n_params)
        se_all[free_idx] = np.sqrt(np.maximum(np.diag(cov), 0.0))
        sl = layout.slice(c)
        se = se_all[sl] * scales[sl]
        gap_after = gap_of(m)
        steps.append(Step(
            name=c, params=[float(x) for x in p_best], stderr=[float(x) for x in se],
            units=_fx.EFFECTS[c].units, gap_before=gaps[-1], gap_after=gap_after,
            heldout_before=float(S[cur]), heldout_after=s_best, z_improvement=z_best,
            runner_up=runner[1] if runner else None, margin_z=margin_z, delta_bic=dbic,
            separable=not equivalent, equivalent=equivalent, notes=notes,
            candidates=[{"name": cc, "heldout": s2_, "bic": b2, "z": z2, "qualifies": bool(ok2)}
                        for _, cc, s2_, b2, z2, ok2, _ in cands]))
        gaps.append(gap_after)
        if verbose:
            tag = "named" if not equivalent else f"NOT SEPARABLE from {equivalent}"
            print(f"  -> {c} {tag}: params {np.round(p_best, 6).tolist()} +- {np.round(se, 6).tolist()} {_fx.EFFECTS[c].units};"
                  f" margin over {steps[-1].runner_up}: z = {margin_z:.1f}, dBIC = {dbic:.1f}")
            for nt in notes:
                print(f"     note: {nt}")
        model.append(c)
        theta = out["theta_full"][m]
    # final state: the model's own full fit
    theta = out["theta_full"][0]
    S_final = float(chi2[0, valid].mean() / 6.0)
    pred = predict(jnp.asarray(theta), data, layout)
    cmp_after = compare(st, pred[0], pred[1], pred[2], pred[3], pred[4], valid)
    pattern = describe(cmp_after, sigma_b_nT, sigma_g)
    ambiguous = [s for s in steps if not s.separable]
    if ambiguous:
        kind = "not_separable"
        verdict = "not separable: " + "; ".join(
            f"{' / '.join([s.name] + s.equivalent)} explain the same discrepancy with these attitudes "
            "(no significant margin between them)" for s in ambiguous)
        clear = [s.name for s in steps if s.separable]
        if clear:
            verdict += f"; named: {', '.join(clear)}"
        if S_final > noise_tolerance * floor:
            verdict += "; unexplained structure remains: " + "; ".join(pattern)
    elif S_final > noise_tolerance * floor:
        kind = "unexplained"
        verdict = "unexplained structure remains"
        if model:
            verdict += f" after adding {', '.join(model)}"
        verdict += f" (held-out chi2/residual {S_final:.2f}): " + "; ".join(pattern)
    elif not model:
        kind = "no_missing_effect"
        verdict = f"no missing effect: the reference model explains the data to noise (held-out chi2/residual {S_final:.2f})"
    else:
        kind = "explained"
        verdict = f"explained by {', '.join(model)}; the rest is noise (held-out chi2/residual {S_final:.2f})"
    if verbose:
        print("verdict:", verdict)
    return Result(steps=steps, verdict=verdict, kind=kind, model=model, theta=theta, layout=layout, gaps=gaps,
                  compare_before=pattern_before, compare_after=cmp_after, pattern=pattern,
                  field=tuple(float(x) for x in np.asarray(data.field0) + theta[layout.n_effect:layout.n_effect + 3] * np.asarray(FIELD_SCALES)),
                  seconds=time.perf_counter() - t0)


# ============================================================ show
def gap_table(res: Result):
    """The gap after each step as a pandas DataFrame (held-out stations)."""
    import pandas as pd

    rows = [dict(step=0, model="reference", **res.gaps[0])]
    for i, s in enumerate(res.steps):
        rows.append(dict(step=i + 1, model="+ " + s.name + ("" if s.separable else f" (or {', '.join(s.equivalent)})"),
                         **s.gap_after))
    return pd.DataFrame(rows)


def result_to_json(res: Result) -> dict:
    """Machine-readable result: {"effects": [{name, params, stderr, gap_before, gap_after, ...}], "verdict"}."""
    return {
        "effects": [
            {"name": s.name, "params": s.params, "stderr": s.stderr, "units": s.units,
             "gap_before": s.gap_before, "gap_after": s.gap_after,
             "heldout_chi2_before": s.heldout_before, "heldout_chi2_after": s.heldout_after,
             "runner_up": s.runner_up, "evidence_margin_z": s.margin_z, "delta_bic_runner_up": s.delta_bic,
             "separable": s.separable, "equivalent": s.equivalent, "notes": s.notes}
            for s in res.steps],
        "verdict": res.verdict,
        "kind": res.kind,
        "pattern": res.pattern,
        "seconds": res.seconds,
    }


def model_params(res: Result) -> dict:
    """name -> physical parameters of the effects in the final model."""
    phys = res.theta * res.layout.scales()
    return {nm: phys[res.layout.slice(nm)] for nm in res.model}


def correct(res: Result, G, B, sigma_b_nT=SIGMA_B_NT, sigma_g=SIGMA_G, n_iter=10):
    """Invert the fitted model: the attitude that best explains each measured station.

    Per station, Gauss-Newton on (A, I) (toolface from G with the model's
    accelerometer effects removed) minimizing the noise-weighted residual of
    the fitted forward model, started from the raw attitude; vmapped over
    stations. Used to score an augmented physics model's azimuth against a
    reference (e.g. against ICGO-RELM on the same test split).

    Args:
        res: a workflow result (its model, fitted parameters and field).
        G: (n, 3) g, B: (n, 3) nT measured.
    Returns:
        (azimuth_deg (n,) in the frame of the fitted declination, inclination_deg (n,)).
    """
    G = jnp.asarray(np.asarray(G, np.float64))
    B = jnp.asarray(np.asarray(B, np.float64))
    params = {k: jnp.asarray(v) for k, v in model_params(res).items()}
    F, dip, dec = res.field
    f_ned = field_vector_ned(F, dip, dec)
    sig = jnp.asarray(_effective_sigma(np.asarray(G), np.asarray(B), sigma_b_nT, sigma_g))
    return _correct_jit(params, G, B, sig, f_ned, dec, n_iter)


@partial(jax.jit, static_argnames=("n_iter",))
def _correct_jit(params, G, B, sig, f_ned, dec, n_iter):
    T = toolface_from_g(_remove_accel_effects(params, G))
    g_ned = jnp.array([0.0, 0.0, 1.0]) * jnp.linalg.norm(G, axis=1).mean()

    def res1(ai, t, g, b, s):
        C = tool_to_earth(ai[0], ai[1], t)
        Gp, Bp = _fx.apply_effects(params, C.T @ g_ned, C.T @ f_ned, C)
        return jnp.concatenate([Gp - g, Bp - b]) / s

    def solve(t, g, b, s, a0, i0):
        def step(ai, _):
            r = res1(ai, t, g, b, s)
            J = jax.jacfwd(res1)(ai, t, g, b, s)
            return ai - jnp.linalg.solve(J.T @ J + 1e-9 * jnp.eye(2), J.T @ r), None

        ai, _ = jax.lax.scan(step, jnp.stack([a0, i0]), None, length=n_iter)
        return ai

    a0 = azimuth_from_gv(G, B) + dec
    i0 = inclination_from_g(G)
    ai = jax.vmap(solve)(T, G, B, sig, a0, i0)
    return jnp.mod(ai[:, 0], 360.0), ai[:, 1]


# ============================================================ plots
def plot_residual_vs_toolface(res: Result, path):
    """Figure: B residual components vs toolface, before (reference model) and after (final model)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(12, 6), sharex=True)
    for row, (cmp, title) in enumerate(((res.compare_before, "before"), (res.compare_after, "after"))):
        r = cmp["resid"]
        v = cmp["valid"]
        T = np.mod(cmp["toolface"], 360)
        for j, c in enumerate("xyz"):
            ax = axes[row, j]
            ax.plot(T[v], r[v, 3 + j], ".", ms=3)
            ax.axhline(0, color="k", lw=0.5)
            ax.set_title(f"b{c} residual, {title}")
            ax.set_ylabel("nT")
            if row == 1:
                ax.set_xlabel("toolface (deg)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_gap_per_step(res: Result, path):
    """Figure: held-out gap (RMS |dB| nT, RMS azimuth deg) after each step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tab = gap_table(res)
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    x = np.arange(len(tab))
    ax[0].bar(x, tab["mag_rms_nT"])
    ax[0].set_ylabel("held-out RMS magnetometer residual (nT)")
    ax[1].bar(x, tab["azimuth_rms_deg"], color="C1")
    ax[1].set_ylabel("held-out RMS azimuth error (deg)")
    for a in ax:
        a.set_xticks(x, tab["model"], rotation=20, ha="right", fontsize=8)
        a.set_yscale("log")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
