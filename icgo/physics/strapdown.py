"""Strapdown gyro propagation: rotation vectors, attitude increments, relative rotations.

Frames (``docs/frames.md``): NED navigation frame n (earth-fixed), tool frame b,
``C = C^n_b = Rz(A) Ry(I) Rz(T)`` (:func:`icgo.physics.frames.tool_to_earth`). The
gyro measures the tool's rate relative to inertial space, ``w_ib`` (earth rate
included). A sample ``W_k`` is the *mean* rate over ``(t_{k-1}, t_k]``: the
body turns by ``exp([W_k dt x])`` in that interval (the delta-angle output of a
strapdown gyro; exact for a rate that is constant in the body frame over the
interval).

Host-side numpy (float64): this is data preparation, not a search's hot path.
"""

from __future__ import annotations

import numpy as np

from icgo.physics.frames import earth_rate_ned, tool_to_earth

DEG_H_TO_RAD_S = np.pi / 180.0 / 3600.0


def rot_exp(phi) -> np.ndarray:
    """Rotation matrices ``exp([phi x])`` of rotation vectors ``phi`` (..., 3) rad -> (..., 3, 3)."""
    phi = np.asarray(phi, np.float64)
    from scipy.spatial.transform import Rotation  # imported here: scipy.spatial takes 0.6 s, most commands never rotate

    return Rotation.from_rotvec(phi.reshape(-1, 3)).as_matrix().reshape(phi.shape[:-1] + (3, 3))


def rot_log(R, near) -> np.ndarray:
    """Rotation vectors (..., 3) rad of matrices ``R`` (..., 3, 3), on the branch nearest ``near`` (..., 3).

    ``exp(phi) = exp(phi + 2 pi n u)`` for the axis ``u``: a string turning by
    more than 180 deg in one sample (30 rpm at 1 Hz) needs the branch of its
    nominal rotation, not scipy's principal one (|phi| <= pi).
    """
    R = np.asarray(R, np.float64)
    near = np.broadcast_to(np.asarray(near, np.float64), R.shape[:-2] + (3,)).reshape(-1, 3)
    from scipy.spatial.transform import Rotation

    phi = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec()
    theta = np.linalg.norm(phi, axis=1, keepdims=True)
    nn = np.linalg.norm(near, axis=1, keepdims=True)
    # the axis is undefined for a null rotation: take the nominal one's
    u = np.where(theta > 1e-12, phi / np.maximum(theta, 1e-300), near / np.maximum(nn, 1e-300))
    cands = phi[:, None, :] + 2.0 * np.pi * np.arange(-3, 4)[None, :, None] * u[:, None, :]
    best = np.argmin(np.linalg.norm(cands - near[:, None, :], axis=2), axis=1)
    return cands[np.arange(len(phi)), best].reshape(R.shape[:-2] + (3,))


def earth_rotation(latitude_deg, seconds) -> np.ndarray:
    """``exp([w_ie^n x] t)``: the NED frame's rotation relative to inertial space after ``seconds`` (...) -> (..., 3, 3)."""
    w = np.asarray(earth_rate_ned(latitude_deg), np.float64) * DEG_H_TO_RAD_S  # rad/s, NED
    return rot_exp(np.multiply.outer(np.asarray(seconds, np.float64), w))


def gyro_rates_from_attitude(azimuth_deg, inclination_deg, toolface_deg, dt_s, latitude_deg,
                             nominal_deg_s) -> np.ndarray:
    """True gyro samples (deg/h) of an attitude history: the constant rate that maps attitude k-1 to k.

    ``exp([W_k dt x]) = C_{k-1}^T exp([w_ie dt x]) C_k`` (body rotation relative to
    inertial space over one interval; ``C^i_b = C^i_n(t) C^n_b``). Sample 0 has no
    predecessor and reads the earth rate alone.

    Args:
        azimuth_deg, inclination_deg, toolface_deg: (N,) attitude at the samples, deg.
        dt_s: sample interval, s. latitude_deg: site latitude, deg.
        nominal_deg_s: (N,) nominal rotation rate about the tool axis (deg/s), which picks
            the branch of each increment (:func:`rot_log`).
    Returns:
        (N, 3) rates in the tool frame, deg/h.
    """
    C = np.asarray(tool_to_earth(azimuth_deg, inclination_deg, toolface_deg), np.float64)
    E = earth_rotation(latitude_deg, dt_s)
    inc = np.einsum("kji,jl,klm->kim", C[:-1], E, C[1:])  # C_{k-1}^T E C_k
    near = np.zeros((len(C) - 1, 3))
    near[:, 2] = np.deg2rad(np.asarray(nominal_deg_s, np.float64)[1:]) * dt_s
    phi = rot_log(inc, near)
    w0 = np.einsum("ji,j->i", C[0], np.asarray(earth_rate_ned(latitude_deg), np.float64))  # deg/h
    return np.vstack([w0[None], phi / (dt_s * DEG_H_TO_RAD_S)])


def relative_rotations(W_deg_h, dt_s, anchor: int, lo: int, hi: int) -> np.ndarray:
    """``Q_k`` with ``C^i_b(k) = C^i_b(anchor) Q_k`` for k = lo .. hi (inclusive), from the gyro samples.

    Forward ``Q_k = Q_{k-1} exp(W_k dt)``; backward ``Q_{k-1} = Q_k exp(W_k dt)^T``.

    Args:
        W_deg_h: (N, 3) gyro samples, deg/h (bias already removed if wanted).
        dt_s: sample interval, s. anchor, lo, hi: sample indices, ``lo <= anchor <= hi``.
    Returns:
        (hi - lo + 1, 3, 3).
    """
    if not lo <= anchor <= hi:
        raise ValueError(f"relative_rotations: need lo <= anchor <= hi, got {lo}, {anchor}, {hi}")
    step = rot_exp(np.asarray(W_deg_h, np.float64)[lo + 1:hi + 1] * DEG_H_TO_RAD_S * dt_s)  # increment into k
    Q = np.empty((hi - lo + 1, 3, 3))
    Q[anchor - lo] = np.eye(3)
    for k in range(anchor + 1, hi + 1):
        Q[k - lo] = Q[k - lo - 1] @ step[k - lo - 1]
    for k in range(anchor, lo, -1):
        Q[k - lo - 1] = Q[k - lo] @ step[k - lo - 1].T
    return Q


__all__ = ["DEG_H_TO_RAD_S", "earth_rotation", "gyro_rates_from_attitude", "relative_rotations",
           "rot_exp", "rot_log"]
