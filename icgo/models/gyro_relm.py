"""A RELM compensating the gyro inclinometer's azimuth (ICGO paper eqs. 8-9 on the patent's inputs).

The RELM of :mod:`icgo.models.relm` learns the wrapped azimuth error ``A_true - A_raw`` from the
instrument's own solution (I, T, A_raw), encoded as the patent network's inputs
(:func:`icgo.models.nets.encode_inputs`). A fitted one is a :class:`GyroRELMParams` pytree and
:func:`predict` its whole forward pass: encode, standardise, hidden layer (eq. 8), output weights,
``wrap360(A_raw + error)``. Fitting, all seeds in one call each: the per-seed fitness data
(:func:`fit_data`), hidden weights drawn (:func:`random_theta`, plain RELM) or searched by a population
optimizer (:func:`search_theta`, ICGO-RELM), then the ridge output weights (:func:`refit`, eq. 9).
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from icgo.models import relm, relm_fit, search_fitness
from icgo.models.nets import encode_inputs
from icgo.physics.frames import wrap360


@partial(jax.tree_util.register_dataclass, data_fields=("theta", "beta", "mean", "std"), meta_fields=("encoding",))
@dataclasses.dataclass(frozen=True)
class GyroRELMParams:
    """A fitted RELM on the encoded (I, T, A_raw) (a leading seed axis S on every array when batched).

    Attributes:
        theta: ((n_in + 1) L,) hidden weights and biases. beta: (L,) output weights, deg.
        mean, std: (n_in,) input standardisation (encoded units) from the training points.
        encoding: the input encoding (:data:`icgo.models.nets.ENCODINGS`), static.
    """

    theta: jnp.ndarray
    beta: jnp.ndarray
    mean: jnp.ndarray
    std: jnp.ndarray
    encoding: str = "scaled"


def predict(params: GyroRELMParams, angles):
    """Compensated azimuth ``wrap360(A_raw + predicted error)`` of one fitted RELM, deg in [0, 360).

    Jit- and vmap-able; the study and the saved model call it as it is (:func:`predict_seeds`), op by op,
    which fixes the rounding of every prediction (a jit around the whole may fuse operations and differ in
    the last bits).

    Args:
        params: :class:`GyroRELMParams` of one RELM (no seed axis).
        angles: (N, 3) measured inclination I, toolface T and computed azimuth A_raw, deg.
    Returns:
        (N,) compensated azimuth, deg.
    """
    x = encode_inputs(angles[:, 0], angles[:, 1], angles[:, 2], params.encoding)
    error = relm_fit.predict_rows(params.theta, params.beta, relm.standardize(x, params.mean, params.std),
                                  params.beta.shape[-1])
    return wrap360(angles[:, 2] + error)


#: :func:`predict` of S RELMs (params with a leading seed axis) on the same points: (S, N) deg.
predict_seeds = jax.vmap(predict, in_axes=(0, None))


def fit_data(keys, X, T, fitness: str):
    """Per-seed RELM fitness data (:class:`icgo.models.relm.FitData`) on all training points.

    Inputs are standardised with the training statistics (:func:`icgo.models.relm.standardize_stats`);
    the folds of the fitness mode (:data:`icgo.models.relm.FITNESS_MODES`) are drawn from each seed's key.

    Args:
        keys: (S, 2) per-seed keys. X: (N, n_in) encoded inputs. T: (N,) targets, deg. fitness: the mode.
    Returns:
        (FitData with leading axis S, theta keys (S, 2)).
    """
    S = keys.shape[0]
    w = jnp.ones(X.shape[0])
    k_theta, k_fold = jax.vmap(lambda k: jax.random.split(k, 2))(keys).transpose(1, 0, 2)
    mean, std = relm.standardize_stats(X, w)
    Xs = relm.standardize(X, mean, std)
    fw, sw = jax.vmap(lambda k: relm.fold_weights(k, w, fitness))(k_fold)
    data = relm.FitData(jnp.broadcast_to(Xs, (S,) + Xs.shape), jnp.broadcast_to(T, (S,) + T.shape), fw, sw)
    return data, k_theta


def random_theta(k_theta, data: relm.FitData, hidden: int, lam: float, bounds: tuple):
    """Plain RELM: theta ~ U(bounds) per seed and its training fitness (RMSE, deg); ((S, D), (S,))."""
    lo, hi = bounds
    n_in = data.X.shape[-1]
    theta = jax.vmap(lambda k: relm.random_theta(k, hidden, (), lo, hi, n_inputs=n_in))(k_theta)
    best_f = jax.vmap(lambda th, d: relm.fitness(th[None], d, lam, hidden)[0])(theta, data)
    return theta, best_f


def search_theta(keys, data: relm.FitData, hidden: int, lam: float, bounds: tuple, optimizer, configs,
                 pop_size: int, iterations: int):
    """Hidden weights searched by a population optimizer on the RELM fitness, all seeds in one call.

    Args:
        keys: (S, 2) per-seed keys. data: :func:`fit_data`. hidden: L. lam: ridge lambda. bounds: (low, high)
            of every weight. optimizer: an :mod:`icgo.optim` optimizer; configs: its ``run_batch`` configs (one
            value on its side-by-side axis) or None. pop_size, iterations: the search budget.
    Returns:
        (theta (S, (n_in + 1) L), best fitness (S,) deg).
    """
    from icgo.optim import run_batch

    D = relm.n_params(hidden, data.X.shape[-1])
    aux = search_fitness.SearchData(data, np.full(keys.shape[:1], lam, data.X.dtype), hidden)
    res = run_batch(optimizer, search_fitness.search_fitness, (np.full(D, bounds[0]), np.full(D, bounds[1])), keys,
                    pop_size, iterations, configs=configs, aux=aux)
    if configs is not None:  # one value on the side-by-side axis: drop that axis
        res = jax.tree_util.tree_map(lambda x: x[0], res)
    return res.best_x, res.best_f


def refit(theta, X, T, lam: float, hidden: int, encoding: str) -> GyroRELMParams:
    """The fitted RELMs of hidden weights ``theta`` (S, D): ridge output weights (eq. 9) and input statistics on
    all training points (:func:`icgo.models.relm_fit.fit_output`), as :class:`GyroRELMParams` with seed axis S."""
    w = jnp.ones(X.shape[0])
    beta, mean, std = jax.vmap(lambda th: relm_fit.fit_output(th, X, T, lam, w, hidden))(theta)
    return GyroRELMParams(theta, beta, mean, std, encoding=encoding)
