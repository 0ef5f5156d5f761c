"""The fits: Levenberg-Marquardt over a free-parameter mask (:func:`icgo.maths.lsq.least_squares_fixed`), the
batched k-fold evaluation of candidate models, standard errors, and fixed models fitted one per member
(:func:`fit_members`, the generalisation study's physics baseline). The fitted model inverted per station
is :mod:`icgo.discrepancy.inversion`.

All residuals are measured - predicted (see :mod:`icgo.discrepancy.model`).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.discrepancy.inversion import PhysicsParams
from icgo.discrepancy.model import (
    Data,
    Layout,
    fitted_field,
    make_layout,
    physical_residuals,
    predict,
    prepare,
    residuals,
    station_blocks,
)
from icgo.discrepancy.noise import NOISE, Noise
from icgo.maths.lsq import gauss_newton_gap, least_squares_fixed
from icgo.physics.frames import azimuth_from_gv

#: Stations per block (stations) of the row-blocked fits, for the reference-attitude layout's
#: parameters (:func:`block_stations` scales it for more). Above this many stations a fit
#: accumulates its normal equations ``JᵀJ``, ``Jᵀr`` over blocks of ``ROW_BLOCK`` stations
#: (:func:`icgo.maths.lsq.least_squares_fixed` ``blocks``), the Jacobian at the full fit is kept as
#: its triangular factor (:func:`jacobian_r`, accumulated block by block) and the held-out
#: residuals are summed fold by fold, so memory holds one block's Jacobian per vmapped fit
#: (models x folds x 6 ROW_BLOCK x P float64: 40 x 6144 x 24 x 8 B = 47 MB, and its
#: forward-mode intermediates) plus a few (models, n, 6) per-station arrays, and time grows
#: linearly in stations. At or below it the unblocked code runs, unchanged.
ROW_BLOCK = 1024


def block_stations(layout: Layout) -> int:
    """Stations per row block for ``layout``: :data:`ROW_BLOCK` for the reference-attitude layout's
    parameters, proportionally fewer for a layout with more (2 per group), so a block's Jacobian
    (6 x stations x parameters, per vmapped fit) keeps its size whatever the number of groups."""
    ref = make_layout(0).n_params
    return max(8, ROW_BLOCK * ref // max(layout.n_params, ref))


# ============================================================ Levenberg-Marquardt
def _weighted_residuals(w, data: Data, layout: Layout, row_block: int):
    """(residual_fn, blocks) of the station-weighted, noise-normalized residuals for
    :func:`icgo.maths.lsq.least_squares_fixed` (``blocks`` None at or below ``row_block`` stations)."""
    if data.G.shape[0] <= row_block:
        sw = jnp.sqrt(w)[:, None]

        def res(th, _):
            r = residuals(th, data, layout) * sw
            return jnp.where(jnp.isfinite(r), r, 1e6).ravel()

        return res, None
    fields, (wb,), real = station_blocks(data, layout, row_block, w)

    def res_block(th, args_blk):
        fb, w_b, real_b = args_blk[1]
        r = residuals(th, data._replace(**fb), layout) * jnp.sqrt(w_b)[:, None]
        return (jnp.where(jnp.isfinite(r), r, 1e6) * real_b[:, None]).ravel()  # pads (real 0) drop out

    return res_block, (fields, wb, real)


def lm_fit(theta0, free, w, data: Data, layout: Layout, n_iter: int, row_block: int = ROW_BLOCK):
    """Weighted fit of the scaled parameters; only ``free`` parameters move.

    The station-weighted, noise-normalized residuals (non-finite components
    replaced by 1e6) minimized by :func:`icgo.maths.lsq.least_squares_fixed`
    (Marquardt-damped LM, a fixed number of steps in ``lax.scan``, so the
    vmapped models x folds all cost ``n_iter`` steps). Above ``row_block``
    stations the normal equations are accumulated over blocks of stations.

    Args:
        theta0: (P,) start (scaled parameters, see :class:`~icgo.discrepancy.model.Layout`).
        free: (P,) 0/1 or bool. w: (n,) station weights (0 = not used).
        n_iter: LM iterations (static). row_block: stations per block (static).
    Returns:
        (theta (P,), cost = sum of weighted squared noise-normalized residuals (),
        gap = :func:`icgo.maths.lsq.gauss_newton_gap` at theta (): 0 when converged).
    """
    res, blocks = _weighted_residuals(w, data, layout, row_block)
    out = least_squares_fixed(res, theta0, n_steps=n_iter, free=free, blocks=blocks)
    return out.x, out.cost, gauss_newton_gap(res, out.x, free=free, blocks=blocks)


def jacobian_r(theta, w, data: Data, layout: Layout, row_block: int = ROW_BLOCK):
    """The noise-weighted Jacobian of the weighted residuals at ``theta``, as its triangular factor.

    ``J = d (residuals * sqrt(w)) / d theta`` is (6n, P); what the identifiability analysis and the
    standard errors need of it is its column geometry (column norms, angles, ``JᵀJ``), which the
    (P, P) factor R of ``J = Q R`` has exactly, with ``RᵀR = JᵀJ`` (no squared condition number).
    R is accumulated over blocks of ``row_block`` stations (``R <- qr([R; J_b])``), so J is never
    held whole.

    Args:
        theta: (P,). w: (n,) station weights. row_block: stations per block (static).
    Returns:
        (P, P) upper-triangular R.
    """
    P = theta.shape[0]
    fields, (wb,), real = station_blocks(data, layout, row_block, w)

    def body(R, blk):
        fb, w_b, real_b = blk
        sw = (jnp.sqrt(w_b) * real_b)[:, None]
        J = jax.jacfwd(lambda t: (residuals(t, data._replace(**fb), layout) * sw).ravel())(theta)
        return jnp.linalg.qr(jnp.concatenate([R, J]), mode="r"), None

    return jax.lax.scan(body, jnp.zeros((P, P), theta.dtype), (fields, wb, real))[0]


# ============================================================ k-fold evaluation
class Evaluation(NamedTuple):
    """Every model fitted on every training fold and on all stations (a pytree).

    M models (rows of the mask stack), n stations, P parameters, K folds.

    Attributes:
        theta_full: (M, P) fit on all valid stations.
        cost_full: (M,) its sum of squared noise-normalized residuals.
        J_full: (M, 6n, P) noise-weighted Jacobian of the residuals at theta_full
            (all P columns, whatever the mask); above ``row_block`` stations its
            (M, P, P) triangular factor (:func:`jacobian_r`, ``RᵀR = JᵀJ``), which
            :func:`standard_errors` and the identifiability analysis take in its place.
        chi2_held: (M, n) held-out chi2 per station (each station scored by the
            fold that left it out).
        r_held: (M, n, 6) held-out residuals measured - predicted, g and nT.
        az_held: (M, n) held-out predicted azimuth, deg.
        theta_fold: (M, K, P) each fold's fit (before the group directions are refitted on all stations).
        gap: (M,) the largest :func:`icgo.maths.lsq.gauss_newton_gap` of the model's fits (folds, their
            group-direction refits, all stations): 0 when every fit converged.
        cost_total: (M,) the sum of the costs of all the model's fits (folds, refits, all stations): it can
            only fall when the fits go on from here (``starts``), so its fall measures their progress.
    """

    theta_full: jnp.ndarray
    cost_full: jnp.ndarray
    J_full: jnp.ndarray
    chi2_held: jnp.ndarray
    r_held: jnp.ndarray
    az_held: jnp.ndarray
    theta_fold: jnp.ndarray
    gap: jnp.ndarray
    cost_total: jnp.ndarray


@partial(jax.jit, static_argnames=("layout", "n_iter", "row_block"))
def evaluate_models(theta0, masks, train_w, test_w, valid_w, group_free, data: Data, layout: Layout,
                    n_iter: int, row_block: int | None = None, starts=None) -> Evaluation:
    """Fit every model on every training fold and on all stations, in one jitted call.

    Args:
        theta0: (P,) start. masks: (M, P) free parameters per model (0/1).
        train_w, test_w: (K, n) station weights of each fold. valid_w: (n,).
        group_free: (P,) the group-direction nuisances (re-fitted on all stations
            with the fold's global parameters fixed before held-out scoring).
        n_iter: LM iterations per fit (static).
        row_block: stations per block above which the fits and the held-out residuals run
            in row blocks (static; None: :func:`block_stations` of the layout).
        starts: None (every fit starts at ``theta0``) or ``(theta_fold (M, K, P), theta_full (M, P))``:
            the fits of an earlier evaluation, to go on from for another ``n_iter`` steps.
    Returns:
        :class:`Evaluation` (``vmap`` over models x folds).
    """
    row_block = block_stations(layout) if row_block is None else row_block
    M, K, P = masks.shape[0], train_w.shape[0], masks.shape[1]
    if starts is None:
        starts = (jnp.broadcast_to(theta0, (M, K, P)), jnp.broadcast_to(theta0, (M, P)))
    fit = lambda t0, m, w: lm_fit(t0, m, w, data, layout, n_iter, row_block)
    th_fold, cost_fold, gap_fold = jax.vmap(lambda t, m: jax.vmap(lambda t1, w: fit(t1, m, w))(t, train_w))(
        starts[0], masks)
    th_train = th_fold
    if layout.n_groups:
        refit = lambda th: lm_fit(th, group_free, valid_w, data, layout, n_iter, row_block)
        th_fold, cost_refit, gap_refit = jax.vmap(jax.vmap(refit))(th_fold)
        gap_fold = jnp.maximum(gap_fold, gap_refit)
        cost_fold = cost_fold + cost_refit
    th_full, cost_full, gap_full = jax.vmap(lambda t, m: fit(t, m, valid_w))(starts[1], masks)

    def heldout(th):  # (n, 6) residuals, (n,) azimuth pred, for one fit
        pred = predict(th, data, layout)
        return physical_residuals(pred, data), azimuth_from_gv(pred.G, pred.B)

    n = data.G.shape[0]
    if n <= row_block:
        r_fold, az_fold = jax.vmap(jax.vmap(heldout))(th_fold)  # (M, K, n, 6), (M, K, n)
        sel = test_w[None, :, :, None]
        r_held = jnp.sum(r_fold * sel, 1)
        az_held = jnp.sum(az_fold * test_w[None], 1)  # each station is held out in exactly one fold
    else:  # one model at a time, its folds summed one by one: (n, 6) at a time, never (M, K, n, 6)
        def held_one(th_k):
            def add_fold(acc, fold):
                r, az = heldout(fold[0])
                return (acc[0] + r * fold[1][:, None], acc[1] + az * fold[1]), None
            return jax.lax.scan(add_fold, (jnp.zeros((n, 6), data.G.dtype), jnp.zeros(n, data.G.dtype)),
                                (th_k, test_w))[0]

        r_held, az_held = jax.lax.map(held_one, th_fold)
    chi2_held = jnp.sum((r_held / data.sig) ** 2, -1)
    if n <= row_block:
        def jac(th):
            return jax.jacfwd(lambda t: (residuals(t, data, layout) * jnp.sqrt(valid_w)[:, None]).ravel())(th)

        J_full = jax.vmap(jac)(th_full)
    else:
        J_full = jax.vmap(lambda th: jacobian_r(th, valid_w, data, layout, row_block))(th_full)
    gap = jnp.maximum(jnp.max(gap_fold, axis=1), gap_full)
    return Evaluation(th_full, cost_full, J_full, chi2_held, r_held, az_held, th_train, gap,
                      jnp.sum(cost_fold, axis=1) + cost_full)


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
        J: (R, P) noise-weighted Jacobian at the fit, or its triangular factor
            (:func:`jacobian_r`, same result). free: (P,) 0/1 mask.
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


# ============================================================ fixed models, one per member
#: The physics baseline of the generalisation protocols: the 12-parameter magnetometer
#: model (bias, scale, cross-coupling, misalignment) with an earth-fixed external field.
TWELVE_PLUS_FIELD = ("hard_iron", "mag_scale", "mag_cross_coupling", "mag_misalignment", "external_field")


def fit_members(st, weights, effects=TWELVE_PLUS_FIELD, noise: Noise = NOISE, n_iter: int = 30) -> list:
    """Fit one fixed physics model per row-weight vector (no search): :func:`lm_fit` over ``effects``,
    vmapped over the members (one compile for every member).

    Args:
        st: :class:`icgo.discrepancy.stations.Stations` with a reference attitude.
        weights: (M, n) 0/1 station weights, one row per member (its training rows).
        effects: effect names (``icgo.physics.effects`` vocabulary) that are fitted.
        noise: residual weights (:class:`icgo.discrepancy.noise.Noise`).
        n_iter: LM steps (fixed; 30 reach the converged cost on the bundled data to 1e-9 relative).
    Returns:
        M :class:`~icgo.discrepancy.inversion.PhysicsParams`, each with the effects' parameters and the field
        (the metadata's field when the stations carry one, else the fitted one).
    """
    if not st.has_reference:
        raise ValueError("physics baseline: the stations need a reference attitude (azimuth_deg, inclination_deg)")
    prep = prepare(st, noise)
    layout = prep.layout
    free = prep.free_nuisance.astype(float)
    for e in effects:
        free[layout.slice(e)] = 1.0
    w = np.asarray(weights, float) * prep.valid[None]
    fit = jax.jit(jax.vmap(lambda wm: lm_fit(jnp.zeros(layout.n_params), jnp.asarray(free), wm, prep.data, layout,
                                             n_iter)[0]))
    thetas = np.asarray(fit(jnp.asarray(w)))
    scales = layout.scales()
    return [PhysicsParams({e: (th * scales)[layout.slice(e)] for e in effects},
                          np.asarray(fitted_field(th, layout, prep.data), float), float(noise.sigma_b_nT),
                          float(noise.sigma_g)) for th in thetas]
