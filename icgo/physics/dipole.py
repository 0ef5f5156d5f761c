"""The field of a point magnetic dipole, and the turntable geometry of a sensor carried about a pivot.

A dipole of moment ``m`` (A m^2) at ``p`` makes at ``r`` the field (nT)

    B = mu0/(4 pi) (3 (m . d) d / |d|^5 - m / |d|^3),   d = r - p        (Jackson, Classical Electrodynamics, eq. 5.56)

On a turntable rig every station is turned about one fixed pivot (the origin), so a sensor ``l`` (m, tool
frame) from the pivot sits at ``r = C l`` (``C`` the tool-to-earth rotation): a magnetized body fixed in the
lab then reads differently at every station (:data:`icgo.physics.effects.EFFECTS` ``magnetic_body``).
Positions in m, NED; fields in nT.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

#: mu0 / (4 pi) in T m / A.
MU0_OVER_4PI = 1e-7
#: Tesla to nanotesla.
T_TO_NT = 1e9
#: Closer than this (m) to the dipole the field is taken as 0 (the point itself, where it is undefined).
MIN_DISTANCE_M = 1e-6


def dipole_field(points, position, moment):
    """Field of one point dipole at ``points`` (nT), in the frame of the positions.

    Finite everywhere (0 within :data:`MIN_DISTANCE_M` of the dipole), with finite derivatives, so a fit may
    pass through any position.

    Args:
        points: (..., 3) field points (m). position: (3,) or (..., 3) dipole position (m).
        moment: (3,) or (..., 3) dipole moment (A m^2).
    Returns:
        (..., 3) field (nT).
    """
    d = jnp.asarray(points) - jnp.asarray(position)
    d2 = jnp.sum(d * d, -1, keepdims=True)
    near = d2 < MIN_DISTANCE_M**2
    d2s = jnp.where(near, 1.0, d2)
    inv3 = d2s ** -1.5
    mdotd = jnp.sum(jnp.asarray(moment) * d, -1, keepdims=True)
    b = (3.0 * mdotd * d / d2s - moment) * inv3
    return jnp.where(near, 0.0, MU0_OVER_4PI * T_TO_NT * b)


def sensor_positions(C, lever):
    """Positions (m, NED, from the pivot) of a sensor ``lever`` (m, tool frame) from the pivot: ``C @ lever``.

    Args:
        C: (..., 3, 3) tool-to-earth rotations. lever: (3,) m.
    Returns:
        (..., 3) positions (m).
    """
    return jnp.einsum("...ij,j->...i", C, lever)


#: Distances (m) from the pivot of the positions :func:`body_start` tries, each in :data:`START_DIRECTIONS`
#: directions (a Fibonacci sphere).
START_DISTANCES_M = (0.3, 0.5, 0.8, 1.2, 2.0, 3.5)
START_DIRECTIONS = 48
#: The lever arm (m, tool frame) a fit starts from when none is given: 0.1 m down the tool axis.
START_LEVER_M = (0.0, 0.0, 0.1)


def _fibonacci_sphere(k: int) -> np.ndarray:
    """(k, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    phi = np.pi * (1.0 + 5**0.5) * i
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], 1)


def body_start(residual, C, w, fixed) -> np.ndarray:
    """A start for a dipole fit (``magnetic_body``): the grid position whose dipole best explains ``residual``.

    For every position of a grid around the pivot (:data:`START_DISTANCES_M` x :data:`START_DIRECTIONS`) the
    field is linear in the moment, so the moment and, beside it, a constant earth-fixed and a constant
    tool-fixed field (which the rest of a model may still explain) are solved by weighted linear least
    squares; the position with the smallest weighted residual and its moment are returned. Host-side numpy.

    Args:
        residual: (n, 3) field the model without the body leaves, nT, tool frame (measured - predicted).
        C: (n, 3, 3) tool-to-earth rotation of each station. w: (n,) station weights (0 = not used).
        fixed: (9,) the given parameters (NaN where free); a given lever arm (entries 6:9) is used as it is,
            else :data:`START_LEVER_M`.
    Returns:
        (9,) moment (A m^2, NED), position (m, NED from the pivot), lever arm (m, tool frame).
    """
    residual, C, w = (np.asarray(a, float) for a in (residual, C, w))
    fixed = np.asarray(fixed, float)
    lever = fixed[6:9] if np.all(np.isfinite(fixed[6:9])) else np.asarray(START_LEVER_M)
    r = np.einsum("nij,j->ni", C, lever)
    P = (np.asarray(START_DISTANCES_M)[:, None, None] * _fibonacci_sphere(START_DIRECTIONS)[None]).reshape(-1, 3)
    d = r[None] - P[:, None]                                                # (Q, n, 3)
    dn = np.linalg.norm(d, axis=-1)[..., None, None]
    T = MU0_OVER_4PI * T_TO_NT * (3.0 * d[..., :, None] * d[..., None, :] / dn**5 - np.eye(3) / dn**3)
    K = np.einsum("nji,qnjk->qnik", C, T)                                   # (Q, n, 3, 3) tool frame per unit moment
    Ct = np.broadcast_to(np.swapaxes(C, 1, 2), K.shape)
    eye = np.broadcast_to(np.eye(3), K.shape)
    A = np.concatenate([K, Ct, eye], -1)                                    # (Q, n, 3, 9)
    sw = np.sqrt(w)[None, :, None, None]
    Aw = (A * sw).reshape(len(P), -1, 9)
    yw = (residual * np.sqrt(w)[:, None]).reshape(-1)
    x = np.stack([np.linalg.lstsq(a, yw, rcond=None)[0] for a in Aw])       # (Q, 9)
    cost = np.sum((np.einsum("qrk,qk->qr", Aw, x) - yw[None]) ** 2, 1)
    q = int(np.argmin(cost))
    return np.concatenate([x[q, :3], P[q], lever])
