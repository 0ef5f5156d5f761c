"""The fits: Levenberg-Marquardt over a free-parameter mask (:func:`icgo.lsq.least_squares_fixed`), the
batched k-fold evaluation of candidate models, standard errors, and the inverse model
(:func:`correct`).

All residuals are measured - predicted (see :mod:`icgo.discrepancy.model`).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo import effects as _fx
from icgo.discrepancy.model import Data, Layout, physical_residuals, predict, remove_accel_effects, residuals
from icgo.discrepancy.noise import Noise, effective_sigma
from icgo.frames import azimuth_from_gv, field_vector_ned, inclination_from_g, tool_to_earth, toolface_from_g
from icgo.lsq import least_squares_fixed


# ============================================================ Levenberg-Marquardt
def lm_fit(theta0, free, w, data: Data, layout: Layout, n_iter: int):
    """Weighted fit of the scaled parameters; only ``free`` parameters move.

    The station-weighted, noise-normalized residuals (non-finite components
    replaced by 1e6) minimized by :func:`icgo.lsq.least_squares_fixed`
    (Marquardt-damped LM, a fixed number of steps in ``lax.scan``, so the
    vmapped models x folds all cost ``n_iter`` steps).

    Args:
        theta0: (P,) start (scaled parameters, see :class:`~icgo.discrepancy.model.Layout`).
        free: (P,) 0/1 or bool. w: (n,) station weights (0 = not used).
        n_iter: LM iterations (static).
    Returns:
        (theta (P,), cost = sum of weighted squared noise-normalized residuals ()).
    """
    sw = jnp.sqrt(w)[:, None]

    def res(th, _):
        r = residuals(th, data, layout) * sw
        return jnp.where(jnp.isfinite(r), r, 1e6).ravel()

    out = least_squares_fixed(res, theta0, n_steps=n_iter, free=free)
    return out.x, out.cost


# ============================================================ k-fold evaluation
class Evaluation(NamedTuple):
    """Every model fitted on every training fold and on all stations (a pytree).

    M models (rows of the mask stack), n stations, P parameters.

    Attributes:
        theta_full: (M, P) fit on all valid stations.
        cost_full: (M,) its sum of squared noise-normalized residuals.
        J_full: (M, 6n, P) noise-weighted Jacobian of the residuals at theta_full
            (all P columns, whatever the mask).
        chi2_held: (M, n) held-out chi2 per station (each station scored by the
            fold that left it out).
        r_held: (M, n, 6) held-out residuals measured - predicted, g and nT.
        az_held: (M, n) held-out predicted azimuth, deg.
    """

    theta_full: jnp.ndarray
    cost_full: jnp.ndarray
    J_full: jnp.ndarray
    chi2_held: jnp.ndarray
    r_held: jnp.ndarray
    az_held: jnp.ndarray


@partial(jax.jit, static_argnames=("layout", "n_iter"))
def evaluate_models(theta0, masks, train_w, test_w, valid_w, group_free, data: Data, layout: Layout,
                    n_iter: int) -> Evaluation:
    """Fit every model on every training fold and on all stations, in one jitted call.

    Args:
        theta0: (P,) start. masks: (M, P) free parameters per model (0/1).
        train_w, test_w: (K, n) station weights of each fold. valid_w: (n,).
        group_free: (P,) the group-direction nuisances (re-fitted on all stations
            with the fold's global parameters fixed before held-out scoring).
        n_iter: LM iterations per fit (static).
    Returns:
        :class:`Evaluation` (``vmap`` over models x folds).
    """
    fit = lambda m, w: lm_fit(theta0, m, w, data, layout, n_iter)
    th_fold, _ = jax.vmap(lambda m: jax.vmap(lambda w: fit(m, w))(train_w))(masks)  # (M, K, P)
    if layout.n_groups:
        refit = lambda th: lm_fit(th, group_free, valid_w, data, layout, n_iter)[0]
        th_fold = jax.vmap(jax.vmap(refit))(th_fold)
    th_full, cost_full = jax.vmap(lambda m: fit(m, valid_w))(masks)

    def heldout(th):  # (n, 6) residuals, (n,) azimuth pred, for one fit
        pred = predict(th, data, layout)
        return physical_residuals(pred, data), azimuth_from_gv(pred.G, pred.B)

    r_fold, az_fold = jax.vmap(jax.vmap(heldout))(th_fold)  # (M, K, n, 6), (M, K, n)
    sel = test_w[None, :, :, None]
    r_held = jnp.sum(r_fold * sel, 1)
    az_held = jnp.sum(az_fold * test_w[None], 1)  # each station is held out in exactly one fold
    chi2_held = jnp.sum((r_held / data.sig) ** 2, -1)

    def jac(th):
        return jax.jacfwd(lambda t: (residuals(t, data, layout) * jnp.sqrt(valid_w)[:, None]).ravel())(th)

    J_full = jax.vmap(jac)(th_full)
    return Evaluation(th_full, cost_full, J_full, chi2_held, r_held, az_held)


def folds(valid, k: int, key, group=None):
    """(K, n) train and test weights: a random permutation, round-robin per group.

    Args:
        valid: (n,) bool, stations that may be used. k: number of folds.
        key: PRNG key of the permutation.
        group: (n,) group ids (group mode: each group's stations are spread over
            the folds), or None.
    Returns:
        (train (K, n), test (K, n)) 0/1 float weights; each valid station is in
        exactly one test fold.
    """
    valid = np.asarray(valid, bool)
    n = valid.size
    idx = np.flatnonzero(valid)
    perm = idx[np.asarray(jax.random.permutation(key, idx.size))]
    fold = np.full(n, -1)
    if group is not None:
        g = np.asarray(group)[perm]
        for gid in np.unique(g):
            sel = perm[g == gid]
            fold[sel] = (np.arange(len(sel)) + int(gid)) % k
    else:
        fold[perm] = np.arange(perm.size) % k
    test = np.stack([(fold == i) & valid for i in range(k)]).astype(float)
    train = np.stack([(fold != i) & (fold >= 0) & valid for i in range(k)]).astype(float)
    return train, test


def standard_errors(J, free, cost: float, n_res: int) -> np.ndarray:
    """Standard errors of the free scaled parameters from the Gauss-Newton covariance ``s² (JᵀJ)⁺``.

    Args:
        J: (R, P) noise-weighted Jacobian at the fit. free: (P,) 0/1 mask.
        cost: sum of squared noise-normalized residuals at the fit.
        n_res: number of residual components used (6 per valid station).
    Returns:
        (P,) standard errors of theta (0 for fixed parameters); multiply by
        ``Layout.scales()`` for physical units.
    """
    J = np.asarray(J)
    free_idx = np.flatnonzero(np.asarray(free) > 0)
    Jf = J[:, free_idx]
    s2 = cost / max(n_res - len(free_idx), 1)
    cov = np.linalg.pinv(Jf.T @ Jf) * s2
    se_all = np.zeros(J.shape[1])
    se_all[free_idx] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return se_all


# ============================================================ the inverse model
def model_params(res) -> dict:
    """name -> (n_params,) physical parameters of the effects in a workflow result's final model."""
    phys = res.theta * res.layout.scales()
    return {nm: phys[res.layout.slice(nm)] for nm in res.model}


class Inversion(NamedTuple):
    """Per station, what the inverted physics model says (:func:`correct`, :func:`correct_with`).

    Attributes:
        azimuth: (n,) deg in the frame of the fitted declination. inclination: (n,) deg.
        b_corrected: (n, 3) nT, the measured field with the model's fitted disturbance removed:
            ``B_meas - (B_pred - C^T f)`` at the solved attitude ``C`` (f the earth field, NED), i.e.
            the earth field in the tool frame plus what the model leaves unexplained.
    """

    azimuth: np.ndarray
    inclination: np.ndarray
    b_corrected: np.ndarray


def correct(res, G, B, noise: Noise | None = None, n_iter: int = 10) -> Inversion:
    """Invert the fitted model: the attitude that best explains each measured station.

    Per station, (A, I) (toolface from G with the model's accelerometer
    effects removed) minimizing the noise-weighted residual of the fitted
    forward model, started from the raw attitude, by
    :func:`icgo.lsq.least_squares_fixed` (Marquardt-damped LM, ``n_iter``
    steps, vmapped over stations). Used to score an augmented physics model's
    azimuth against a reference (e.g. against ICGO-RELM on the same test split).

    Args:
        res: a workflow result (its model, fitted parameters, field and config).
        G: (n, 3) g, B: (n, 3) nT measured.
        noise: residual weights; default the noise of ``res.config``.
        n_iter: LM steps per station.
    Returns:
        :class:`Inversion`.
    """
    noise = res.config.noise if noise is None else noise
    return correct_with(model_params(res), res.field, G, B, noise, n_iter)


def correct_with(params: dict, field, G, B, noise: Noise, n_iter: int = 10) -> Inversion:
    """:func:`correct` for given effect parameters and field (what a saved physics model holds).

    Args:
        params: effect name -> (n_params,) physical parameters (:func:`model_params`).
        field: (total nT, dip deg, declination deg).
        G: (n, 3) g, B: (n, 3) nT measured.
        noise: residual weights. n_iter: LM steps per station.
    Returns:
        :class:`Inversion`.
    """
    G = jnp.asarray(np.asarray(G, np.float64))
    B = jnp.asarray(np.asarray(B, np.float64))
    params = {k: jnp.asarray(v) for k, v in params.items()}
    F, dip, dec = field
    f_ned = field_vector_ned(F, dip, dec)
    sig = jnp.asarray(effective_sigma(np.asarray(G), np.asarray(B), noise))
    return Inversion(*(np.asarray(x) for x in _correct_jit(params, G, B, sig, f_ned, dec, n_iter)))


@partial(jax.jit, static_argnames=("n_iter",))
def _correct_jit(params, G, B, sig, f_ned, dec, n_iter):
    T = toolface_from_g(remove_accel_effects(params, G))
    g_ned = jnp.array([0.0, 0.0, 1.0]) * jnp.linalg.norm(G, axis=1).mean()

    def res1(ai, tgbs):  # (6,) measured - predicted, noise units
        t, g, b, s = tgbs
        C = tool_to_earth(ai[0], ai[1], t)
        Gp, Bp = _fx.apply_effects(params, C.T @ g_ned, C.T @ f_ned, C)
        return jnp.concatenate([g - Gp, b - Bp]) / s

    def solve(t, g, b, s, a0, i0):
        return least_squares_fixed(res1, jnp.stack([a0, i0]), (t, g, b, s), n_steps=n_iter).x

    def disturbance(ai, t, g):  # (3,) B_pred - C^T f at the solved attitude, nT
        C = tool_to_earth(ai[0], ai[1], t)
        b0 = C.T @ f_ned
        return _fx.apply_effects(params, C.T @ g_ned, b0, C)[1] - b0

    a0 = azimuth_from_gv(G, B) + dec
    i0 = inclination_from_g(G)
    ai = jax.vmap(solve)(T, G, B, sig, a0, i0)
    return jnp.mod(ai[:, 0], 360.0), ai[:, 1], B - jax.vmap(disturbance)(ai, T, G)
