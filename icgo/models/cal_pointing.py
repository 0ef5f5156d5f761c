"""Rolled groups of static shots after a calibration: pointing directions, the peer's score, the roll axis.

A group is shots that share one true direction, rolled about the pointing axis (:mod:`icgo.physics.rolls`).
:func:`pointing_directions` (and its JAX twin :func:`pointing_jnp`) gives each shot's tool-axis direction in
the earth frame, :func:`group_spread_deg` the peer package's accuracy score (circuitpython-mag-cal
``Calibration.accuracy``), and :func:`align_to_axis` the common rotation that puts the rolled groups' roll axis
on the tool z axis (mag_cal ``fit_to_axis``). Host-side numpy except :func:`pointing_jnp`.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from icgo.physics.rolls import MIN_ROLLED_SHOTS


def pointing_directions(G, B):
    """Direction of the tool z axis in the earth frame (N, E, D components), (N, 3).

    Built as the peer package does (mag_cal ``get_orientation_matrix``): down =
    unit G, east = unit(down x B), north = east x down; the tool axis' earth
    coordinates are the z components of those three unit vectors.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    down = G / np.linalg.norm(G, axis=-1, keepdims=True)
    east = np.cross(down, B)
    east /= np.linalg.norm(east, axis=-1, keepdims=True)
    north = np.cross(east, down)
    return np.stack([north[..., 2], east[..., 2], down[..., 2]], -1)


def group_spread_deg(G, B, groups, min_size=2):
    """The peer package's accuracy score (mag_cal ``Calibration.accuracy``), in deg.

    For each group of at least ``min_size`` shots sharing one true direction
    (rolled about the pointing axis), the norm of the per-axis standard
    deviations (ddof = 1) of the unit pointing-direction vectors; converted
    from radians to degrees and averaged over the groups.

    Args:
        G: (N, 3) calibrated gravity. B: (N, 3) calibrated field.
        groups: (N,) group ids.
    Returns:
        (mean over groups, dict group id -> spread), deg.
    """
    groups = np.asarray(groups)
    d = pointing_directions(G, B)
    out = {}
    for gid in np.unique(groups):
        m = groups == gid
        if m.sum() >= min_size:
            out[int(gid)] = float(np.degrees(np.linalg.norm(np.std(d[m], axis=0, ddof=1))))
    if not out:
        raise ValueError(f"group spread: no group has {min_size} or more shots")
    return float(np.mean(list(out.values()))), out


def _rotation_to_z(n):
    """Smallest rotation Q (3, 3) with ``Q n = e_z`` for a unit vector n."""
    n = n / np.linalg.norm(n)
    ez = np.array([0.0, 0.0, 1.0])
    v = np.cross(n, ez)
    s, c = np.linalg.norm(v), float(n @ ez)
    if s < 1e-15:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def roll_axis(vectors_by_group):
    """Common roll axis (unit, tool frame) of several rolled groups.

    Each rolled group's vectors lie on a cone about the roll axis, i.e. in a
    plane ``v . n = const``: ``n`` from least squares (as mag_cal ``_find_plane``),
    signs made to agree with +z, then averaged.
    """
    acc = np.zeros(3)
    for v in vectors_by_group:
        v = np.asarray(v, np.float64)
        n = np.linalg.lstsq(v, np.ones(len(v)), rcond=None)[0]
        n /= np.linalg.norm(n)
        acc += n if n[2] >= 0 else -n
    return acc / np.linalg.norm(acc)


def align_to_axis(G_cal, B_cal, groups, min_size=MIN_ROLLED_SHOTS):
    """Rotation Q (3, 3) putting the rolled groups' roll axis on tool z (mag_cal ``fit_to_axis``).

    One rotation common to both sensors (so the dot products fitted before are
    kept); the axis is the average of the accelerometer's and magnetometer's
    plane normals over the rolled groups. Apply as ``v @ Q.T``.
    """
    groups = np.asarray(groups)
    vecs = []
    for gid in np.unique(groups):
        m = groups == gid
        if m.sum() >= min_size:
            vecs.append(np.asarray(G_cal)[m] / np.linalg.norm(np.asarray(G_cal)[m], axis=1, keepdims=True))
            vecs.append(np.asarray(B_cal)[m] / np.linalg.norm(np.asarray(B_cal)[m], axis=1, keepdims=True))
    if not vecs:
        raise ValueError(f"axis alignment: no group with {min_size} or more rolled shots")
    return _rotation_to_z(roll_axis(vecs))


def pointing_jnp(G, B):
    """:func:`pointing_directions` in JAX (jittable, differentiable): (..., 3) from G, B (..., 3)."""
    down = G / jnp.linalg.norm(G, axis=-1, keepdims=True)
    east = jnp.cross(down, B)
    east = east / jnp.linalg.norm(east, axis=-1, keepdims=True)
    north = jnp.cross(east, down)
    return jnp.stack([north[..., 2], east[..., 2], down[..., 2]], -1)
