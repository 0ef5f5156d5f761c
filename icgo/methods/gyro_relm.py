"""A RELM compensating the gyro inclinometer's azimuth (ICGO paper eqs. 8-9 on the patent's inputs).

The RELM of :mod:`icgo.methods.relm` learns the wrapped azimuth error ``A_true - A_raw`` from the
instrument's own solution (I, T, A_raw), encoded as the patent network's inputs
(:func:`icgo.methods.nets.encode_inputs`). A fitted one is a :class:`GyroRELMParams` pytree and
:func:`predict` its whole forward pass: encode, standardise, hidden layer (eq. 8), output weights,
``wrap360(A_raw + error)``.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp

from icgo.methods import relm
from icgo.methods.nets import encode_inputs
from icgo.physics.frames import wrap360


@partial(jax.tree_util.register_dataclass, data_fields=("theta", "beta", "mean", "std"), meta_fields=("encoding",))
@dataclasses.dataclass(frozen=True)
class GyroRELMParams:
    """A fitted RELM on the encoded (I, T, A_raw) (a leading seed axis S on every array when batched).

    Attributes:
        theta: ((n_in + 1) L,) hidden weights and biases. beta: (L,) output weights, deg.
        mean, std: (n_in,) input standardisation (encoded units) from the training points.
        encoding: the input encoding (:data:`icgo.methods.nets.ENCODINGS`), static.
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
    error = relm.predict(relm.RELM(params.theta, params.beta, params.mean, params.std), x)
    return wrap360(angles[:, 2] + error)


#: :func:`predict` of S RELMs (params with a leading seed axis) on the same points: (S, N) deg.
predict_seeds = jax.vmap(predict, in_axes=(0, None))
