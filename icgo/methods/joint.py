"""The joint calibration: accelerometer and magnetometer fitted together, regularised toward small accelerometer errors.

Both sensors' 12 parameters (``G_c = S (G - c)``, ``B_c = M (B - b)``, unit spheres, eq. 4 for each) are
fitted together on grouped static shots. Per shot, the residuals (:func:`residuals`) are

* its pointing direction (:func:`icgo.methods.calibration.pointing_directions`) minus its roll's mean
  direction (3 components, rad; 0 for a single shot): the rolls' group consistency, the peer's metric;
* its ``G_c . B_c / (|G_c| |B_c|)`` minus the mean over the fitting shots (eq. 5: one dip);
* ``|G_c| - 1`` and ``|B_c| - 1`` (one gravity, one field strength).

Freed completely, the 24 parameters over-fit the two rolls of a 24-shot recording (the first build: 0.256 deg
in-sample, 0.577 held out on the bundled devices; 0.408 / 0.792 on unseen devices). So the fit starts from
``twelve+axis`` (the accelerometer's ellipsoid fit and the 12-parameter magnetometer fit, both turned onto the
rolls' axis, :func:`icgo.methods.calibration.align_to_axis`) and **the accelerometer may leave its start only
by physically small amounts**: the penalty ``lambda (|S - S_0|^2 / SIGMA_S^2 + |c - c_0|^2 / SIGMA_C^2)``
with :data:`SIGMA_S` (1 % per matrix entry: consumer MEMS gain and cross-axis errors after an ellipsoid fit)
and :data:`SIGMA_C` (10 mg). The magnetometer is free (a weak ridge of 1e-5 in scaled variables, as before,
holds the one direction no residual sees: both sensors turned together about the pointing axis).

**The strength ``lambda`` is chosen by leave-one-group-out on the training shots only** (as the residual RELM,
:mod:`icgo.methods.mag_relm`): each group (every single shot, every roll) is left out in turn, the joint fit
made on the rest, and the same residuals scored on the left-out shots (a roll's spread about its own mean,
a single shot's dip and moduli against the fitting shots' field). The chosen ``lambda`` minimises their mean
square over :data:`LAMBDAS`; all ``len(LAMBDAS) x (groups + 1)`` fits run as one vmapped batch of
:func:`icgo.maths.lsq.least_squares_fixed`, :data:`N_STEPS` steps from the start (more change no chosen
``lambda`` or score on the bundled devices, :data:`N_STEPS`). ``lambda`` is in rad^2 per unit of the
penalty (a residual of 1 rad costs as much as one sigma of accelerometer error at ``lambda = 1``).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.maths.lsq import gauss_newton_gap, least_squares_fixed
from icgo.methods.calibration import MIN_ROLLED_SHOTS, correct, normalized_dot, pointing_jnp

#: Prior scale of the accelerometer matrix's change from its start, per entry (dimensionless).
SIGMA_S = 0.01
#: ... of its bias, g.
SIGMA_C = 0.01
#: Candidate strengths (rad^2 per unit penalty), chosen among by leave-one-group-out. 1e-6 leaves the
#: accelerometer nearly free (the unregularised joint fit), 1e2 holds it at its start.
LAMBDAS = tuple(float(v) for v in 10.0 ** np.arange(-6.0, 2.01, 1.0))
#: Levenberg-Marquardt steps per fit (from the twelve+axis start). On the 9 bundled devices x 3 splits, 20
#: and 40 steps choose the same strengths and give the same scores to 1e-15 deg (10 steps: 1e-10 deg); the
#: chosen fit's Gauss-Newton gap is recorded in the model's header.
N_STEPS = 20
#: Weak ridge on every scaled variable (holds the common roll of both sensors about the pointing axis).
RIDGE = 1e-5


class Joint(NamedTuple):
    """A fitted joint calibration.

    Attributes:
        xg: (12,) accelerometer ``[S, c]``. xm: (12,) magnetometer ``[M, b]`` (unit sphere, b raw nT).
        lam: the chosen strength. cv: (len(LAMBDAS),) leave-one-group-out mean square residual per strength.
        gap: :func:`icgo.maths.lsq.gauss_newton_gap` of the chosen fit (0 when converged).
    """

    xg: np.ndarray
    xm: np.ndarray
    lam: float
    cv: np.ndarray
    gap: float


def residuals(x, G, B, member, fit_w):
    """Per-shot residuals (N, 6) of the calibration ``x = [S, c, M, b]`` (24,): pointing deviation from the
    roll's mean (3, rad; 0 for single shots), dot deviation from the fitting shots' mean, ``|G_c| - 1``,
    ``|B_c| - 1``.

    Args:
        x: (24,). G, B: (N, 3) raw shots. member: (K, N) 0/1 shot n in roll k (the roll's training shots).
        fit_w: (N,) 0/1 the shots whose mean dot product is the reference.
    """
    Gc, Bc = correct(x[:12], G), correct(x[12:], B)
    d = pointing_jnp(Gc, Bc)
    mean = (member @ d) / jnp.maximum(member.sum(1, keepdims=True), 1.0)
    dev = (d - member.T @ mean) * member.sum(0)[:, None]
    c = normalized_dot(Gc, Bc)
    c_dev = c - jnp.sum(fit_w * c) / jnp.sum(fit_w)
    return jnp.concatenate([dev, c_dev[:, None], (jnp.linalg.norm(Gc, axis=1) - 1.0)[:, None],
                            (jnp.linalg.norm(Bc, axis=1) - 1.0)[:, None]], 1)


def _fit_one(lam, fit_w, held_w, u0, scale, G, B, member, n_steps):
    """One fit from ``u0`` (scaled) on the ``fit_w`` shots: x (24,), the ``held_w`` shots' sum of squares, its
    Gauss-Newton gap."""
    prior = jnp.concatenate([jnp.full(9, 1.0 / SIGMA_S), jnp.full(3, 1.0 / SIGMA_C)])

    def res(u, _):
        x = u * scale
        r = residuals(x, G, B, member, fit_w) * fit_w[:, None]
        pen = jnp.sqrt(lam) * (x[:12] - u0[:12] * scale[:12]) * prior
        return jnp.concatenate([r.ravel(), pen, RIDGE * (u[:12] - u0[:12])])

    free = jnp.arange(24) < 12  # the accelerometer; the magnetometer stays at its start (the staged fit)
    u = least_squares_fixed(res, u0, n_steps=n_steps, free=free).x
    x = u * scale
    held = residuals(x, G, B, member, fit_w) * held_w[:, None]
    return x, jnp.sum(held ** 2), gauss_newton_gap(res, u, free=free)


@partial(jax.jit, static_argnames="n_steps")
def _fit_batch(lambdas, fit_w, held_w, u0, scale, G, B, member, n_steps):
    """:func:`_fit_one` for every strength (R,) x fold (F, N): x (R, F, 24), held (R, F), gap (R, F)."""
    one = partial(_fit_one, n_steps=n_steps)
    folds = jax.vmap(one, in_axes=(None, 0, 0, None, None, None, None, None))
    return jax.vmap(folds, in_axes=(0, None, None, None, None, None, None, None))(
        lambdas, fit_w, held_w, u0, scale, G, B, member)


def fit(G, B, groups, train, xg0, xm0, lambdas=LAMBDAS, n_steps: int = N_STEPS) -> Joint:
    """The regularised joint fit on the ``train`` shots, its strength by leave-one-group-out.

    Args:
        G, B: (N, 3) raw shots (g, nT), all of the recording (the held-out ones get zero weight).
        groups: (N,) group ids (groups of at least MIN_ROLLED_SHOTS training shots are rolls).
        train: (N,) bool, the training shots.
        xg0, xm0: (12,) the start: twelve+axis's accelerometer and magnetometer with its rotation folded in.
        lambdas: candidate strengths. n_steps: LM steps per fit (static).
    Returns:
        :class:`Joint`.
    Raises:
        ValueError: no roll among the training shots, or a fit that is not finite.
    """
    groups = np.asarray(groups)
    train = np.asarray(train, bool)
    if not any((train & (groups == g)).sum() >= MIN_ROLLED_SHOTS for g in np.unique(groups)):
        raise ValueError(f"joint fit: no roll ({MIN_ROLLED_SHOTS} or more shots) among the training shots")
    # one roll row and one fold per group of the whole recording, so that every split has the same shapes
    # (a held-out roll's row is all zero)
    member = np.array([train & (groups == g) for g in np.unique(groups) if (groups == g).sum() >= MIN_ROLLED_SHOTS],
                      np.float64)
    all_ids = np.unique(groups)
    fit_w = np.array([train] + [train & (groups != g) for g in all_ids], np.float64)
    held_w = np.array([np.zeros(len(groups))] + [train & (groups == g) for g in all_ids], np.float64)
    x0 = np.concatenate([np.asarray(xg0, np.float64), np.asarray(xm0, np.float64)])
    scale = np.concatenate([np.full(9, np.abs(x0[:9]).max()), np.full(3, 1.0 / np.abs(x0[:9]).max()),
                            np.full(9, np.abs(x0[12:21]).max()), np.full(3, 1.0 / np.abs(x0[12:21]).max())])
    x, held, gap = _fit_batch(jnp.asarray(lambdas, jnp.float64), jnp.asarray(fit_w), jnp.asarray(held_w),
                               jnp.asarray(x0 / scale), jnp.asarray(scale), jnp.asarray(G, jnp.float64),
                               jnp.asarray(B, jnp.float64), jnp.asarray(member), n_steps=n_steps)
    cv = np.asarray(held[:, 1:].sum(1)) / int(train.sum())
    if not np.all(np.isfinite(cv)) or not np.all(np.isfinite(np.asarray(x[:, 0]))):
        raise ValueError("joint fit: a leave-one-group-out fit is not finite")
    k = int(np.argmin(cv))
    xk = np.asarray(x[k, 0])
    return Joint(xk[:12], xk[12:], float(lambdas[k]), cv, float(gap[k, 0]))
