"""A RELM fitted for chosen hidden weights, and its output on new rows (ICGO paper eqs. 8-9).

The search (:mod:`icgo.models.relm` and its kernels) only scores hidden weights; once they are chosen, the
output weights are refitted on all training rows: :func:`ridge_beta` (eq. 9 on standardised features) and
:func:`fit_output` (with the features' statistics). :func:`predict_rows` is the RELM's output ``H beta`` on
standardised features. All three hold at most :data:`icgo.models.relm.ROW_BLOCK` rows of hidden outputs
at a time, so memory stays flat in the number of rows; at or below it they are the unblocked products.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from icgo.models import relm


def ridge_beta(theta, Xs, T, lam, hidden: int, weights=None, row_block: int = relm.ROW_BLOCK):
    """Eq. (9) for hidden parameters ``theta``: :func:`icgo.models.relm.ridge_solve` of its hidden layer, in bounded memory.

    Up to ``row_block`` rows this is ``relm.ridge_solve(relm.hidden_layer(theta, Xs, hidden), T, lam, weights)``
    exactly; above, ``H^T diag(w) H`` and ``H^T diag(w) T`` are accumulated over row blocks of
    ``row_block`` rows (``lax.scan``, in the dtype of ``Xs``), so ``H`` (N, L) is never held whole.

    Args:
        theta: (7 L,) hidden parameters. Xs: (N, 6) standardised inputs. T: (N,) targets.
        lam: ridge lambda. hidden: L. weights: (N,) row weights or None.
        row_block: rows per block (static).
    Returns:
        beta (L,).
    """
    Xs = jnp.asarray(Xs)
    n = Xs.shape[0]
    if n <= row_block:
        return relm.ridge_solve(relm.hidden_layer(theta, Xs, hidden), T, lam, weights)
    dt = Xs.dtype
    w = jnp.ones(n, dt) if weights is None else jnp.asarray(weights, dt)
    Xb, Tb, wb, _ = relm.row_blocks(row_block, Xs, jnp.asarray(T, dt), w)

    def normal(x, t, w):  # this block's H^T diag(w) H (L, L) and H^T diag(w) T (L,)
        H = relm.hidden_layer(theta, x, hidden)
        Hw = H * w[:, None]
        return Hw.T @ H, Hw.T @ t

    A, b = relm.scan_sum(normal, (jnp.zeros((hidden, hidden), dt), jnp.zeros(hidden, dt)), (Xb, Tb, wb))
    c = jax.scipy.linalg.cho_factor(A + jnp.asarray(lam, dt) * jnp.eye(hidden, dtype=dt), lower=True)
    return jax.scipy.linalg.cho_solve(c, b)


def predict_rows(theta, beta, Xs, hidden: int, row_block: int = relm.ROW_BLOCK):
    """RELM output ``hidden_layer(theta, Xs) @ beta`` (N,) for standardised inputs, in bounded memory.

    Above ``row_block`` rows the hidden outputs are formed one block at a time (``lax.map``).

    Args:
        theta: (7 L,). beta: (L,). Xs: (N, 6) standardised inputs. hidden: L. row_block: rows per block.
    Returns:
        (N,) predictions.
    """
    Xs = jnp.asarray(Xs)
    n = Xs.shape[0]
    if n <= row_block:
        return relm.hidden_layer(theta, Xs, hidden) @ beta
    Xb, _ = relm.row_blocks(row_block, Xs)
    return jax.lax.map(lambda x: relm.hidden_layer(theta, x, hidden) @ beta, Xb).reshape(-1)[:n]


@partial(jax.jit, static_argnames=("hidden",))
def fit_output(theta, X, T, lam, weights, hidden: int):
    """A RELM's output weights for given hidden weights: the weighted feature statistics and the ridge fit.

    Jittable and vmappable, unchecked (:func:`icgo.models.compensation.fit` checks its inputs).

    Args:
        theta: ((d + 1) L,) hidden parameters. X: (N, d) raw features. T: (N,) targets.
        lam: ridge lambda. weights: (N,) row weights. hidden: L.
    Returns:
        (beta (L,), mean (d,), std (d,)): output weights (eq. 9, :func:`ridge_beta`) on the features standardised
        with the statistics of the rows of weight > 0 (:func:`icgo.models.relm.standardize_stats`).
    """
    mean, std = relm.standardize_stats(X, weights)
    return ridge_beta(theta, relm.standardize(X, mean, std), T, lam, hidden, weights), mean, std
