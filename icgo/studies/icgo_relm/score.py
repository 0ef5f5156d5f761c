"""The ICGO-RELM study's scores (ICGO paper section 3.4, eq. 9 and eq. 21): the output weights refitted on all
training rows of every (strategy, repeat), the compensated azimuths predicted through the forward pass the saved model
applies (:func:`icgo.models.compensation.predict_methods`), and their test and training metrics.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from icgo.maths.metrics import azimuth_metrics
from icgo.models import relm_fit
from icgo.models.compensation import RELMParams, predict_methods
from icgo.physics.frames import wrap360
from icgo.studies.icgo_relm.prepare import Prepared


class Scored(NamedTuple):
    """Every (strategy, repeat) refitted, predicted and scored (:func:`score_all`)."""

    a_msa: jnp.ndarray      # (S, R, N) MSA azimuth, deg
    pred: jnp.ndarray       # (S, R, N) predicted error, deg
    a_comp: jnp.ndarray     # (S, R, N) compensated azimuth, deg
    test: Any               # Metrics (S, R)
    train: Any              # Metrics (S, R)
    params: RELMParams      # the fitted members (S strategies x R repeats) the saved model holds


@functools.partial(jax.jit, static_argnames=("hidden",))
def refit_all(thetas, prep: Prepared, lam, hidden):
    """Output weights beta (S, R, L) refitted on all training rows of each (strategy, repeat) (eq. 9; row blocks
    above :data:`icgo.models.relm.ROW_BLOCK` rows, so memory does not grow with strategies x rows x hidden)."""
    over_s = jax.vmap(lambda th, p: relm_fit.ridge_beta(th, p.data.X, p.target, lam, hidden, p.train), in_axes=(0, None))
    # lax.map over repeats for bitwise batch-size independence (see icgo_relm_prepare.prepare).
    return jnp.swapaxes(jax.lax.map(lambda tp: over_s(*tp), (jnp.swapaxes(thetas, 0, 1), prep)), 0, 1)


@jax.jit
def _metrics(a_comp, prep: Prepared, a_true):
    """Test and training metrics (S, R) of the compensated azimuths a_comp (S, R, N)."""
    def one(ap):
        a, p = ap
        return jax.vmap(lambda x: (azimuth_metrics(a_true, x, p.target, p.test),
                                   azimuth_metrics(a_true, x, p.target, p.train)))(a)

    test, train = jax.lax.map(one, (jnp.swapaxes(a_comp, 0, 1), prep._replace(data=None)))
    return jax.tree_util.tree_map(lambda x: jnp.swapaxes(x, 0, 1), (test, train))


def score_all(thetas, prep: Prepared, G, B, a_true, lam, hidden: int, raw_features: bool) -> Scored:
    """Refit, predict and score every (strategy, repeat).

    The predictions come from :func:`icgo.models.compensation.predict_methods` on the params the study saves
    (:attr:`Scored.params`), the forward pass its artifact applies, so a saved model reproduces them bitwise.

    Args:
        thetas: (S, R, 7 L) searched hidden weights. prep: the R repeats' :class:`Prepared`.
        G, B: (N, 3) the study's rows (g, nT). a_true: (N,) reference azimuth, deg.
        lam: ridge lambda. hidden: L. raw_features: the RELM reads (G, B), else (G, B_corr).
    """
    params = RELMParams(prep.msa.bias, prep.msa.scale, prep.x_mean, prep.x_std, thetas,
                        refit_all(thetas, prep, lam, hidden), int(hidden), bool(raw_features))
    a_msa, pred = predict_methods(params, jnp.concatenate([jnp.asarray(G), jnp.asarray(B)], axis=1))
    a_comp = wrap360(a_msa - pred)
    test, train = _metrics(a_comp, prep, jnp.asarray(a_true))
    return Scored(a_msa, pred, a_comp, test, train, params)
