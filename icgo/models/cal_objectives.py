"""The objectives of a 12-parameter magnetometer calibration (JAX, jittable, vmappable over candidate parameters).

Parameters as in :mod:`icgo.models.calibration` (``[R^-1 row-major, b]``, (12,); eq. 4 corrects
``B_true = R^-1 (B_meas - b)``); the equation numbers are the MISMA paper's, reconstructed as listed in
``docs/misma.md``:

* :func:`dot_invariance` (eq. 5): at one site the angle between G and B is
  constant, so the spread (variance) of ``G.B / (|G| |B|)`` over the samples
  is zero at the true parameters.
* :func:`magnitude_consistency`: mean squared relative deviation of the
  corrected ``|B|`` from the reference modulus ``|M_omega|`` (the equality
  constraint of eq. 8 used as a quadratic penalty).
* :func:`pearson_xy` (eqs. 6-7): while the string rotates, the cross-axial
  magnetometer and accelerometer signals are sinusoids of one frequency; the
  Pearson correlation of corrected ``bx`` with ``gx`` and ``by`` with ``gy``
  must reach a threshold.
* :func:`magnitude_ratio` (eq. 15): the geomagnetic modulus ratio GMR, in
  (0, 1], 1 when every corrected ``|B|`` equals ``|M_omega|``.

:class:`icgo.models.misma_objective.MismaObjective` combines them into the penalised fitness that MISMA and
SMA minimise (``(P, 12) -> (P,)``, +inf for non-finite values) and exposes the GMR for :mod:`icgo.optim.misma`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from icgo.models.calibration import correct, normalized_dot


def _wmean(v, w):
    return jnp.sum(v * w, -1) / jnp.sum(w, -1)


def dot_invariance(x, G, B_meas, weights=None):
    """Eq. (5): spread of the normalised dot product after correction.

    ``J_dot = sum_k w_k (d_k - d_bar)^2 / sum_k w_k`` with
    ``d_k = G_k.B_k / (|G_k| |B_k|)``, ``B_k = R^-1 (B_meas,k - b)``. Zero at the
    true parameters on noise-free data. Unit: (cosine)^2.

    Args:
        x: (12,) parameters. G: (N, 3) gravity, g. B_meas: (N, 3) raw field, nT.
        weights: (N,) sample weights or None (all 1).
    Returns:
        scalar.
    """
    d = normalized_dot(G, correct(x, B_meas))
    w = jnp.ones_like(d) if weights is None else jnp.asarray(weights, d.dtype)
    return _wmean((d - _wmean(d, w)) ** 2, w)


def magnitude_consistency(x, B_meas, ref_nT, weights=None):
    """Field-magnitude consistency: ``mean_k (|B_k| / |M_omega| - 1)^2`` (eq. 8 as a penalty).

    Args:
        x: (12,) parameters. B_meas: (N, 3) raw field, nT.
        ref_nT: reference modulus |M_omega| (nT), scalar.
        weights: (N,) or None.
    Returns:
        scalar, dimensionless.
    """
    m = jnp.linalg.norm(correct(x, B_meas), axis=-1)
    w = jnp.ones_like(m) if weights is None else jnp.asarray(weights, m.dtype)
    return _wmean((m / ref_nT - 1.0) ** 2, w)


def magnitude_ratio(x, B_meas, ref_nT, weights=None):
    """Eq. (15): geomagnetic modulus ratio GMR in (0, 1].

    ``GMR = mean_k min(r_k, 1 / r_k)``, ``r_k = |R^-1 (B_k - b)| / |M_omega|``:
    1 when every corrected modulus equals the reference, small for a poor
    solution (the paper: "GMR small -> B is a poor solution").
    """
    r = jnp.linalg.norm(correct(x, B_meas), axis=-1) / ref_nT
    g = jnp.minimum(r, 1.0 / r)
    w = jnp.ones_like(g) if weights is None else jnp.asarray(weights, g.dtype)
    return _wmean(g, w)


def _segment_pearson(a, b, seg, w, n_seg):
    """Pearson correlation of a and b inside each segment (weights w), (n_seg,) and counts."""
    s = lambda v: jax.ops.segment_sum(v * w, seg, num_segments=n_seg)
    n = s(jnp.ones_like(a))
    safe = jnp.maximum(n, 1.0)
    ma, mb = s(a) / safe, s(b) / safe
    da, db = a - ma[seg], b - mb[seg]
    cov = s(da * db)
    va, vb = s(da * da), s(db * db)
    rho = cov / jnp.sqrt(jnp.maximum(va * vb, 1e-300))
    return rho, n


def _segment_complex_corr(G, B, seg, w, n_seg):
    """|complex correlation| of the cross-axial phasors gx + i gy and bx + i by per segment."""
    s = lambda v: jax.ops.segment_sum(v * w, seg, num_segments=n_seg)
    n = s(jnp.ones_like(G[:, 0]))
    safe = jnp.maximum(n, 1.0)
    gx, gy, bx, by = G[:, 0], G[:, 1], B[:, 0], B[:, 1]
    gx, gy = gx - (s(gx) / safe)[seg], gy - (s(gy) / safe)[seg]
    bx, by = bx - (s(bx) / safe)[seg], by - (s(by) / safe)[seg]
    re = s(bx * gx + by * gy)
    im = s(by * gx - bx * gy)
    den = jnp.sqrt(jnp.maximum(s(bx * bx + by * by) * s(gx * gx + gy * gy), 1e-300))
    return jnp.sqrt(re * re + im * im) / den, n


def pearson_xy(x, G, B_meas, segment, rotating, n_segments, mode="axis"):
    """Eqs. (6)-(7): correlation of corrected magnetometer and accelerometer x/y while rotating.

    Args:
        x: (12,) parameters. G: (N, 3) g. B_meas: (N, 3) nT.
        segment: (N,) int segment id (one rotating stretch between two stops).
        rotating: (N,) bool/float, 1 where the string rotates.
        n_segments: static number of segments.
        mode: ``"axis"`` (paper: rho(bx, gx) and rho(by, gy)) or ``"complex"``
            (|correlation| of the cross-axial phasors, independent of the
            azimuth-dependent phase between the two rotating vectors).
    Returns:
        (rho, counts): rho (n_segments, 2) for ``axis`` (x, y columns) or
        (n_segments, 1) for ``complex``; counts (n_segments,) samples used.
    """
    Bc = correct(x, B_meas)
    G = jnp.asarray(G)
    w = jnp.asarray(rotating, Bc.dtype)
    seg = jnp.asarray(segment)
    if mode == "axis":
        rx, n = _segment_pearson(Bc[:, 0], G[:, 0], seg, w, n_segments)
        ry, _ = _segment_pearson(Bc[:, 1], G[:, 1], seg, w, n_segments)
        return jnp.stack([rx, ry], -1), n
    if mode == "complex":
        r, n = _segment_complex_corr(G, Bc, seg, w, n_segments)
        return r[:, None], n
    raise ValueError(f"pearson mode {mode!r}: choose 'axis' or 'complex'")
