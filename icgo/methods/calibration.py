"""12-parameter magnetometer calibration: model, objectives, closed-form baselines.

The MISMA paper (Yang & Cai, ``seeds/002_438cb34a40e5ab84.txt``) lost its
equations in the text extraction; each formula below is reconstructed from the
paragraph that describes it and carries the paper's equation number. The list
of reconstructions, with the reasons, is in ``docs/misma.md``.

Model (paper eqs. 2-4). The magnetometer reads ``B_meas = R B_true + b``
(R: 3x3 matrix lumping scale factors, non-orthogonality, misalignment and soft
iron; b: hard iron and sensor bias, nT). The paper identifies the 12 numbers
``Mcc = [R^-1 (row-major, 9), b (3)]`` and corrects with
``B_true = R^-1 (B_meas - b)`` (eq. 4). A parameter vector here is that (12,)
array; ``R^-1`` is dimensionless and ``b`` in nT.

Objectives (JAX, jittable, vmappable over candidate parameter vectors):

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

:class:`icgo.methods.misma_objective.MismaObjective` combines them into the penalised fitness that MISMA and
SMA minimise (``(P, 12) -> (P,)``, +inf for non-finite values) and exposes the
GMR for :mod:`icgo.optim.misma`.

Closed-form / deterministic baselines (host side, numpy; the nonlinear least
squares by :func:`icgo.maths.lsq.least_squares`, the converging entry point of :mod:`icgo.maths.lsq`):
:func:`ellipsoid_fit` (the classical quadric fit, symmetric ``R^-1``),
:func:`fit_twelve` (all 12 parameters by least squares on the dot-invariance
and magnitude residuals), :func:`align_to_axis` (a common rotation that puts
the roll axis of rolled groups on the tool z axis) and the peer package's
score :func:`group_spread_deg`.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.maths.lsq import LSQResult, least_squares
from icgo.physics.frames import angle_diff, azimuth_from_gv
from icgo.physics.rolls import MIN_ROLLED_SHOTS

N_PARAMS = 12
#: Tool-frame directions closer than this (deg, in G and in B) count as one orientation.
DISTINCT_SEPARATION_DEG = 2.0
#: Distinct orientations a 12-parameter fit needs (see :func:`check_orientations`).
MIN_ORIENTATIONS_12 = 12
#: ... and the 9-coefficient ellipsoid (quadric) fit.
MIN_ORIENTATIONS_ELLIPSOID = 9


# ----------------------------------------------------------------------- model
def pack(r_inv, b):
    """12-vector ``[R^-1 row-major, b]`` from ``R^-1`` (..., 3, 3) and ``b`` (..., 3) nT."""
    r_inv = jnp.asarray(r_inv)
    b = jnp.asarray(b)
    return jnp.concatenate([r_inv.reshape(r_inv.shape[:-2] + (9,)), b], axis=-1)


def unpack(x):
    """Inverse of :func:`pack`: ``(R^-1 (..., 3, 3), b (..., 3))`` from (..., 12)."""
    x = jnp.asarray(x)
    return x[..., :9].reshape(x.shape[:-1] + (3, 3)), x[..., 9:]


def params_from_error_model(r, b):
    """Calibration parameters (12,) for a sensor with ``B_meas = R B_true + b`` (eq. 3)."""
    return pack(jnp.linalg.inv(jnp.asarray(r)), b)


def identity_params(dtype=jnp.float64):
    """Parameters of a perfect magnetometer (R^-1 = I, b = 0), (12,)."""
    return pack(jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype))


def distort(r, b, B_true):
    """Eq. (3): ``B_meas = R B_true + b``; B_true (N, 3) nT -> (N, 3) nT."""
    return jnp.einsum("ij,...j->...i", jnp.asarray(r), jnp.asarray(B_true)) + jnp.asarray(b)


def correct(x, B_meas):
    """Eq. (4): ``B_true = R^-1 (B_meas - b)``.

    Args:
        x: (12,) parameters ``[R^-1, b]``.
        B_meas: (N, 3) raw magnetometer readings, nT.
    Returns:
        (N, 3) corrected field, nT.
    """
    r_inv, b = unpack(x)
    return jnp.einsum("ij,nj->ni", r_inv, jnp.asarray(B_meas) - b)


# ------------------------------------------------------------------ objectives
def normalized_dot(G, B):
    """``G.B / (|G| |B|)`` per sample, (N,). Equals sin(dip) for ideal sensors."""
    G = jnp.asarray(G)
    B = jnp.asarray(B)
    num = jnp.sum(G * B, -1)
    return num / (jnp.linalg.norm(G, axis=-1) * jnp.linalg.norm(B, axis=-1))


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


# --------------------------------------------------------------- the fitness
class CalData(NamedTuple):
    """Samples a calibration is fitted on.

    Attributes:
        G: (N, 3) gravity, g. B: (N, 3) raw magnetometer, nT.
        segment: (N,) int32 rotating-stretch id (0 .. n_segments-1).
        rotating: (N,) float 1/0, samples taken while the string rotates.
        ref_nT: reference modulus |M_omega| (nT), scalar.
        weights: (N,) sample weights of the magnitude term.
        dot_weights: (N,) sample weights of the dot-invariance term (the
            paper takes gravity at zero-velocity stops: see :func:`make_caldata`).
    """

    G: jnp.ndarray
    B: jnp.ndarray
    segment: jnp.ndarray
    rotating: jnp.ndarray
    ref_nT: jnp.ndarray
    weights: jnp.ndarray
    dot_weights: jnp.ndarray


def make_caldata(G, B, ref_nT, segment=None, rotating=None, weights=None, dot_weights=None) -> CalData:
    """Validate and pack calibration samples.

    Args:
        G: (N, 3) gravity in the tool frame, g. B: (N, 3) raw field, nT.
        ref_nT: reference field modulus |M_omega|, nT (> 0).
        segment: (N,) ints >= 0 or None (one segment).
        rotating: (N,) bools or None (no sample rotating: no Pearson term).
        weights: (N,) non-negative or None (all 1), for the magnitude term.
        dot_weights: (N,) non-negative or None (= weights), for the dot term;
            e.g. 1 at static samples only, where the accelerometer reads
            gravity without vibration and centripetal acceleration.
    Raises:
        ValueError: one line naming the bad argument.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    if G.ndim != 2 or G.shape[1] != 3 or B.shape != G.shape:
        raise ValueError(f"calibration data: G and B must both be (N, 3), got {G.shape} and {B.shape}")
    n = G.shape[0]
    if n < 2:
        raise ValueError(f"calibration data: need at least 2 samples, got {n}")
    for name, v in (("G", G), ("B", B)):
        bad = np.argwhere(~np.isfinite(v))
        if bad.size:
            raise ValueError(f"calibration data: {name} has a non-finite value at row {bad[0][0]}")
    if np.any(np.linalg.norm(G, axis=1) == 0) or np.any(np.linalg.norm(B, axis=1) == 0):
        raise ValueError("calibration data: a G or B row is the zero vector")
    if not np.isfinite(ref_nT) or ref_nT <= 0:
        raise ValueError(f"calibration data: reference modulus must be > 0, got {ref_nT}")
    seg = np.zeros(n, np.int32) if segment is None else np.asarray(segment)
    if seg.shape != (n,) or np.any(seg < 0):
        raise ValueError(f"calibration data: segment must be (N,) non-negative ints, got shape {seg.shape}")
    rot = np.zeros(n) if rotating is None else np.asarray(rotating, np.float64)
    if rot.shape != (n,):
        raise ValueError(f"calibration data: rotating must be (N,), got shape {rot.shape}")
    w = np.ones(n) if weights is None else np.asarray(weights, np.float64)
    if w.shape != (n,) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError("calibration data: weights must be (N,), non-negative, not all zero")
    dw = w if dot_weights is None else np.asarray(dot_weights, np.float64)
    if dw.shape != (n,) or np.any(dw < 0) or dw.sum() <= 0:
        raise ValueError("calibration data: dot_weights must be (N,), non-negative, not all zero")
    return CalData(jnp.asarray(G), jnp.asarray(B), jnp.asarray(seg.astype(np.int32)),
                   jnp.asarray(rot), jnp.asarray(float(ref_nT)), jnp.asarray(w), jnp.asarray(dw))


# ------------------------------------------------ orientation count (bad input)
def count_distinct_orientations(G, B, min_sep_deg=DISTINCT_SEPARATION_DEG) -> int:
    """Number of distinct tool-frame orientations (greedy clustering of unit G and B).

    Two samples belong to one orientation when both their G directions and
    their raw B directions are within ``min_sep_deg`` of each other.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    g = G / np.linalg.norm(G, axis=1, keepdims=True)
    b = B / np.linalg.norm(B, axis=1, keepdims=True)
    c = np.cos(np.deg2rad(min_sep_deg))
    reps_g, reps_b = np.zeros((0, 3)), np.zeros((0, 3))
    for gi, bi in zip(g, b):
        if reps_g.shape[0] and np.any((reps_g @ gi >= c) & (reps_b @ bi >= c)):
            continue
        reps_g = np.vstack([reps_g, gi])
        reps_b = np.vstack([reps_b, bi])
    return int(reps_g.shape[0])


def check_orientations(G, B, n_required=MIN_ORIENTATIONS_12, what="the 12-parameter model",
                       min_sep_deg=DISTINCT_SEPARATION_DEG) -> int:
    """Raise ValueError when a recording has too few distinct orientations.

    Each static orientation gives two scalar conditions (field modulus and dip)
    with an unknown heading; we ask for one distinct orientation per parameter
    (12 for the full model, 9 for the ellipsoid's quadric), which leaves the
    least-squares problems over-determined by a factor of ~2. Geometry that is
    rank deficient despite enough orientations (e.g. rotation about one axis
    only) is caught by :func:`ellipsoid_fit`.

    Returns:
        the number of distinct orientations.
    """
    n = count_distinct_orientations(G, B, min_sep_deg)
    if n < n_required:
        raise ValueError(
            f"only {n} distinct orientations (>{min_sep_deg:g} deg apart) in the recording; "
            f"{what} needs at least {n_required}: record {n_required - n} more")
    return n


# --------------------------------------------------------- closed-form fits
def _sqrtm_spd(m):
    w, v = np.linalg.eigh(0.5 * (m + m.T))
    return (v * np.sqrt(w)) @ v.T, w


def ellipsoid_fit(B, ref_nT, G=None, check=True) -> np.ndarray:
    """Classical closed-form ellipsoid fit; symmetric ``R^-1`` and bias b.

    Least squares on the quadric ``x^T A x + 2 v^T x = 1`` (9 coefficients),
    centre ``b = -A^-1 v``, and ``R^-1 = |M_omega| sqrtm(A / (1 + b^T A b))``,
    the symmetric square root (the rotation part of R is invisible to
    magnitudes). Exact on noise-free data when R is symmetric positive definite.

    Args:
        B: (N, 3) raw field, nT. ref_nT: radius to scale to, nT.
        G: optional (N, 3) gravity; with ``check`` the orientation count is checked.
        check: raise on too few orientations / degenerate geometry.
    Returns:
        (12,) numpy parameters.
    Raises:
        ValueError: too few distinct orientations, rank-deficient design or a
            quadric that is not an ellipsoid.
    """
    B = np.asarray(B, np.float64)
    if check:
        check_orientations(G if G is not None else np.ones_like(B), B,
                           MIN_ORIENTATIONS_ELLIPSOID, "the ellipsoid fit")
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused just below
        s = np.median(np.linalg.norm(B, axis=1))
        x, y, z = (B / s).T
        D = np.stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z], 1)
    if not np.all(np.isfinite(D)):  # LAPACK on inf hangs or fails: a reading far larger than the others
        raise ValueError("ellipsoid fit: a reading is too large to square (check the units of every shot)")
    sv = np.linalg.svd(D, compute_uv=False)
    if check and sv[-1] < 1e-9 * sv[0]:
        raise ValueError(
            "ellipsoid fit: the orientations do not span the sphere (rank-deficient design, e.g. "
            "rotation about a single axis): record orientations with other inclinations/azimuths")
    a, bq, c, d, e, f, g, h, i = np.linalg.lstsq(D, np.ones(len(B)), rcond=None)[0]
    A = np.array([[a, d, e], [d, bq, f], [e, f, c]])
    v = np.array([g, h, i])
    centre = -np.linalg.solve(A, v)
    k = 1.0 + centre @ A @ centre
    M = A / k
    if np.any(np.linalg.eigvalsh(M) <= 0):
        raise ValueError("ellipsoid fit: the fitted quadric is not an ellipsoid (data too noisy or degenerate)")
    root, _ = _sqrtm_spd(M)
    return np.concatenate([(ref_nT / s * root).ravel(), centre * s])


#: Step budget of the calibration least squares (Levenberg-Marquardt steps).
LSQ_MAX_STEPS = 500


def _twelve_residuals(u, args):
    """Residuals of :func:`fit_twelve`: eq. (5) ``d_k - d_bar`` and ``sqrt(mu) (|B_k| / |M| - 1)``, (2N,)."""
    scale, G, B, sw, ref_nT, mu = args
    Bc = correct(u * scale, B)
    d = normalized_dot(G, Bc)
    r1 = (d - jnp.sum(sw * sw * d) / jnp.sum(sw * sw)) * sw  # the weighted mean: zero-weight shots do not enter
    r2 = jnp.sqrt(mu) * (jnp.linalg.norm(Bc, axis=1) / ref_nT - 1.0) * sw
    return jnp.concatenate([r1, r2])


def _modulus_residuals(u, args):
    """Residuals of :func:`modulus_fit`: ``|R^-1 (B_k - b)| / |M| - 1`` (N,) and ``ridge (u - u0)`` (12,)."""
    scale, B, ref_nT, u0, ridge = args
    m = jnp.linalg.norm(correct(u * scale, B), axis=1) / ref_nT - 1.0
    return jnp.concatenate([m, ridge * (u - u0)])


def _column_scaled(fn):
    """``fn`` in variables ``v = c * u`` (``args = (c, fn_args)``), c: (P,) column scales."""
    return lambda v, args: fn(v / args[0], args[1])


_twelve_scaled_residuals = _column_scaled(_twelve_residuals)


@jax.jit
def _solve_twelve(u0, args) -> LSQResult:
    """:func:`fit_twelve`'s solve, each variable also in units of its Jacobian column norm at the start.

    That is the fixed form of the ``x_scale="jac"`` the scipy version used;
    without it the near-straight ``rotating_drill`` variant (condition ~4e3)
    does not converge in 500 steps. Returns x in the ``u`` variables.
    """
    c = jnp.linalg.norm(jax.jacfwd(_twelve_residuals)(u0, args), axis=0)
    c = jnp.where(c > 0, c, 1.0)
    fit = least_squares(_twelve_scaled_residuals, u0 * c, (c, args), max_steps=LSQ_MAX_STEPS)
    return fit._replace(x=fit.x / c)


@jax.jit
def _solve_modulus(u0, args) -> LSQResult:
    return least_squares(_modulus_residuals, u0, args, max_steps=LSQ_MAX_STEPS)


def _checked(fit: LSQResult, what: str) -> np.ndarray:
    """The solution (numpy) of a calibration least squares.

    Raises ValueError if it is not finite; warns (RuntimeWarning) and returns
    the last iterate when the step budget ran out before convergence.
    """
    x = np.asarray(fit.x)
    if not np.all(np.isfinite(x)) or not np.isfinite(float(fit.cost)):
        raise ValueError(f"{what}: the least squares diverged to a non-finite solution (bad start or data)")
    if not bool(fit.ok):
        warnings.warn(f"{what}: Levenberg-Marquardt did not converge in {int(fit.n_steps)} steps; "
                      "returning the last iterate", RuntimeWarning, stacklevel=3)
    return x


def fit_twelve(G, B, ref_nT, x0=None, mu_magnitude=1.0, weights=None, check=True):
    """All 12 parameters by least squares (the deterministic 12-parameter baseline).

    Residuals: ``d_k - d_bar`` (eq. 5) and ``sqrt(mu_m) (|B_k| / |M_omega| - 1)``,
    solved by :func:`icgo.maths.lsq.least_squares` (Levenberg-Marquardt, exact JAX
    Jacobian) from the ellipsoid fit, in variables scaled so that the matrix
    (by its largest start entry) and the bias (by ``ref_nT``) are of order one
    and then by the Jacobian's column norms at the start.
    Unlike the ellipsoid fit it also finds the rotation of the magnetometer
    relative to the accelerometers.

    Args:
        G: (N, 3) g. B: (N, 3) raw nT. ref_nT: |M_omega|, nT.
        x0: start (12,) or None (ellipsoid fit).
        mu_magnitude: weight of the magnitude residuals.
        weights: (N,) or None.
    Returns:
        (12,) numpy parameters.
    """
    G = np.asarray(G, np.float64)
    B = np.asarray(B, np.float64)
    if check:
        check_orientations(G, B)
    if x0 is None:
        x0 = ellipsoid_fit(B, ref_nT, G, check=check)
    w = np.ones(len(B)) if weights is None else np.asarray(weights, np.float64)
    sw = jnp.asarray(np.sqrt(w / w.mean()))
    # scale the variables so the bias (nT) and the matrix (1) are comparable
    scale = np.concatenate([np.full(9, np.abs(np.asarray(x0[:9])).max()), np.full(3, ref_nT)])
    args = (jnp.asarray(scale), jnp.asarray(G), jnp.asarray(B), sw, jnp.asarray(float(ref_nT)),
            jnp.asarray(float(mu_magnitude)))
    fit = _solve_twelve(jnp.asarray(np.asarray(x0, np.float64) / scale), args)
    return _checked(fit, "fit_twelve") * scale


def modulus_fit(B, ref_nT, x0=None, ridge=0.03):
    """U of MISMA (eqs. 9-10): parameters whose corrected modulus matches ``|M_omega|``.

    Least squares (:func:`icgo.maths.lsq.least_squares`) on
    ``|R^-1 (B_k - b)| / |M_omega| - 1`` with a weak ridge ``ridge * (x - x0)``
    (scaled) towards ``x0`` (default: identity matrix, bias = mean of B), so
    the fit stays defined where the geometry cannot separate all 12
    parameters (e.g. rotation about one axis only, where the ellipsoid fit is
    rank deficient). On well-spread data it agrees with :func:`ellipsoid_fit`
    up to a rotation, which moduli cannot see.

    Returns:
        (12,) numpy parameters.
    """
    B = np.asarray(B, np.float64)
    if x0 is None:  # a roughly calibrated sensor: identity (scaled to the reference), no bias
        s = np.median(np.linalg.norm(B, axis=1))
        x0 = np.concatenate([(np.eye(3) * ref_nT / s).ravel(), np.zeros(3)])
    x0 = np.asarray(x0, np.float64)
    scale = np.concatenate([np.full(9, np.abs(x0[:9]).max()), np.full(3, ref_nT)])
    u0 = jnp.asarray(x0 / scale)
    args = (jnp.asarray(scale), jnp.asarray(B), jnp.asarray(float(ref_nT)), u0, jnp.asarray(float(ridge)))
    return _checked(_solve_modulus(u0, args), "modulus_fit") * scale


# -------------------------------------------------- accelerometer and groups
def ellipsoid_fit_accel(G, check=True) -> np.ndarray:
    """Ellipsoid fit of the accelerometer: ``G_true = S (G_meas - c)`` on the unit sphere.

    Same closed form as :func:`ellipsoid_fit` with radius 1 g; returns (12,)
    ``[S, c]`` usable with :func:`correct`.
    """
    return ellipsoid_fit(np.asarray(G, np.float64), 1.0, check=False) if not check else \
        ellipsoid_fit(np.asarray(G, np.float64), 1.0, G, check=True)


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
    down = G / jnp.linalg.norm(G, axis=-1, keepdims=True)
    east = jnp.cross(down, B)
    east = east / jnp.linalg.norm(east, axis=-1, keepdims=True)
    north = jnp.cross(east, down)
    return jnp.stack([north[..., 2], east[..., 2], down[..., 2]], -1)


# ------------------------------------------------------------------- azimuth
def azimuth_error_deg(G, B, reference_azimuth_deg, declination_deg=0.0):
    """Wrapped azimuth error (deg, (-180, 180]) of ``azimuth_from_gv(G, B) + declination`` vs a reference."""
    a = azimuth_from_gv(jnp.asarray(G), jnp.asarray(B)) + declination_deg
    return np.asarray(angle_diff(a, jnp.asarray(reference_azimuth_deg)))
