"""The gyro-derived reference field M_omega (MISMA paper, sections 2.1 and 2.3) and the terms built on it.

The paper (seeds/002, section 2.1): "based on the gyroscope data, the geomagnetic
vector is decoupled from the magnetometer signal to obtain the reference
geomagnetic vector M_omega"; section 2.3: "using the MEMS gyro's high short-time
accuracy ... by the Coriolis transport model, decouple the geomagnetic
information". Our reconstruction (``docs/misma.md``, "Gyro reference"):

* **Windows.** One window per stop (the zero-velocity survey of the paper's
  field run): the stop's static samples plus ``window_s`` seconds of rotating
  samples on each side. The anchor is the stop's middle sample.
* **Anchor attitude up to heading.** Inclination and toolface from the stop's
  mean gravity (zero velocity, as the paper takes gravity); the heading psi is
  the one rotation the gyro cannot see (a MEMS gyro cannot gyro-compass: its
  bias is ten times the earth rate).
* **Gyro bias at the stop.** The mean static gyro reading minus the earth
  rate's known vertical component (``bias="stop"``); the horizontal earth rate
  (``15.04 cos(lat)`` deg/h) stays in the estimate, an error of at most
  ``15.04 cos(lat) window`` on the propagated attitude (0.07 deg for 20 s at 35 N).
* **Propagation (Coriolis transport, strapdown).** ``C^i_b(k) = C^i_b(a) Q_k``
  from the gyro (:func:`icgo.physics.strapdown.relative_rotations`); the field is fixed
  to the rotating earth, so ``m_b(k) = Q_k^T C_a^T exp([w_ie x](t_k - t_a)) m_n``
  with ``C_a = Rz(psi) C0`` (C0: the anchor's attitude at heading 0) and
  ``m_n`` the site field (NED; total field and dip from the metadata).
* **M_omega(k; psi)** ``= cos(psi) a_k + sin(psi) b_k + c_k`` (nT) with
  ``a, b, c`` precomputed (:class:`GyroReference`). For a corrected field the
  best psi per window has a closed form (:func:`reference_at`).

On it: the objective term ``J_gyro`` (:func:`gyro_term`), the box centre
``U_omega`` (eqs. 9-10, :func:`fit_to_reference`) and the GMR (eq. 15) at the
window samples (``|M_omega(k)| = |m_n|``: a rotation keeps the modulus).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.models import calibration as cal
from icgo.physics.frames import earth_rate_ned, field_vector_ned, inclination_from_g, tool_to_earth, toolface_from_g
from icgo.physics.strapdown import earth_rotation, relative_rotations

#: Ways to take the gyro bias out before propagating: at each stop, or not at all.
BIAS_MODES = ("stop", "none")


class GyroReference(NamedTuple):
    """M_omega up to one heading per window, at the window samples (M samples, nW windows).

    Attributes:
        index: (M,) sample indices into the recording.
        window: (M,) int32 window id (0 .. nW-1).
        a, b, c: (M, 3) nT; ``M_omega(k; psi) = cos(psi) a_k + sin(psi) b_k + c_k``.
        ref_nT: |m_n|, the site's total field (nT).
        bias_deg_h: (nW, 3) the gyro bias taken out in each window (deg/h; zeros with ``bias="none"``).
    """

    index: np.ndarray
    window: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    ref_nT: float
    bias_deg_h: np.ndarray

    @property
    def n_windows(self) -> int:
        return int(self.window.max()) + 1 if len(self.window) else 0


def stop_runs(static) -> list[tuple[int, int]]:
    """(first, last) sample index of each run of consecutive static samples."""
    s = np.asarray(static, bool).astype(np.int8)
    edges = np.diff(np.r_[0, s, 0])
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))


def gyro_reference(G, W, t, static, latitude_deg, total_field_nT, dip_deg, window_s=10.0,
                   bias="stop") -> GyroReference:
    """Build :class:`GyroReference` from a recording (see the module doc).

    Args:
        G: (N, 3) accelerometer, g. W: (N, 3) gyro, deg/h. t: (N,) time, s (uniform steps).
        static: (N,) bool zero-velocity samples (stops). latitude_deg: site latitude, deg.
        total_field_nT, dip_deg: the site field (metadata). window_s: rotating seconds on each side of a stop.
        bias: ``"stop"`` (estimate the gyro bias at each stop) or ``"none"``.
    Raises:
        ValueError: no stop, non-uniform time, or a bad setting (one line).
    """
    G, W, t = (np.asarray(v, np.float64) for v in (G, W, t))
    if bias not in BIAS_MODES:
        raise ValueError(f"gyro bias mode {bias!r}: choose one of {BIAS_MODES}")
    if not (np.isfinite(window_s) and window_s >= 0):
        raise ValueError(f"gyro window_s must be a number >= 0, got {window_s!r}")
    dts = np.diff(t)
    if len(t) < 2 or not np.allclose(dts, dts[0], rtol=1e-6, atol=0) or dts[0] <= 0:
        raise ValueError("gyro reference: time_s must increase in uniform steps")
    dt = float(dts[0])
    runs = stop_runs(static)
    if not runs:
        raise ValueError("gyro reference: the recording has no static samples (stops) to anchor the gyro windows on")
    side = int(round(window_s / dt))
    m_n = np.asarray(field_vector_ned(total_field_nT, dip_deg), np.float64)
    w_down = float(np.asarray(earth_rate_ned(latitude_deg))[2])  # deg/h along NED down
    parts = {k: [] for k in ("index", "window", "a", "b", "c")}
    biases = []
    for w, (first, last) in enumerate(runs):
        anchor = (first + last) // 2
        lo, hi = max(first - side, 0), min(last + side, len(t) - 1)
        g = G[first:last + 1].mean(0)
        down = g / np.linalg.norm(g)
        bw = W[first:last + 1].mean(0) - w_down * down if bias == "stop" else np.zeros(3)
        biases.append(bw)
        Q = relative_rotations(W - bw, dt, anchor, lo, hi)
        C0 = np.asarray(tool_to_earth(0.0, inclination_from_g(g), toolface_from_g(g)), np.float64)  # heading 0
        P = np.einsum("kji,lj->kil", Q, C0)  # Q_k^T C0^T
        v = earth_rotation(latitude_deg, t[lo:hi + 1] - t[anchor]) @ m_n  # (n, 3) NED
        zero = np.zeros(len(v))
        parts["a"].append(np.einsum("kij,kj->ki", P, np.stack([v[:, 0], v[:, 1], zero], 1)))
        parts["b"].append(np.einsum("kij,kj->ki", P, np.stack([v[:, 1], -v[:, 0], zero], 1)))
        parts["c"].append(np.einsum("kij,kj->ki", P, np.stack([zero, zero, v[:, 2]], 1)))
        parts["index"].append(np.arange(lo, hi + 1))
        parts["window"].append(np.full(hi - lo + 1, w, np.int32))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    return GyroReference(cat["index"], cat["window"], cat["a"], cat["b"], cat["c"],
                         float(np.linalg.norm(m_n)), np.asarray(biases))


def reference_at(Bc, ref: GyroReference):
    """M_omega at the heading that best fits a corrected field, per window (closed form).

    ``psi_w = atan2(sum_k Bc_k.b_k, sum_k Bc_k.a_k)`` minimises
    ``sum_k |Bc_k - M_omega(k; psi)|^2`` (``|a_k| = |b_k|``, ``a_k . b_k = 0``, ``c_k`` orthogonal to both).

    Args:
        Bc: (M, 3) corrected field at ``ref.index``, nT. ref: :class:`GyroReference`.
    Returns:
        (psi (nW,) rad, M_omega (M, 3) nT).
    """
    n = ref.n_windows
    seg = jnp.asarray(ref.window)
    a, b, c = jnp.asarray(ref.a), jnp.asarray(ref.b), jnp.asarray(ref.c)
    sa = jax.ops.segment_sum(jnp.sum(Bc * a, -1), seg, n)
    sb = jax.ops.segment_sum(jnp.sum(Bc * b, -1), seg, n)
    psi = jnp.arctan2(sb, sa)
    return psi, jnp.cos(psi)[seg, None] * a + jnp.sin(psi)[seg, None] * b + c


def gyro_term(x, B, ref: GyroReference):
    """``J_gyro = mean_k |Bc_k - M_omega(k)|^2 / |M_omega|^2`` (dimensionless) for one (12,) candidate.

    Args:
        x: (12,) parameters ``[R^-1, b]``. B: (M, 3) raw field at ``ref.index``, nT.
    """
    Bc = cal.correct(x, B)
    _, m = reference_at(Bc, ref)
    return jnp.mean(jnp.sum((Bc - m) ** 2, -1)) / ref.ref_nT ** 2


def fit_to_reference(B, ref: GyroReference, x0, iters=100, tol=1e-12, ridge=1e-4) -> np.ndarray:
    """``U_omega``: the 12 parameters that best map the raw field onto M_omega (eqs. 9-10 on the gyro reference).

    Alternates the closed-form headings (:func:`reference_at`) with the linear
    least squares ``M_omega(k) ~= R^-1 B_k + d`` (``b = -R d``), each step
    lowering the cost. A weak ridge pulls the linear coefficients towards those
    of ``x0`` (columns of ``[B, 1]`` scaled to unit RMS, so the ridge is in nT):
    on a near-straight hole the cost has a flat direction (the tool-axis scale
    against its bias, ``docs/misma.md``) and plain least squares walks along it
    to 1e5 nT biases. Stops when the relative change of x is below ``tol``.

    Args:
        B: (M, 3) raw field at ``ref.index``, nT. x0: (12,) start and ridge centre (e.g. the modulus fit U).
        ridge: weight of ``|theta - theta0|^2`` relative to the mean squared residual (dimensionless).
    Returns:
        (12,) parameters.
    """
    B = np.asarray(B, np.float64)
    X = np.c_[B, np.ones(len(B))]
    s = np.sqrt(np.mean(X ** 2, 0))
    Xs = X / s
    x = np.asarray(x0, np.float64)
    r0, b0 = np.asarray(x[:9]).reshape(3, 3), x[9:]
    theta0 = np.vstack([r0.T, -(r0 @ b0)[None]]) * s[:, None]  # scaled coefficients of x0
    lam = np.sqrt(ridge * len(B))
    A = np.vstack([Xs, lam * np.eye(4)])
    for _ in range(int(iters)):
        _, m = reference_at(cal.correct(jnp.asarray(x), B), ref)
        sol, *_ = np.linalg.lstsq(A, np.vstack([np.asarray(m), lam * theta0]), rcond=None)
        sol = sol / s[:, None]
        r_inv, d = sol[:3].T, sol[3]
        new = np.r_[r_inv.ravel(), -np.linalg.solve(r_inv, d)]
        done = np.max(np.abs(new - x) / np.maximum(np.abs(x), 1.0)) < tol
        x = new
        if done:
            break
    return x
