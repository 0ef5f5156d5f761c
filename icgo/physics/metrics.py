"""Azimuth error metrics: MAE, RMSE, R^2 (ICGO paper eqs. 19-21) with angle wrapping.

Every difference of two azimuths is wrapped to (-180, 180] before it is used
(:func:`icgo.physics.frames.angle_diff`), so 359 deg vs 1 deg is an error of 2 deg.

Eq. (21) is printed without squares, ``1 - sum(A - A_hat) / sum(A - A_bar)``,
which is 0/0-like and cannot give the paper's 0.866-0.9994; we read it as the
usual coefficient of determination with squared sums. ``A_bar`` is the
arithmetic mean of the true azimuths as given (deg in [0, 360)), the paper's
reading. That R^2 is inflated by the spread of the azimuths (30 to 330 deg in
the paper's data): it is ~0.87 for errors of ~0.6 deg. :func:`r2_error` is the
honest figure: the share of the variance of the *error* before compensation
that the compensation removes.

All functions take optional row weights (a 0/1 test mask), so they stay
jittable and vmappable over repeats with fixed shapes.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from icgo.physics.frames import angle_diff


def _w(x, weights):
    return jnp.ones_like(x) if weights is None else jnp.asarray(weights, x.dtype)


def _wmean(x, w):
    return jnp.sum(w * x, -1) / jnp.sum(w, -1)


def mae(a_true_deg, a_est_deg, weights=None):
    """Eq. (19): mean |wrap(A - A_hat)| (deg); arrays (..., N)."""
    e = angle_diff(a_true_deg, a_est_deg)
    return _wmean(jnp.abs(e), _w(e, weights))


def rmse(a_true_deg, a_est_deg, weights=None):
    """Eq. (20): sqrt(mean wrap(A - A_hat)^2) (deg); arrays (..., N)."""
    e = angle_diff(a_true_deg, a_est_deg)
    return jnp.sqrt(_wmean(e * e, _w(e, weights)))


def r2(a_true_deg, a_est_deg, weights=None):
    """Eq. (21) with squares: 1 - sum wrap(A - A_hat)^2 / sum (A - mean A)^2; arrays (..., N)."""
    a = jnp.asarray(a_true_deg)
    e = angle_diff(a, a_est_deg)
    w = _w(e, weights)
    abar = _wmean(a, w)[..., None]
    return 1.0 - jnp.sum(w * e * e, -1) / jnp.sum(w * (a - abar) ** 2, -1)


def r2_error(err_before_deg, err_after_deg, weights=None):
    """R^2 of the error model: 1 - sum e_after^2 / sum (e_before - mean e_before)^2.

    Args:
        err_before_deg: (..., N) azimuth error before compensation (the model's
            target), deg.
        err_after_deg: (..., N) azimuth error after compensation (target minus
            prediction, wrapped), deg.
        weights: (..., N) row weights or None.
    """
    eb = jnp.asarray(err_before_deg)
    ea = jnp.asarray(err_after_deg)
    w = _w(eb, weights)
    mb = _wmean(eb, w)[..., None]
    return 1.0 - jnp.sum(w * ea * ea, -1) / jnp.sum(w * (eb - mb) ** 2, -1)


class Metrics(NamedTuple):
    """MAE, RMSE (deg), R^2 of azimuth (eq. 21) and R^2 of the error; each (...)."""

    mae: jnp.ndarray
    rmse: jnp.ndarray
    r2: jnp.ndarray
    r2_error: jnp.ndarray


def azimuth_metrics(a_true_deg, a_comp_deg, err_before_deg, weights=None) -> Metrics:
    """All four metrics of a compensated azimuth.

    Args:
        a_true_deg: (..., N) reference azimuth, deg.
        a_comp_deg: (..., N) compensated azimuth, deg.
        err_before_deg: (..., N) error before compensation (e.g. after MSA), deg.
        weights: (..., N) row weights (test mask) or None.
    Returns:
        Metrics.
    """
    after = angle_diff(a_comp_deg, a_true_deg)
    return Metrics(mae(a_true_deg, a_comp_deg, weights), rmse(a_true_deg, a_comp_deg, weights),
                   r2(a_true_deg, a_comp_deg, weights), r2_error(err_before_deg, after, weights))
