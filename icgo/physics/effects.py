"""The named physical effects (DESIGN.md vocabulary): one source of truth.

Every effect acts on ideal tool-frame sensor vectors ``G`` (g) and ``B`` (nT)
given the tool-to-earth rotation ``C`` of each station (``icgo.physics.frames.tool_to_earth``):

    G_meas, B_meas = effect.apply(params, G, B, C)

``params`` is a flat (n_params,) array in the units listed in ``Effect.units``.
All ``apply`` functions are pure, jittable, vmappable and differentiable in
``params``. Effects compose through :func:`apply_effects`, which applies them in
the fixed physical order of :data:`ORDER`, whatever order they are given in:

1. ``external_field``: an earth-fixed field adds to the earth's field before the
   sensor sees it;
2. the magnetometer matrix effects (``mag_cross_coupling``, ``mag_scale``,
   ``mag_misalignment``) act on the total field at the sensor;
3. ``hard_iron`` adds after the matrix, so that together they form the usual
   12-parameter model ``B_meas = R B_true + b``;
4. ``accel_scale`` then ``accel_bias``: ``G_meas = (I + diag s) G + b_g``.

``magnetic_body`` (after ``external_field``) is a field fixed in the lab whose value depends on where the
sensor is: a point dipole at a position relative to the pivot of a rig that turns every station about that
pivot (meta ``"rig": "turntable"``), read by a sensor a lever arm off the pivot (:mod:`icgo.physics.dipole`).
An effect with ``rig`` set is only meaningful on data recorded on that rig (:func:`names_for_rig`).

New effects are added by :func:`register` (one more entry), e.g. in a notebook.
"""

from __future__ import annotations

from typing import Callable, Mapping, NamedTuple

import jax.numpy as jnp
import numpy as np

from icgo.physics.dipole import body_start, dipole_field, sensor_positions


class Effect(NamedTuple):
    """One named effect.

    Attributes:
        name: vocabulary name.
        n_params: length of the flat parameter vector.
        description: one-line physics.
        units: unit of the parameters.
        typical: a realistic magnitude of each parameter (same unit), used to
            simulate the effect and to scale fits: one number, or one per parameter.
        apply: ``(params, G, B, C) -> (G, B)``; G (..., 3) g, B (..., 3) nT,
            C (..., 3, 3) tool-to-earth rotation.
        frame: ``"tool"`` if the effect is fixed in the tool frame (turns with the
            tool), ``"earth"`` if fixed in the earth frame.
        labels: the parameters' component names (None: x, y, z for 3 parameters, else 0, 1, ...).
        rig: None for any data; else the rig (meta ``"rig"``) whose data it needs (its field depends on
            where the sensor is, known only on that rig).
        start: None (a fit starts the effect at 0), or a data-driven start of a nonlinear effect,
            ``start(residual_B (n, 3) nT tool frame, C (n, 3, 3), w (n,), fixed (n_params,)) -> (n_params,)``:
            the parameters that best explain the residual field of the model without it, ``w`` the station
            weights, ``fixed`` the given values of the parameters the fit does not move (NaN: free).
    """

    name: str
    n_params: int
    description: str
    units: str
    typical: float
    apply: Callable
    frame: str = "tool"
    labels: tuple | None = None
    rig: str | None = None
    start: Callable | None = None

    def typical_each(self) -> np.ndarray:
        """(n_params,) the typical magnitude of each parameter."""
        return np.broadcast_to(np.asarray(self.typical, float), (self.n_params,)).copy()


def skew(w):
    """Cross-product matrix ``[w]x`` of (..., 3) vectors, shape (..., 3, 3)."""
    w = jnp.asarray(w)
    z = jnp.zeros_like(w[..., 0])
    return jnp.stack(
        [
            jnp.stack([z, -w[..., 2], w[..., 1]], -1),
            jnp.stack([w[..., 2], z, -w[..., 0]], -1),
            jnp.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )


def rotation_from_vector(w_deg):
    """Exact rotation ``exp([w]x)`` for a rotation vector in deg (Rodrigues), (3, 3).

    To first order this is ``I + [w]x`` (the vocabulary's definition); the exact
    form keeps |B| unchanged to rounding, and has a finite derivative at w = 0.
    """
    w = jnp.deg2rad(jnp.asarray(w_deg))
    th2 = jnp.sum(w * w)
    small = th2 < 1e-12
    th2s = jnp.where(small, 1.0, th2)
    th = jnp.sqrt(th2s)
    a = jnp.where(small, 1.0 - th2 / 6.0, jnp.sin(th) / th)
    b = jnp.where(small, 0.5 - th2 / 24.0, (1.0 - jnp.cos(th)) / th2s)
    k = skew(w)
    return jnp.eye(3, dtype=w.dtype) + a * k + b * (k @ k)


def _matvec(m, v):
    return jnp.einsum("ij,...j->...i", m, v)


def _hard_iron(p, G, B, C):
    return G, B + p


def _external_field(p, G, B, C):
    # C^T e: the earth-fixed vector seen in each station's tool frame.
    return G, B + jnp.einsum("...ji,j->...i", C, p)


def _magnetic_body(p, G, B, C):
    # p = moment (A m^2, NED), position (m, NED from the pivot), lever arm (m, tool frame): the body's field at
    # the sensor, r = C l, seen in each station's tool frame.
    b_ned = dipole_field(sensor_positions(C, p[6:9]), p[3:6], p[0:3])
    return G, B + jnp.einsum("...ji,...j->...i", C, b_ned)


def _mag_scale(p, G, B, C):
    return G, B * (1.0 + p)


def _cross_matrix(p):
    """Symmetric off-diagonal matrix from (sxy, sxz, syz)."""
    z = jnp.zeros_like(p[0])
    return jnp.stack(
        [jnp.stack([z, p[0], p[1]]), jnp.stack([p[0], z, p[2]]), jnp.stack([p[1], p[2], z])]
    )


def _mag_cross_coupling(p, G, B, C):
    return G, B + _matvec(_cross_matrix(p), B)


def _mag_misalignment(p, G, B, C):
    return G, _matvec(rotation_from_vector(p), B)


def _accel_bias(p, G, B, C):
    return G + p, B


def _accel_scale(p, G, B, C):
    return G * (1.0 + p), B


EFFECTS: dict[str, Effect] = {}


def register(effect: Effect, order_after: str | None = None) -> Effect:
    """Add an effect to the vocabulary (and to :data:`ORDER`, after ``order_after`` or last)."""
    if effect.name in EFFECTS:
        raise ValueError(f"effect {effect.name!r} is already registered")
    EFFECTS[effect.name] = effect
    if order_after is None:
        ORDER.append(effect.name)
    else:
        ORDER.insert(ORDER.index(order_after) + 1, effect.name)
    return effect


ORDER: list[str] = []

for _e in (
    Effect("external_field", 3, "constant field fixed in the earth frame (nearby casing, wrong reference field); NED components",
           "nT", 300.0, _external_field, "earth"),
    Effect("magnetic_body", 9, "a magnetized body (casing) fixed in the lab, a point dipole: moment (A m^2, NED), position "
           "(m, NED from the rig's pivot), the sensor's lever arm from the pivot (m, tool frame); its field at the sensor "
           "C l changes as the tool turns (meta rig: turntable)",
           "A m^2, m, m", (30.0,) * 3 + (1.0,) * 3 + (0.1,) * 3, _magnetic_body, "earth",
           ("m_N", "m_E", "m_D", "p_N", "p_E", "p_D", "lever_x", "lever_y", "lever_z"), "turntable",
           body_start),
    Effect("mag_cross_coupling", 3, "symmetric off-diagonal magnetometer matrix (non-orthogonality, soft iron): B <- (I + S) B; (sxy, sxz, syz)",
           "1", 0.01, _mag_cross_coupling),
    Effect("mag_scale", 3, "magnetometer scale factors: B <- (I + diag(s)) B",
           "1", 0.01, _mag_scale),
    Effect("mag_misalignment", 3, "small rotation of the magnetometer triad relative to the accelerometers: B <- exp([w]x) B ~ (I + [w]x) B",
           "deg", 0.5, _mag_misalignment),
    Effect("hard_iron", 3, "constant magnetometer bias in the tool frame (incl. drill-string axial magnetization)",
           "nT", 500.0, _hard_iron),
    Effect("accel_scale", 3, "accelerometer scale factors: G <- (I + diag(s)) G",
           "1", 3e-3, _accel_scale),
    Effect("accel_bias", 3, "accelerometer bias: G <- G + b",
           "g", 3e-3, _accel_bias),
):
    register(_e)


def names_for_rig(rig: str | None = None, names=None) -> tuple:
    """The effects of ``names`` (default :data:`ORDER`) meaningful on data recorded on ``rig`` (meta ``"rig"``,
    None: none declared): those without a rig, and those of that rig."""
    return tuple(n for n in (ORDER if names is None else names) if EFFECTS[n].rig in (None, rig))


def check_names(names) -> None:
    """Raise ValueError naming any effect not in the vocabulary."""
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}: known are {list(EFFECTS)}")


def apply_effects(params: Mapping[str, jnp.ndarray], G, B, C):
    """Apply several effects in the physical order :data:`ORDER`.

    Args:
        params: mapping effect name -> (n_params,) parameters.
        G: (..., 3) ideal gravity, g. B: (..., 3) ideal field, nT.
        C: (..., 3, 3) tool-to-earth rotation of each station.
    Returns:
        (G, B) as measured.
    """
    check_names(params)
    for name in ORDER:
        if name in params:
            p = jnp.asarray(params[name], dtype=jnp.result_type(B))
            if p.shape != (EFFECTS[name].n_params,):
                raise ValueError(f"effect {name!r}: expected {EFFECTS[name].n_params} parameters, got shape {p.shape}")
            G, B = EFFECTS[name].apply(p, G, B, C)
    return G, B


def twelve_parameter_matrix(params: Mapping[str, jnp.ndarray]):
    """The matrix R of ``B_meas = R B + b`` implied by the magnetometer matrix effects, (3, 3)."""
    r = jnp.eye(3)
    if "mag_cross_coupling" in params:
        r = (jnp.eye(3) + _cross_matrix(jnp.asarray(params["mag_cross_coupling"]))) @ r
    if "mag_scale" in params:
        r = jnp.diag(1.0 + jnp.asarray(params["mag_scale"])) @ r
    if "mag_misalignment" in params:
        r = rotation_from_vector(params["mag_misalignment"]) @ r
    return r
