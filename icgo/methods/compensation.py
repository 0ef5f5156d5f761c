"""The MSA + RELM azimuth compensation as one pure function of its parameters (ICGO paper section 3).

A fitted compensation is a :class:`RELMParams` pytree with a leading member axis (one member per repeat,
or per repeat and fold, of a study); :func:`predict` is its only forward pass. The study scores its fits
through it and the saved artifact (:class:`icgo.models.relm.RELMCompensation`) applies it to new surveys,
so "apply reproduces the study" holds bitwise by construction: every member runs the same compiled
program (``lax.map`` over members and over fixed-size row blocks), whatever the number of members or rows.

Per member: ``B_corr = (B - eps) / (1 + s)`` (eq. 2), ``A_msa = A(G, B_corr)``, features ``X = (G, B)``
(``raw_features``, the paper) or ``(G, B_corr)``, standardised with the member's training statistics,
``H = sigmoid(Xs W + b)`` (eq. 8), predicted error ``H beta`` (deg); the compensated azimuth is
``A_msa - H beta``.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from icgo.methods import msa as _msa
from icgo.methods import relm as _relm
from icgo.physics.frames import azimuth_from_gv

#: Survey rows per block of :func:`predict`: bounds its memory (one block x hidden units at a time) whatever
#: the survey's length, and fixes the program each block runs.
PREDICT_BLOCK_ROWS = 1024


class RELMParams(NamedTuple):
    """Parameters of M fitted MSA + RELM members (leading axis M on every field).

    msa_bias: (M, 3) MSA biases eps, nT. msa_scale: (M, 3) MSA scale errors s.
    x_mean, x_std: (M, 6) feature standardisation (g, g, g, nT, nT, nT) from the member's training rows.
    theta: (M, 7 L) hidden weights and biases. beta: (M, L) output weights, deg.
    """

    msa_bias: jnp.ndarray
    msa_scale: jnp.ndarray
    x_mean: jnp.ndarray
    x_std: jnp.ndarray
    theta: jnp.ndarray
    beta: jnp.ndarray


class Prediction(NamedTuple):
    """What :func:`predict` returns: (M, N) arrays, deg."""

    a_msa: jnp.ndarray    # MSA-corrected azimuth
    error: jnp.ndarray    # predicted azimuth error of A_msa (the RELM's output)


@partial(jax.jit, static_argnames=("hidden", "raw_features", "block_rows"))
def predict(params: RELMParams, G, B, *, hidden: int, raw_features: bool,
            block_rows: int = PREDICT_BLOCK_ROWS) -> Prediction:
    """Every member's MSA azimuth and predicted error on one survey.

    Args:
        params: M members (:class:`RELMParams`).
        G: (N, 3) accelerometer, g. B: (N, 3) magnetometer, nT.
        hidden: L. raw_features: features (G, B) if True, else (G, B_corr).
        block_rows: rows per block (static).
    Returns:
        :class:`Prediction` of (M, N) arrays, deg; the compensated azimuth is ``wrap360(a_msa - error)``.
    """
    n = G.shape[0]
    Gb, Bb, _ = _relm.row_blocks(block_rows, G, B)

    def member(p: RELMParams):
        def block(gb):
            g, b = gb
            b_corr = _msa.correct_field(b, p.msa_bias, p.msa_scale)
            X = jnp.concatenate([g, b if raw_features else b_corr], axis=1)
            Xs = _relm.standardize(X, p.x_mean, p.x_std)
            return azimuth_from_gv(g, b_corr), _relm.hidden_layer(p.theta, Xs, hidden) @ p.beta

        a, e = jax.lax.map(block, (Gb, Bb))
        return a.reshape(-1)[:n], e.reshape(-1)[:n]

    # lax.map, not vmap, over members and row blocks: one member's block is the same program whatever M and N
    # (a vmapped or longer matrix product may be reordered by XLA), so a study's member and the saved model agree
    # bitwise
    return Prediction(*jax.lax.map(member, params))
