"""The fitted physics model inverted per station: a :class:`PhysicsParams` pytree and its pure :func:`predict`.

A fitted physics model is the workflow's named effects with their physical parameters, the fitted earth
field and the residual weights (:class:`PhysicsParams`; :func:`physics_params` of a workflow result).
:func:`predict` inverts it on measured stations: per station the attitude (A, I) that best explains the
measured (G, B), toolface from G with the model's accelerometer effects removed, and the measured field
with the fitted disturbance removed. The lab_casing study scores the workflow through it and the saved
model (:class:`icgo.artifacts.discrepancy.PhysicsModel`) applies it.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

from icgo.discrepancy.model import remove_accel_effects
from icgo.discrepancy.noise import Noise, effective_sigma
from icgo.maths.lsq import least_squares_fixed
from icgo.physics import effects as _fx
from icgo.physics.frames import azimuth_from_gv, field_vector_ned, inclination_from_g, tool_to_earth, toolface_from_g

#: Levenberg-Marquardt steps of the per-station inversion of a workflow's model.
N_ITER = 10


@partial(jax.tree_util.register_dataclass, data_fields=("effects", "field"),
         meta_fields=("sigma_b_nT", "sigma_g", "n_iter"))
@dataclasses.dataclass(frozen=True)
class PhysicsParams:
    """A fitted physics model as :func:`predict` takes it (a pytree).

    Attributes:
        effects: effect name -> (n_params,) physical parameters (units per effect: :mod:`icgo.physics.effects`).
        field: (3,) the earth field: total nT, dip deg, declination deg.
        sigma_b_nT, sigma_g: the residual weights (sensor noise, 1 sigma per axis, nT and g), static.
        n_iter: Levenberg-Marquardt steps of the per-station inversion, static.
    """

    effects: dict
    field: jnp.ndarray
    sigma_b_nT: float
    sigma_g: float
    n_iter: int = N_ITER


class Inversion(NamedTuple):
    """Per station, what the inverted physics model says (:func:`predict`).

    Attributes:
        azimuth: (n,) deg in the frame of the fitted declination. inclination: (n,) deg.
        b_corrected: (n, 3) nT, the measured field with the model's fitted disturbance removed:
            ``B_meas - (B_pred - C^T f)`` at the solved attitude ``C`` (f the earth field, NED), i.e.
            the earth field in the tool frame plus what the model leaves unexplained.
    """

    azimuth: jnp.ndarray
    inclination: jnp.ndarray
    b_corrected: jnp.ndarray


def physics_params(res, n_iter: int = N_ITER) -> PhysicsParams:
    """The fitted physics model of a workflow result (:class:`icgo.discrepancy.search.Result`): the effects of
    its final model, its fitted field and its configured noise."""
    phys = res.theta * res.layout.scales()
    return PhysicsParams({nm: phys[res.layout.slice(nm)] for nm in res.model}, jnp.asarray(res.field, float),
                         float(res.config.sigma_b_nT), float(res.config.sigma_g), int(n_iter))


def predict(params: PhysicsParams, sensors) -> Inversion:
    """Invert the fitted model: the attitude that best explains each measured station.

    Per station, (A, I) (toolface from G with the model's accelerometer effects removed) minimizing the
    noise-weighted residual of the fitted forward model (:func:`icgo.physics.effects.apply_effects`), started
    from the raw attitude, by :func:`icgo.maths.lsq.least_squares_fixed` (Marquardt-damped LM, ``n_iter``
    steps, vmapped over stations). The gravity magnitude is the stations' mean |G|.

    Pure, jit- and vmap-able; the study and the saved model call it as it is: the field vector and the
    weights op by op, the inversion as one compiled program (:func:`_invert`), which fixes the rounding of
    every result (a jit around the whole may fuse operations and differ in the last bits).

    Args:
        params: :class:`PhysicsParams`.
        sensors: (n, 6) measured ``gx, gy, gz`` (g) and ``bx, by, bz`` (nT).
    Returns:
        :class:`Inversion`.
    """
    sensors = jnp.asarray(sensors)
    G, B = sensors[:, :3], sensors[:, 3:]
    F, dip, dec = params.field[0], params.field[1], params.field[2]
    f_ned = field_vector_ned(F, dip, dec)
    sig = effective_sigma(G, B, Noise(params.sigma_b_nT, params.sigma_g))
    return Inversion(*_invert(params.effects, G, B, sig, f_ned, dec, params.n_iter))


@partial(jax.jit, static_argnames=("n_iter",))
def _invert(effects, G, B, sig, f_ned, dec, n_iter):
    """(azimuth (n,) deg, inclination (n,) deg, corrected field (n, 3) nT) of :func:`predict`."""
    T = toolface_from_g(remove_accel_effects(effects, G))
    g_ned = jnp.array([0.0, 0.0, 1.0]) * jnp.linalg.norm(G, axis=1).mean()

    def res1(ai, tgbs):  # (6,) measured - predicted, noise units
        t, g, b, s = tgbs
        C = tool_to_earth(ai[0], ai[1], t)
        Gp, Bp = _fx.apply_effects(effects, C.T @ g_ned, C.T @ f_ned, C)
        return jnp.concatenate([g - Gp, b - Bp]) / s

    def solve(t, g, b, s, a0, i0):
        return least_squares_fixed(res1, jnp.stack([a0, i0]), (t, g, b, s), n_steps=n_iter).x

    def disturbance(ai, t):  # (3,) B_pred - C^T f at the solved attitude, nT
        C = tool_to_earth(ai[0], ai[1], t)
        b0 = C.T @ f_ned
        return _fx.apply_effects(effects, C.T @ g_ned, b0, C)[1] - b0

    a0 = azimuth_from_gv(G, B) + dec
    i0 = inclination_from_g(G)
    ai = jax.vmap(solve)(T, G, B, sig, a0, i0)
    return jnp.mod(ai[:, 0], 360.0), ai[:, 1], B - jax.vmap(disturbance)(ai, T)
