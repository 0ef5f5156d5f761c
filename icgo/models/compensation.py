"""The MSA + RELM azimuth compensation: one params pytree and one pure forward pass (ICGO paper section 3).

A fitted compensation is a :class:`RELMParams` pytree: the MSA biases and scale errors of each member's
training rows, its feature standardisation and its RELM (hidden weights ``theta``, output weights ``beta``),
with the RELM's size ``hidden`` and its input features (``raw_features``) as static settings.
:func:`predict` is its only forward pass; :func:`fit` fits one member's output weights (eq. 9, checked).
The study scores its fits through :func:`predict_methods` and the saved artifact
(:class:`icgo.artifacts.relm.RELMCompensation`) applies the same function to the same params, so "apply
reproduces the study" holds bitwise by construction: every member runs the same compiled program
(``lax.map`` over members and over fixed-size row blocks), whatever the number of members or rows.

Per member: ``B_corr = (B - eps) / (1 + s)`` (eq. 2), ``A_msa = A(G, B_corr)``, features ``X = (G, B)``
(``raw_features``, the paper) or ``(G, B_corr)``, standardised with the member's training statistics,
``H = sigmoid(Xs W + b)`` (eq. 8), predicted error ``H beta`` (deg); the compensated azimuth is
``A_msa - H beta``.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.models import msa as _msa
from icgo.models import relm as _relm
from icgo.models import relm_fit
from icgo.physics.frames import azimuth_from_gv

#: Survey rows per block of :func:`predict`: bounds its memory (one block x hidden units at a time) whatever
#: the survey's length, and fixes the program each block runs.
PREDICT_BLOCK_ROWS = 1024


@partial(jax.tree_util.register_dataclass,
         data_fields=("msa_bias", "msa_scale", "x_mean", "x_std", "theta", "beta"),
         meta_fields=("hidden", "raw_features"))
@dataclasses.dataclass(frozen=True)
class RELMParams:
    """A fitted MSA + RELM compensation (leading member axes on every array when batched).

    One member (no leading axis): msa_bias (3,) MSA biases eps, nT; msa_scale (3,) MSA scale errors s;
    x_mean, x_std (6,) feature standardisation (g, g, g, nT, nT, nT) from the member's training rows;
    theta (7 L,) hidden weights and biases (:func:`icgo.models.relm.unpack`); beta (L,) output weights, deg.
    :func:`predict` takes M members (a leading axis M on every array); :func:`predict_methods` takes the
    layout a study and its saved model hold: S methods x R repeats, the MSA and standardisation per repeat
    ((R, 3), (R, 6)) and the RELM per method and repeat (theta (S, R, 7 L), beta (S, R, L)).

    Static: hidden, the number of hidden units L; raw_features, whether the RELM reads the raw sensor
    values (G, B) (the paper) or (G, B_corr).
    """

    msa_bias: jnp.ndarray
    msa_scale: jnp.ndarray
    x_mean: jnp.ndarray
    x_std: jnp.ndarray
    theta: jnp.ndarray
    beta: jnp.ndarray
    hidden: int
    raw_features: bool = True


class Prediction(NamedTuple):
    """What :func:`predict` returns: (M, N) arrays, deg (:func:`predict_methods`: (S, R, N))."""

    a_msa: jnp.ndarray    # MSA-corrected azimuth
    error: jnp.ndarray    # predicted azimuth error of A_msa (the RELM's output)


@partial(jax.jit, static_argnames=("block_rows",))
def predict(params: RELMParams, x, *, block_rows: int = PREDICT_BLOCK_ROWS) -> Prediction:
    """Every member's MSA azimuth and predicted error on one survey.

    Args:
        params: M members (:class:`RELMParams` with a leading axis M on every array).
        x: (N, 6) sensor values Gx, Gy, Gz (g), Bx, By, Bz (nT).
        block_rows: rows per block (static).
    Returns:
        :class:`Prediction` of (M, N) arrays, deg; the compensated azimuth is ``wrap360(a_msa - error)``.
    """
    n = x.shape[0]
    Gb, Bb, _ = _relm.row_blocks(block_rows, x[:, :3], x[:, 3:])

    def member(p: RELMParams):
        def block(gb):
            g, b = gb
            b_corr = _msa.correct_field(b, p.msa_bias, p.msa_scale)
            X = jnp.concatenate([g, b if p.raw_features else b_corr], axis=1)
            Xs = _relm.standardize(X, p.x_mean, p.x_std)
            return azimuth_from_gv(g, b_corr), _relm.hidden_layer(p.theta, Xs, p.hidden) @ p.beta

        a, e = jax.lax.map(block, (Gb, Bb))
        return a.reshape(-1)[:n], e.reshape(-1)[:n]

    # lax.map, not vmap, over members and row blocks: one member's block is the same program whatever M and N
    # (a vmapped or longer matrix product may be reordered by XLA), so a study's member and the saved model agree
    # bitwise
    return Prediction(*jax.lax.map(member, params))


def members(params: RELMParams) -> RELMParams:
    """The S x R members of a (methods, repeats) params as one leading member axis of S R (method-major):
    every method of a repeat shares that repeat's MSA and standardisation."""
    S, R = params.theta.shape[:2]

    def per_member(a):
        return jnp.broadcast_to(a, (S, *a.shape)).reshape(S * R, *a.shape[1:])

    return dataclasses.replace(params, msa_bias=per_member(params.msa_bias), msa_scale=per_member(params.msa_scale),
                               x_mean=per_member(params.x_mean), x_std=per_member(params.x_std),
                               theta=params.theta.reshape(S * R, -1), beta=params.beta.reshape(S * R, -1))


def predict_methods(params: RELMParams, x, *, block_rows: int = PREDICT_BLOCK_ROWS) -> Prediction:
    """:func:`predict` of S methods x R repeats (the layout of :class:`RELMParams` a study and its model hold).

    Args:
        params: msa_bias, msa_scale (R, 3), x_mean, x_std (R, 6), theta (S, R, 7 L), beta (S, R, L).
        x: (N, 6) sensor values (g, nT). block_rows: rows per block.
    Returns:
        :class:`Prediction` of (S, R, N) arrays, deg.
    """
    S, R = params.theta.shape[:2]
    out = predict(members(jax.tree_util.tree_map(jnp.asarray, params)), jnp.asarray(x), block_rows=block_rows)
    return Prediction(*(a.reshape(S, R, -1) for a in out))


def _check_fit(x, target, lam, hidden, weights):
    """Checked float64 inputs of :func:`fit` (ValueError naming the bad one)."""
    x = np.asarray(x, dtype=float)
    target = np.asarray(target, dtype=float)
    if x.ndim != 2 or x.shape[1] != _relm.N_INPUTS:
        raise ValueError(f"relm: features must be (N, {_relm.N_INPUTS}); got {x.shape}")
    if target.shape != (x.shape[0],):
        raise ValueError(f"relm: targets must be ({x.shape[0]},) to match the features; got {target.shape}")
    if not (np.isfinite(x).all() and np.isfinite(target).all()):
        bad = np.argwhere(~np.isfinite(np.column_stack([x, target])))[0]
        raise ValueError(f"relm: non-finite value in the inputs at row {bad[0]}, column {bad[1]}")
    if not (np.isfinite(lam) and lam > 0):
        raise ValueError(f"relm: lambda must be > 0; got {lam}")
    if int(hidden) < 1:
        raise ValueError(f"relm: hidden size must be >= 1; got {hidden}")
    w = np.ones(x.shape[0]) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (x.shape[0],) or np.any(w < 0) or not np.isfinite(w).all():
        raise ValueError(f"relm: weights must be ({x.shape[0]},), finite, non-negative")
    n = int(np.count_nonzero(w))
    if n < hidden:
        raise ValueError(f"relm: {n} training rows for {hidden} hidden units; need at least as many rows as units")
    return x, target, w


def fit(theta, x, target, lam: float, hidden: int, weights=None, msa_bias=None, msa_scale=None,
        raw_features: bool = True) -> RELMParams:
    """One member fitted for given hidden weights (checked, float64): its feature statistics and the ridge
    output weights (eq. 9) on the rows with weight > 0.

    Args:
        theta: (7 L,) hidden parameters.
        x: (N, 6) sensor values Gx, Gy, Gz (g), Bx, By, Bz (nT). target: (N,) azimuth error to learn, deg.
        lam: ridge lambda > 0. hidden: L. weights: (N,) row weights (training mask) or None.
        msa_bias, msa_scale: (3,) the member's MSA correction (nT; dimensionless), zero when None (a RELM on
            the sensor values alone). raw_features: features (G, B) if True, else (G, B_corr).
    Returns:
        :class:`RELMParams` of one member (no leading axis).
    """
    x, target, w = _check_fit(x, target, lam, hidden, weights)
    theta = jnp.asarray(theta, jnp.float64)
    if theta.shape != (_relm.n_params(hidden),):
        raise ValueError(f"relm: theta must be ({_relm.n_params(hidden)},) for L = {hidden}; got {theta.shape}")
    bias = jnp.zeros(3) if msa_bias is None else jnp.asarray(msa_bias, jnp.float64)
    scale = jnp.zeros(3) if msa_scale is None else jnp.asarray(msa_scale, jnp.float64)
    B = x[:, 3:] if raw_features else np.asarray(_msa.correct_field(x[:, 3:], bias, scale))
    beta, mean, std = relm_fit.fit_output(theta, jnp.asarray(np.column_stack([x[:, :3], B])), jnp.asarray(target), lam,
                                       jnp.asarray(w), int(hidden))
    return RELMParams(bias, scale, mean, std, theta, beta, int(hidden), bool(raw_features))
