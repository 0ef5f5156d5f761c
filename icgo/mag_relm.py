"""A non-linear magnetometer correction: a RELM on the residual of a linear calibration (issue 16, item 5).

After a linear calibration (12-parameter least squares + axis alignment) the
field ``b`` (unit sphere, tool frame) keeps a small non-linear error. We model it
as ``b' = b + tanh([u, 1] A) W`` with ``u = b / |b|``: ``L`` hidden units with fixed
random weights ``A`` ((4, L), the RELM's hidden layer) and output weights ``W``
((L, 3)) found in closed form by ridge regression (``(H^T H + lambda I) W = H^T R``).

Training targets come from **group consistency** and **one field**. The linear
calibration gives every shot its gravity (inclination, toolface) and a magnetic
azimuth. The common dip ``delta`` is the median over all shots. The target field of
a shot is the unit earth field ``(cos delta, 0, sin delta)`` (NED) seen at
(azimuth, inclination, toolface). The azimuth is the group's circular mean for a
rolled group, and the shot's own azimuth for a single shot, so singles are only
pulled onto the common dip and unit modulus. ``R = target - b``.

``lambda`` is chosen by leave-one-group-out on the training shots only: each group
(every single shot and every roll) is predicted by the fit on the others. The
chosen ``lambda`` minimizes the mean angle (deg) between a held-out shot's
corrected field and its target, over ``LAMBDAS``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from icgo.frames import azimuth_from_gv, inclination_from_g, tool_to_earth, toolface_from_g
from icgo.qc import measured_dip_deg

#: Candidate ridge parameters (leave-one-group-out picks one).
LAMBDAS = tuple(10.0 ** np.arange(-4.0, 2.01, 0.5))
#: Hidden units and the std of the hidden weights (inputs are unit vectors).
HIDDEN = 12
WEIGHT_STD = 1.0


class MagRELM(NamedTuple):
    """A fitted residual RELM. hidden: (4, L) input weights (last row: bias). out: (L, 3). lam: the chosen ridge."""

    hidden: np.ndarray
    out: np.ndarray
    lam: float


def features(b, hidden) -> np.ndarray:
    """RELM hidden layer ``tanh([u, 1] A)`` of unit field directions ``u = b / |b|``, (N, L)."""
    b = np.asarray(b, np.float64)
    u = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.tanh(np.hstack([u, np.ones((len(u), 1))]) @ hidden)


def apply(model_hidden, model_out, b) -> np.ndarray:
    """The corrected field ``b + tanh([u, 1] A) W``, (N, 3), same units as ``b`` (unit sphere)."""
    b = np.asarray(b, np.float64)
    return b + features(b, model_hidden) @ np.asarray(model_out, np.float64)


def targets(G, b, groups) -> np.ndarray:
    """One-field, group-consistent target fields (unit sphere, tool frame), (N, 3) (see the module doc)."""
    G = np.asarray(G, np.float64)
    b = np.asarray(b, np.float64)
    groups = np.asarray(groups)
    az = np.array(azimuth_from_gv(G, b), np.float64)  # a writable copy
    for g in np.unique(groups):
        m = groups == g
        if m.sum() > 1:
            z = np.exp(1j * np.radians(az[m])).mean()
            az[m] = np.degrees(np.angle(z))
    dip = np.radians(np.median(measured_dip_deg(G, b)))
    C = np.asarray(tool_to_earth(az, np.asarray(inclination_from_g(G)), np.asarray(toolface_from_g(G))))
    m_ned = np.array([np.cos(dip), 0.0, np.sin(dip)])
    return np.einsum("nji,j->ni", C, m_ned)


def _solve(H, R, lam) -> np.ndarray:
    return np.linalg.solve(H.T @ H + lam * np.eye(H.shape[1]), H.T @ R)


def _angle_deg(a, b) -> np.ndarray:
    c = np.sum(a * b, 1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def fit(G, b, groups, seed: int = 0, hidden: int = HIDDEN) -> MagRELM:
    """Fit the residual RELM on linearly calibrated shots; ``lambda`` by leave-one-group-out.

    Args:
        G: (N, 3) calibrated gravity (tool frame). b: (N, 3) linearly calibrated field (unit sphere).
        groups: (N,) group ids. seed: seed of the random hidden weights. hidden: L.
    Returns:
        :class:`MagRELM`.
    """
    rng = np.random.default_rng(seed)
    A = rng.normal(0.0, WEIGHT_STD, (4, int(hidden)))
    T = targets(G, b, groups)
    H, R = features(b, A), T - np.asarray(b, np.float64)
    groups = np.asarray(groups)
    ids = np.unique(groups)
    cv = []
    for lam in LAMBDAS:
        err = []
        for g in ids:
            m = groups == g
            W = _solve(H[~m], R[~m], lam)
            err.append(_angle_deg(b[m] + H[m] @ W, T[m]))
        cv.append(float(np.mean(np.concatenate(err))))
    lam = float(LAMBDAS[int(np.argmin(cv))])
    return MagRELM(A, _solve(H, R, lam), lam)
